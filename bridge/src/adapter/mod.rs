//! The simulator side of the protocol: serves `info`/`reset`/`step` with a per-k reply cache,
//! runs free-run mode (absolute-deadline pacing, `state` out, `command` in) and holds the
//! liveliness token — for any [`SimBackend`], Rust or Python.
//!
//! Zenoh callbacks only forward queries and samples into a channel; the backend is called on the
//! thread that called [`serve`], never inside a Zenoh callback.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use zenoh::query::Query;
use zenoh::{Session, Wait};

use crate::codec::{CommandMsg, StateMsg, StepReply, StepRequest, PROTOCOL_VERSION};
use crate::error::{Error, ErrorCode, ErrorReply, Result};
use crate::keyexpr::{Keys, Role, SimLeaf};
pub use crate::messages::{AdapterStats, InfoReply, ResetRequest, SimInfo};

/// A simulator as the adapter sees it: plain synchronous calls, one at a time, on one thread.
pub trait SimBackend {
    /// What the simulator is (called once when serving starts).
    fn info(&self) -> SimInfo;
    /// Resets and returns the first state `x_0` (`nx` values).
    fn reset(&mut self, req: &ResetRequest) -> std::result::Result<Vec<f64>, SimError>;
    /// Applies `u` (`nu` values, held over one `dt`) and returns the next state.
    fn step(&mut self, u: &[f64]) -> std::result::Result<Vec<f64>, SimError>;
}

/// A failure reported by a backend.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SimError {
    /// The request was wrong (bad initial state, input out of range the simulator refuses, ...).
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// The request is not supported by this simulator (e.g. an explicit `x0`).
    #[error("unsupported: {0}")]
    Unsupported(String),
    /// The simulator failed (diverged, crashed, ...).
    #[error("simulator failure: {0}")]
    Failed(String),
}

impl SimError {
    fn reply(&self) -> ErrorReply {
        let code = match self {
            SimError::InvalidInput(_) => ErrorCode::BadRequest,
            SimError::Unsupported(_) => ErrorCode::Unsupported,
            SimError::Failed(_) => ErrorCode::SimFailure,
        };
        ErrorReply::new(code, self.to_string())
    }
}

/// Free-run settings.
#[derive(Clone, Debug, PartialEq)]
pub struct FreeRunOptions {
    /// Steps per wall-clock second; `None` = real time (`1/dt`).
    pub rate_hz: Option<f64>,
    /// Stop after this many steps (then [`serve`] returns); `None` = until stopped.
    pub steps: Option<u64>,
    /// How to reset before the run starts.
    pub reset: ResetRequest,
}

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
            max_payload: 1 << 20,
            cache_len: 16,
            wait_subscriber: None,
        })
    }
}

enum Event {
    Query(SimLeaf, Query),
    Command(Vec<u8>),
}

struct Cached {
    k: u64,
    u: Vec<u64>,
    reply: Vec<u8>,
}

struct FreeRun {
    opts: FreeRunOptions,
    period: Duration,
    t0: Instant,
    tick: u64,
    seq: u64,
    latest: Option<CommandMsg>,
    fresh: bool,
    seen_command: bool,
}

struct Adapter<'a> {
    backend: &'a mut dyn SimBackend,
    info: SimInfo,
    opts: &'a AdapterOptions,
    k: u64,
    has_state: bool,
    cache: VecDeque<Cached>,
    stats: AdapterStats,
}

