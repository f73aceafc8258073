//! Zenoh services (trainer, model store, MPC, recorder): each runs on its own worker thread;
//! Zenoh callbacks only forward queries into that thread's channel.

pub mod koopman_trainer;
pub mod model_kind;
pub mod models;
pub mod mpc;
pub mod recorder;
pub mod recording_mcap;
mod service;
pub mod trainer;

pub use service::Service;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Mutex, MutexGuard};
use std::time::Duration;

use zenoh::query::Query;
use zenoh::{Session, Wait};

use crate::error::{Error, ErrorCode, ErrorReply, Result};
use crate::keyexpr::{validate_chunk, Keys, Role};

/// Locks `m`, going on with the data if another thread panicked while holding it (every
/// service keeps serving; the data of a mutex here is always left consistent between updates).
pub fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Largest request payload a service accepts by default (1 MiB).
pub const DEFAULT_MAX_PAYLOAD: usize = 1 << 20;

/// Most queries a service holds waiting for its thread (PROTOCOL.md, "Limits"): one more is
/// answered `busy` at once. Payloads above [`DEFAULT_MAX_PAYLOAD`] are answered `too_large`
/// on arrival and never queued, so the waiting queries hold at most 256 MiB of payload.
pub const INBOX_CAPACITY: usize = 256;

/// A queryable whose queries arrive on a bounded channel ([`INBOX_CAPACITY`]), tagged with `T`.
pub struct Inbox<T> {
    rx: mpsc::Receiver<(T, Query)>,
    tx: mpsc::SyncSender<(T, Query)>,
    queryables: Vec<zenoh::query::Queryable<()>>,
}

