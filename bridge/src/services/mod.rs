//! Zenoh services (trainer, model store, MPC, recorder): each runs on its own worker thread;
//! Zenoh callbacks only forward queries into that thread's channel.

pub mod koopman_trainer;
pub mod models;
pub mod mpc;
pub mod recorder;
pub mod trainer;

use std::sync::mpsc;
use std::time::Duration;

use zenoh::query::Query;
use zenoh::{Session, Wait};

use crate::error::{Error, ErrorCode, ErrorReply, Result};

/// Largest request payload a service accepts by default (1 MiB).
pub const DEFAULT_MAX_PAYLOAD: usize = 1 << 20;

/// A queryable whose queries arrive on a channel, tagged with `T`.
pub struct Inbox<T> {
    rx: mpsc::Receiver<(T, Query)>,
    tx: mpsc::Sender<(T, Query)>,
    queryables: Vec<zenoh::query::Queryable<()>>,
}

impl<T: Copy + Send + Sync + 'static> Inbox<T> {
    /// An inbox with no queryable yet.
    pub fn new() -> Self {
        let (tx, rx) = mpsc::channel();
        Inbox {
            rx,
            tx,
            queryables: Vec::new(),
        }
    }

    /// Declares a queryable on `key` whose queries arrive tagged `tag`.
    pub fn declare(&mut self, session: &Session, key: &str, tag: T) -> Result<()> {
        let tx = self.tx.clone();
        let q = session
            .declare_queryable(key)
            .callback(move |q| {
                let _ = tx.send((tag, q));
            })
            .wait()
            .map_err(Error::zenoh)?;
        self.queryables.push(q);
        Ok(())
    }

    /// The next query, or `None` after `timeout`.
    pub fn next(&self, timeout: Duration) -> Option<(T, Query)> {
        self.rx.recv_timeout(timeout).ok()
    }
}

impl<T: Copy + Send + Sync + 'static> Default for Inbox<T> {
    fn default() -> Self {
        Self::new()
    }
}

/// The request payload, or a `too_large` error if it exceeds `max` bytes.
pub fn payload(q: &Query, max: usize) -> std::result::Result<Vec<u8>, ErrorReply> {
    let p = q
        .payload()
        .map(|p| p.to_bytes().into_owned())
        .unwrap_or_default();
    if p.len() > max {
        return Err(ErrorReply::new(
            ErrorCode::TooLarge,
            format!("{} bytes, this service accepts at most {max}", p.len()),
        ));
    }
    Ok(p)
}

/// Parses a JSON request body into `T`, or a `bad_request` error.
pub fn parse_json<T: serde::de::DeserializeOwned>(
    what: &str,
    body: &[u8],
) -> std::result::Result<T, ErrorReply> {
    serde_json::from_slice(body)
        .map_err(|e| ErrorReply::new(ErrorCode::BadRequest, format!("{what}: invalid JSON: {e}")))
}

/// Serialises a JSON reply body.
pub fn to_json<T: serde::Serialize>(v: &T) -> std::result::Result<Vec<u8>, ErrorReply> {
    serde_json::to_vec(v).map_err(|e| ErrorReply::new(ErrorCode::Internal, e.to_string()))
}

/// Sends the result (payload) or the typed error as the reply to `q`.
pub fn respond(q: &Query, result: std::result::Result<Vec<u8>, ErrorReply>) {
    let sent = match result {
        Ok(b) => q.reply(q.key_expr().clone(), b).wait(),
        Err(e) => {
            tracing::debug!(key = %q.key_expr(), code = %e.code, "error reply: {}", e.message);
            q.reply_err(e.to_json()).wait()
        }
    };
    if let Err(e) = sent {
        tracing::warn!(key = %q.key_expr(), "could not send a reply: {e}");
    }
}
