//! The simulator side of the protocol — serves `info`/`reset`/`step` with a per-k reply cache,
//! runs free-run mode (absolute-deadline pacing, `state` out, `command` in) and holds the
//! liveliness token — for any [`SimBackend`], Rust or Python.
//!
//! - [`backend`]: the [`SimBackend`] trait, its default in-process `collect` ([`run_windows`])
//!   and [`SystemBackend`];
//! - [`lockstep`]: the protocol state machine, request bytes in, reply bytes out (no Zenoh);
//! - [`free_run`]: the free-run clock, command clipping and counters (no Zenoh);
//! - [`collect`]: `collect` requests checked and the windows a backend returns cut into reply
//!   chunks;
//! - [`serve`] (here): the Zenoh wiring around them.
//!
//! Zenoh callbacks only forward queries and samples into a channel; the backend is called on the
//! thread that called [`serve`], never inside a Zenoh callback.

pub mod backend;
pub mod collect;
pub mod free_run;
pub mod lockstep;
#[cfg(test)]
mod tests_collect;
#[cfg(test)]
pub(crate) mod tests_lockstep;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use zenoh::query::Query;
use zenoh::{Session, Wait};

use crate::codec::StateMsg;
use crate::error::{Error, Result};
use crate::keyexpr::{Keys, Role, SimLeaf};
use crate::services::{payload, respond, DEFAULT_MAX_PAYLOAD};

pub use crate::messages::{AdapterStats, InfoReply, ResetRequest, SimInfo};
pub use backend::{run_windows, window_rng, SimBackend, SimError, SystemBackend};
pub use collect::{CollectPlan, Windows};
pub use free_run::{FreeRun, FreeRunOptions};
pub use lockstep::Lockstep;

/// How an adapter serves.
#[derive(Clone, Debug)]
pub struct AdapterOptions {
    /// Key expressions of the session.
    pub keys: Keys,
    /// The simulator id (`…/sim/{id}/…`).
    pub id: String,
    /// Free-run mode instead of lockstep.
    pub free_run: Option<FreeRunOptions>,
    /// Largest accepted request payload in bytes (larger: `too_large` error reply).
    pub max_payload: usize,
    /// How many past step replies are kept for idempotent retries.
    pub cache_len: usize,
    /// Free-run: wait up to this long for a subscriber of `state` before the first tick (so
    /// that nobody misses the start of the stream); `None` = start at once.
    pub wait_subscriber: Option<Duration>,
}

impl AdapterOptions {
    /// Lockstep defaults for simulator `id` in session `session` (both validated).
    pub fn new(session: &str, id: &str) -> Result<Self> {
        let keys = Keys::new(session)?;
        keys.sim(id, SimLeaf::Info)?;
        Ok(AdapterOptions {
            keys,
            id: id.to_string(),
            free_run: None,
            max_payload: DEFAULT_MAX_PAYLOAD,
            cache_len: 16,
            wait_subscriber: None,
        })
    }
}

enum Event {
    Query(SimLeaf, Query),
    Command(Vec<u8>),
}