impl<T: Copy + Send + Sync + 'static> Inbox<T> {
    /// An inbox with no queryable yet.
    pub fn new() -> Self {
        let (tx, rx) = mpsc::sync_channel(INBOX_CAPACITY);
        Inbox {
            rx,
            tx,
            queryables: Vec::new(),
        }
    }

    /// Declares a queryable on `key` whose queries arrive tagged `tag`. A query whose payload
    /// is larger than [`DEFAULT_MAX_PAYLOAD`] is answered `too_large`, and one that finds
    /// [`INBOX_CAPACITY`] queries waiting `busy`, in the Zenoh callback: neither is kept.
    pub fn declare(&mut self, session: &Session, key: &str, tag: T) -> Result<()> {
        let tx = self.tx.clone();
        let q = session
            .declare_queryable(key)
            .callback(move |q| {
                if let Err(e) = payload_len(&q, DEFAULT_MAX_PAYLOAD) {
                    return respond(&q, Err(e));
                }
                if let Err(mpsc::TrySendError::Full((_, q))) = tx.try_send((tag, q)) {
                    let e = format!("{INBOX_CAPACITY} queries are already waiting; try again");
                    respond(&q, Err(ErrorReply::new(ErrorCode::Busy, e)));
                }
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

/// Set when a query above [`DEFAULT_MAX_PAYLOAD`] arrived (any service of the process).
static OVERSIZED_SEEN: AtomicBool = AtomicBool::new(false);

/// After an oversized query, once a service (or an adapter) is idle: hands the heap's free
/// pages back to the system. Zenoh receives such a message whole, in batch buffers spread over its threads' malloc
/// arenas, before the service refuses it; glibc keeps those freed pages (measured: +16 MB per
/// receiving thread after 17 MB queries, BENCHMARKS.md "Reliability"). `malloc_trim` is glibc's.
pub(crate) fn trim_after_oversized() {
    if OVERSIZED_SEEN.swap(false, Ordering::Relaxed) {
        #[cfg(all(target_os = "linux", target_env = "gnu"))]
        // SAFETY: malloc_trim only releases free memory of the allocator; no pointer is touched.
        unsafe {
            libc::malloc_trim(0);
        }
    }
}

/// The request payload's length, or a `too_large` error if it exceeds `max` bytes (nothing
/// is copied; [`trim_after_oversized`] will trim).
fn payload_len(q: &Query, max: usize) -> std::result::Result<usize, ErrorReply> {
    let n = q.payload().map_or(0, |p| p.len());
    if n > max {
        OVERSIZED_SEEN.store(true, Ordering::Relaxed);
        return Err(ErrorReply::new(
            ErrorCode::TooLarge,
            format!("{n} bytes, this service accepts at most {max}"),
        ));
    }
    Ok(n)
}

/// The request payload, or a `too_large` error if it exceeds `max` bytes (checked before the
/// payload is copied).
pub fn payload(q: &Query, max: usize) -> std::result::Result<Vec<u8>, ErrorReply> {
    payload_len(q, max)?;
    Ok(q.payload()
        .map(|p| p.to_bytes().into_owned())
        .unwrap_or_default())
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

/// Client side of a JSON control-plane request: sends `req` to `key` and decodes the reply as
/// `T`; a reply that does not decode is a `bad_request` protocol error naming `who`.
pub fn query_json<T: serde::de::DeserializeOwned>(
    client: &crate::client::Client,
    key: &str,
    req: &impl serde::Serialize,
    timeout: Duration,
    who: &str,
) -> Result<T> {
    let body = serde_json::to_vec(req).map_err(|e| Error::Config(e.to_string()))?;
    let b = client.query(key, body, timeout, who)?;
    serde_json::from_slice(&b).map_err(|e| {
        Error::protocol(
            ErrorCode::BadRequest,
            format!("{who}: reply is not valid: {e}"),
        )
    })
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

/// The result of handling one query: the reply payload or a typed error.
pub type Reply = std::result::Result<Vec<u8>, ErrorReply>;

/// The loop every service runs: holds the liveliness token `…/alive/{role}/{id}`, then answers
/// each query of `inbox` with `handle(tag, query, body)` (`body` = the payload, refused with
/// `too_large` above [`DEFAULT_MAX_PAYLOAD`]) until `stop` is set.
pub fn serve_queries<T: Copy + Send + Sync + 'static>(
    session: &Session,
    keys: &Keys,
    role: Role,
    id: &str,
    inbox: &Inbox<T>,
    stop: &AtomicBool,
    mut handle: impl FnMut(T, &Query, Vec<u8>) -> Reply,
) -> Result<()> {
    serve_queries_handing_on(session, keys, role, id, inbox, stop, |tag, q, body| {
        Some(handle(tag, q, body))
    })
}

/// [`serve_queries`] whose handler may hand a query on instead of answering it: `None` means
/// it gave a clone of the query to another thread, which answers it (Zenoh ends a query when
/// its last clone is dropped).
pub fn serve_queries_handing_on<T: Copy + Send + Sync + 'static>(
    session: &Session,
    keys: &Keys,
    role: Role,
    id: &str,
    inbox: &Inbox<T>,
    stop: &AtomicBool,
    mut handle: impl FnMut(T, &Query, Vec<u8>) -> Option<Reply>,
) -> Result<()> {
    let _token = session
        .liveliness()
        .declare_token(keys.alive(role, id)?)
        .wait()
        .map_err(Error::zenoh)?;
    tracing::info!("{role:?} service '{id}' ready");
    while !stop.load(Ordering::Relaxed) {
        let Some((tag, q)) = inbox.next(Duration::from_millis(100)) else {
            trim_after_oversized();
            continue;
        };
        let result = match payload(&q, DEFAULT_MAX_PAYLOAD) {
            Ok(body) => handle(tag, &q, body),
            Err(e) => Some(Err(e)),
        };
        if let Some(result) = result {
            respond(&q, result);
        }
    }
    Ok(())
}

/// The last chunk of the query's key (the `{name}` of `…/models/{name}`), checked as an id
/// chunk; `what` names it in the `bad_request` error.
pub fn key_tail(q: &Query, what: &str) -> std::result::Result<String, ErrorReply> {
    let name = q.key_expr().as_str().rsplit('/').next().unwrap_or("");
    validate_chunk(what, name).map_err(|e| e.to_reply())?;
    Ok(name.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::session::{free_loopback_endpoint, open_session, ZenohOptions};

    /// The error code of a reply, `None` for a sample or a reply that is not an `ErrorReply`.
    fn code(r: &zenoh::query::Reply) -> Option<ErrorCode> {
        let e = r.result().err()?;
        let reply: ErrorReply = serde_json::from_slice(&e.payload().to_bytes()).ok()?;
        Some(reply.code)
    }

    /// While nothing drains an inbox, an oversized query is answered `too_large` and every
    /// query past [`INBOX_CAPACITY`] `busy`, from the Zenoh callback; the queued ones wait.
    #[test]
    fn a_full_inbox_answers_busy_and_an_oversized_query_too_large() {
        let ep = free_loopback_endpoint().unwrap();
        let a = open_session(&ZenohOptions::peer(vec![ep.clone()], vec![])).unwrap();
        let b = open_session(&ZenohOptions::peer(vec![], vec![ep])).unwrap();
        let mut inbox = Inbox::new();
        let key = "koopbridge/t/inbox";
        inbox.declare(&a, key, ()).unwrap();
        let get = |payload: Vec<u8>, secs: u64| {
            b.get(key)
                .payload(payload)
                .timeout(Duration::from_secs(secs))
                .wait()
                .unwrap()
        };
        // Oversized: `too_large` at once (also the sign that `b` reaches the queryable).
        let deadline = std::time::Instant::now() + Duration::from_secs(20);
        loop {
            let r = get(vec![0; DEFAULT_MAX_PAYLOAD + 1], 2).recv();
            if let Ok(r) = r {
                assert_eq!(code(&r), Some(ErrorCode::TooLarge));
                break;
            }
            assert!(std::time::Instant::now() < deadline, "no reply");
        }
        let extra = 20;
        let pending: Vec<_> = (0..INBOX_CAPACITY + extra)
            .map(|_| get(vec![1, 2, 3], 3))
            .collect();
        let busy = pending
            .iter()
            .filter(|p| p.recv().is_ok_and(|r| code(&r) == Some(ErrorCode::Busy)))
            .count();
        assert_eq!(busy, extra);
        // The queued ones are there, untouched, in order of arrival.
        let queued = std::iter::from_fn(|| inbox.next(Duration::ZERO)).count();
        assert_eq!(queued, INBOX_CAPACITY);
    }
}