/// Serves one simulator until `stop` is set (or, in free-run mode with a step limit, until the
/// run is done). Blocking; call it from a thread of your own. Returns the final counters.
pub fn serve(
    session: &Session,
    backend: &mut dyn SimBackend,
    opts: &AdapterOptions,
    stop: &AtomicBool,
) -> Result<AdapterStats> {
    let info = backend.info();
    if info.u_min.len() != info.nu() || info.u_max.len() != info.nu() {
        return Err(Error::Config(format!(
            "simulator info: {} inputs but {} lower and {} upper bounds",
            info.nu(),
            info.u_min.len(),
            info.u_max.len()
        )));
    }
    if !(info.dt > 0.0 && info.dt.is_finite()) {
        return Err(Error::Config(format!("simulator info: dt = {}", info.dt)));
    }
    let keys = &opts.keys;
    let (tx, rx) = mpsc::channel::<Event>();
    let mut queryables = Vec::new();
    for leaf in [SimLeaf::Info, SimLeaf::Reset, SimLeaf::Step] {
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

    let mut a = Adapter {
        backend,
        info,
        opts,
        k: 0,
        has_state: false,
        cache: VecDeque::new(),
        stats: AdapterStats::default(),
    };

    let mut free = match &opts.free_run {
        Some(fr) => {
            let rate = fr.rate_hz.unwrap_or(1.0 / a.info.dt);
            if !(rate > 0.0 && rate.is_finite()) {
                return Err(Error::Config(format!("free-run rate {rate} Hz")));
            }
            if let (Some(w), Some(p)) = (opts.wait_subscriber, &publisher) {
                let until = Instant::now() + w;
                while Instant::now() < until && !stop.load(Ordering::Relaxed) {
                    if p.matching_status().wait().is_ok_and(|m| m.matching()) {
                        break;
                    }
                    std::thread::sleep(Duration::from_millis(20));
                }
            }
            let x = a
                .reset_backend(&fr.reset)
                .map_err(|e| Error::Config(format!("free-run reset failed: {}", e.message)))?;
            let mut f = FreeRun {
                opts: fr.clone(),
                period: Duration::from_secs_f64(1.0 / rate),
                t0: Instant::now(),
                tick: 0,
                seq: 0,
                latest: None,
                fresh: false,
                seen_command: false,
            };
            if let Some(p) = &publisher {
                publish(p, &mut f, &mut a.stats, 0, 0.0, x, Vec::new())?;
            }
            Some(f)
        }
        None => None,
    };

    loop {
        if stop.load(Ordering::Relaxed) {
            break;
        }
        let now = Instant::now();
        let wait = match &free {
            Some(f) => {
                (f.t0 + f.period.mul_f64((f.tick + 1) as f64)).saturating_duration_since(now)
            }
            None => Duration::from_millis(100),
        }
        .min(Duration::from_millis(100));
        match rx.recv_timeout(wait) {
            Ok(Event::Query(leaf, q)) => a.handle_query(leaf, &q, free.is_some()),
            Ok(Event::Command(bytes)) => {
                if let Some(f) = free.as_mut() {
                    match CommandMsg::decode(&bytes) {
                        Ok(c) if c.u.len() == a.info.nu() && c.u.iter().all(|v| v.is_finite()) => {
                            f.latest = Some(c);
                            f.fresh = true;
                            f.seen_command = true;
                        }
                        _ => a.stats.errors += 1,
                    }
                }
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
        }
        if let (Some(f), Some(p)) = (free.as_mut(), publisher.as_ref()) {
            let deadline = f.t0 + f.period.mul_f64((f.tick + 1) as f64);
            let now = Instant::now();
            if now >= deadline {
                let late = now - deadline;
                a.stats.max_lateness_us = a.stats.max_lateness_us.max(late.as_micros() as u64);
                if late > f.period {
                    a.stats.overruns += 1;
                }
                if f.seen_command {
                    match (&f.latest, f.fresh) {
                        (Some(c), true) if c.k >= a.k => {}
                        (Some(_), true) => a.stats.late_commands += 1,
                        _ => a.stats.missing_commands += 1,
                    }
                }
                f.fresh = false;
                let u = match &f.latest {
                    Some(c) => c.u.clone(),
                    None => vec![0.0; a.info.nu()],
                };
                let x = match a.step_backend(&u) {
                    Ok(x) => x,
                    Err(e) => {
                        return Err(Error::Remote {
                            who: format!("simulator {}", opts.id),
                            reply: e,
                        })
                    }
                };
                f.tick += 1;
                let t = a.k as f64 * a.info.dt;
                let k = a.k;
                publish(p, f, &mut a.stats, k, t, x, u)?;
                let wall = f.t0.elapsed().as_secs_f64();
                if wall > 0.0 {
                    a.stats.real_time_factor = t / wall;
                }
                if f.opts.steps.is_some_and(|n| f.tick >= n) {
                    break;
                }
            }
        }
    }
    Ok(a.stats)
}

fn publish(
    p: &zenoh::pubsub::Publisher<'_>,
    f: &mut FreeRun,
    stats: &mut AdapterStats,
    k: u64,
    t: f64,
    x: Vec<f64>,
    u: Vec<f64>,
) -> Result<()> {
    let msg = StateMsg {
        seq: f.seq,
        k,
        t,
        x,
        u,
    };
    p.put(msg.encode()).wait().map_err(Error::zenoh)?;
    f.seq += 1;
    stats.published += 1;
    Ok(())
}

impl Adapter<'_> {
    fn reset_backend(&mut self, req: &ResetRequest) -> std::result::Result<Vec<f64>, ErrorReply> {
        if let Some(x0) = &req.x0 {
            if x0.len() != self.info.nx() {
                return Err(ErrorReply::new(
                    ErrorCode::Dimension,
                    format!(
                        "x0 has {} values, the state has {}",
                        x0.len(),
                        self.info.nx()
                    ),
                ));
            }
            if !x0.iter().all(|v| v.is_finite()) {
                return Err(ErrorReply::new(ErrorCode::BadRequest, "x0 is not finite"));
            }
        }
        let x = self.backend.reset(req).map_err(|e| e.reply())?;
        self.check_state(&x)?;
        self.k = 0;
        self.has_state = true;
        self.cache.clear();
        self.stats.resets += 1;
        Ok(x)
    }

    fn step_backend(&mut self, u: &[f64]) -> std::result::Result<Vec<f64>, ErrorReply> {
        let x = self.backend.step(u).map_err(|e| e.reply())?;
        self.check_state(&x)?;
        self.k += 1;
        self.stats.steps += 1;
        Ok(x)
    }

    fn check_state(&self, x: &[f64]) -> std::result::Result<(), ErrorReply> {
        if x.len() != self.info.nx() {
            return Err(ErrorReply::new(
                ErrorCode::SimFailure,
                format!(
                    "simulator returned {} state values, info says {}",
                    x.len(),
                    self.info.nx()
                ),
            ));
        }
        if !x.iter().all(|v| v.is_finite()) {
            return Err(ErrorReply::new(
                ErrorCode::SimFailure,
                "simulator returned a non-finite state",
            ));
        }
        Ok(())
    }

    fn handle_query(&mut self, leaf: SimLeaf, q: &Query, free_run: bool) {
        let result = self.answer(leaf, q, free_run);
        let sent = match result {
            Ok(bytes) => q.reply(q.key_expr().clone(), bytes).wait(),
            Err(e) => {
                self.stats.errors += 1;
                tracing::debug!(sim = %self.opts.id, code = %e.code, "error reply: {}", e.message);
                q.reply_err(e.to_json()).wait()
            }
        };
        if let Err(e) = sent {
            tracing::warn!(sim = %self.opts.id, "could not send a reply: {e}");
        }
    }

    fn answer(
        &mut self,
        leaf: SimLeaf,
        q: &Query,
        free_run: bool,
    ) -> std::result::Result<Vec<u8>, ErrorReply> {
        let payload = q
            .payload()
            .map(|p| p.to_bytes().into_owned())
            .unwrap_or_default();
        if payload.len() > self.opts.max_payload {
            return Err(ErrorReply::new(
                ErrorCode::TooLarge,
                format!(
                    "{} bytes, this adapter accepts at most {}",
                    payload.len(),
                    self.opts.max_payload
                ),
            ));
        }
        match leaf {
            SimLeaf::Info => {
                let reply = InfoReply {
                    protocol_version: PROTOCOL_VERSION,
                    id: self.opts.id.clone(),
                    mode: if free_run { "free-run" } else { "lockstep" }.into(),
                    k: self.k,
                    sim: self.info.clone(),
                    stats: self.stats.clone(),
                };
                serde_json::to_vec(&reply)
                    .map_err(|e| ErrorReply::new(ErrorCode::Internal, e.to_string()))
            }
            SimLeaf::Reset => {
                if free_run {
                    return Err(ErrorReply::new(
                        ErrorCode::Busy,
                        "this simulator is free-running; reset is lockstep only",
                    ));
                }
                let req: ResetRequest = if payload.iter().all(|b| b.is_ascii_whitespace()) {
                    ResetRequest::default()
                } else {
                    serde_json::from_slice(&payload).map_err(|e| {
                        ErrorReply::new(
                            ErrorCode::BadRequest,
                            format!("reset request is not valid JSON: {e}"),
                        )
                    })?
                };
                let x = self.reset_backend(&req)?;
                Ok(StepReply { k: 0, t: 0.0, x }.encode())
            }
            SimLeaf::Step => {
                if free_run {
                    return Err(ErrorReply::new(
                        ErrorCode::Busy,
                        "this simulator is free-running; step is lockstep only",
                    ));
                }
                let req = StepRequest::decode(&payload).map_err(|e| e.to_reply())?;
                if req.u.len() != self.info.nu() {
                    return Err(ErrorReply::new(
                        ErrorCode::Dimension,
                        format!(
                            "u has {} values, the simulator has {} inputs",
                            req.u.len(),
                            self.info.nu()
                        ),
                    ));
                }
                if !req.u.iter().all(|v| v.is_finite()) {
                    return Err(ErrorReply::new(ErrorCode::BadRequest, "u is not finite"));
                }
                let bits: Vec<u64> = req.u.iter().map(|v| v.to_bits()).collect();
                if let Some(c) = self.cache.iter().find(|c| c.k == req.k) {
                    if c.u == bits {
                        self.stats.cache_hits += 1;
                        return Ok(c.reply.clone());
                    }
                    return Err(ErrorReply::new(
                        ErrorCode::Conflict,
                        format!("step {} was already taken with a different input", req.k),
                    ));
                }
                if !self.has_state {
                    return Err(ErrorReply::new(
                        ErrorCode::OutOfOrder,
                        "no state yet: send a reset first",
                    ));
                }
                if req.k != self.k {
                    return Err(ErrorReply::new(
                        ErrorCode::OutOfOrder,
                        format!(
                            "step request for k = {}, the simulator is at k = {}",
                            req.k, self.k
                        ),
                    ));
                }
                let x = self.step_backend(&req.u)?;
                let reply = StepReply {
                    k: self.k,
                    t: self.k as f64 * self.info.dt,
                    x,
                }
                .encode();
                self.cache.push_back(Cached {
                    k: req.k,
                    u: bits,
                    reply: reply.clone(),
                });
                while self.cache.len() > self.opts.cache_len.max(1) {
                    self.cache.pop_front();
                }
                Ok(reply)
            }
            SimLeaf::State | SimLeaf::Command => {
                Err(ErrorReply::new(ErrorCode::Unsupported, "not a queryable"))
            }
        }
    }
}

/// A [`SimBackend`] for any built-in reference system of `koopman::systems`.
pub struct SystemBackend {
    system: Box<dyn koopman::systems::System>,
    x: Vec<f64>,
}

impl SystemBackend {
    /// Wraps a system.
    pub fn new(system: Box<dyn koopman::systems::System>) -> Self {
        let nx = system.nx();
        SystemBackend {
            system,
            x: vec![0.0; nx],
        }
    }
}

impl SimBackend for SystemBackend {
    fn info(&self) -> SimInfo {
        SimInfo::from_system(self.system.as_ref())
    }

    fn reset(&mut self, req: &ResetRequest) -> std::result::Result<Vec<f64>, SimError> {
        self.x = match (&req.x0, req.seed) {
            (Some(x0), _) => x0.clone(),
            (None, seed) => {
                let mut rng = koopman::rng::Rng::new(seed.unwrap_or(0));
                self.system.sample_initial_state(&mut rng)
            }
        };
        Ok(self.x.clone())
    }

    fn step(&mut self, u: &[f64]) -> std::result::Result<Vec<f64>, SimError> {
        let mut next = vec![0.0; self.x.len()];
        self.system.step(&self.x, u, &mut next);
        if !next.iter().all(|v| v.is_finite()) {
            return Err(SimError::Failed("the state became non-finite".into()));
        }
        self.x = next;
        Ok(self.x.clone())
    }
}