/// Serves one simulator until `stop` is set (or, in free-run mode with a step limit, until the
/// run is done). Blocking; call it from a thread of your own. Returns the final counters.
pub fn serve(
    session: &Session,
    backend: &mut dyn SimBackend,
    opts: &AdapterOptions,
    stop: &AtomicBool,
) -> Result<AdapterStats> {
    let mut sim = Lockstep::new(backend, &opts.id, opts.cache_len)?;
    // Free-running from the start: `info` says so and lockstep requests are refused even while
    // the adapter waits for a subscriber.
    sim.set_free_run(opts.free_run.is_some());
    let keys = &opts.keys;
    let (tx, rx) = mpsc::channel::<Event>();
    let mut queryables = Vec::new();
    for leaf in [
        SimLeaf::Info,
        SimLeaf::Reset,
        SimLeaf::Step,
        SimLeaf::Collect,
    ] {
        let tx = tx.clone();
        let q = session
            .declare_queryable(keys.sim(&opts.id, leaf)?)
            .callback(move |q| {
                let _ = tx.send(Event::Query(leaf, q));
            })
            .wait()
            .map_err(Error::zenoh)?;
        queryables.push(q);
    }
    let mut publisher = None;
    let mut _subscriber = None;
    if opts.free_run.is_some() {
        publisher = Some(
            session
                .declare_publisher(keys.sim(&opts.id, SimLeaf::State)?)
                .congestion_control(zenoh::qos::CongestionControl::Block)
                .wait()
                .map_err(Error::zenoh)?,
        );
        let tx = tx.clone();
        _subscriber = Some(
            session
                .declare_subscriber(keys.sim(&opts.id, SimLeaf::Command)?)
                .callback(move |s| {
                    let _ = tx.send(Event::Command(s.payload().to_bytes().into_owned()));
                })
                .wait()
                .map_err(Error::zenoh)?,
        );
    }
    drop(tx);
    let _token = session
        .liveliness()
        .declare_token(keys.alive(Role::Sim, &opts.id)?)
        .wait()
        .map_err(Error::zenoh)?;

    let mut free = match (&opts.free_run, &publisher) {
        (Some(fr), Some(p)) => {
            if let Some(w) = opts.wait_subscriber {
                let until = Instant::now() + w;
                while Instant::now() < until && !stop.load(Ordering::Relaxed) {
                    if p.matching_status().wait().is_ok_and(|m| m.matching()) {
                        break;
                    }
                    std::thread::sleep(Duration::from_millis(20));
                }
            }
            let (run, first) = FreeRun::start(&mut sim, fr)?;
            publish(p, &mut sim, &first)?;
            Some(run)
        }
        _ => None,
    };

    while !stop.load(Ordering::Relaxed) {
        let wait = free
            .as_ref()
            .map_or(Duration::from_millis(100), |f| {
                f.deadline().saturating_duration_since(Instant::now())
            })
            .min(Duration::from_millis(100));
        match rx.recv_timeout(wait) {
            Ok(Event::Query(SimLeaf::Collect, q)) => {
                let result = match payload(&q, opts.max_payload) {
                    Ok(body) => sim.answer_collect(&body),
                    Err(e) => sim.refuse(e).map(|b| vec![b]),
                };
                respond_chunks(&q, result);
            }
            Ok(Event::Query(leaf, q)) => {
                let result = match payload(&q, opts.max_payload) {
                    Ok(body) => sim.answer(leaf, &body),
                    Err(e) => sim.refuse(e),
                };
                respond(&q, result);
            }
            Ok(Event::Command(bytes)) => {
                if let Some(f) = free.as_mut() {
                    f.command(&mut sim, &bytes);
                }
            }
            // Idle: the heap pages of a refused oversized query go back to the system.
            Err(mpsc::RecvTimeoutError::Timeout) => crate::services::trim_after_oversized(),
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
        }
        if let (Some(f), Some(p)) = (free.as_mut(), publisher.as_ref()) {
            let state = f
                .tick(&mut sim, Instant::now())
                .map_err(|e| Error::Remote {
                    who: format!("simulator {}", opts.id),
                    reply: e,
                })?;
            if let Some(s) = state {
                publish(p, &mut sim, &s)?;
                if f.finished() {
                    break;
                }
            }
        }
    }
    Ok(sim.stats().clone())
}

/// Sends each chunk as one reply to `q` (a `collect` query), or the typed error.
fn respond_chunks(q: &Query, result: std::result::Result<Vec<Vec<u8>>, crate::ErrorReply>) {
    match result {
        Ok(chunks) => {
            for c in chunks {
                if let Err(e) = q.reply(q.key_expr().clone(), c).wait() {
                    tracing::warn!(key = %q.key_expr(), "could not send a collect chunk: {e}");
                    return;
                }
            }
        }
        Err(e) => respond(q, Err(e)),
    }
}

fn publish(p: &zenoh::pubsub::Publisher<'_>, sim: &mut Lockstep<'_>, s: &StateMsg) -> Result<()> {
    p.put(s.encode()).wait().map_err(Error::zenoh)?;
    sim.stats_mut().published += 1;
    Ok(())
}
