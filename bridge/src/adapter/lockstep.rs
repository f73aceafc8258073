//! The adapter's protocol state machine apart from Zenoh: request bytes of `info`, `reset` or
//! `step` in, reply bytes or a typed error out, with the per-k reply cache that makes a retried
//! step idempotent. Free-run mode ([`super::free_run`]) steps the backend through it too.

use std::collections::VecDeque;

use crate::codec::{StepReply, StepRequest, StepStatus, PROTOCOL_VERSION};
use crate::error::{Error, ErrorCode, ErrorReply, Result};
use crate::keyexpr::SimLeaf;
use crate::messages::{AdapterStats, CollectRequest, InfoReply, ResetRequest, SimInfo};
use crate::services::Reply;

use super::backend::SimBackend;
use super::collect::CollectPlan;

/// A step reply kept for retries: the step index, the input's bits and the reply bytes.
struct Cached {
    k: u64,
    u: Vec<u64>,
    reply: Vec<u8>,
}

/// One simulator's side of the protocol: its backend, step index, reply cache and counters.
pub struct Lockstep<'a> {
    backend: &'a mut dyn SimBackend,
    info: SimInfo,
    id: String,
    cache_len: usize,
    free_run: bool,
    k: u64,
    has_state: bool,
    cache: VecDeque<Cached>,
    stats: AdapterStats,
}

impl<'a> Lockstep<'a> {
    /// The state machine of simulator `id` over `backend`, keeping the last `cache_len` (≥ 1)
    /// step replies. Fails if the backend's info is inconsistent (bounds of another length than
    /// the inputs, `dt` not positive and finite).
    pub fn new(backend: &'a mut dyn SimBackend, id: &str, cache_len: usize) -> Result<Self> {
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
        Ok(Lockstep {
            backend,
            info,
            id: id.to_string(),
            cache_len: cache_len.max(1),
            free_run: false,
            k: 0,
            has_state: false,
            cache: VecDeque::new(),
            stats: AdapterStats::default(),
        })
    }

    /// Marks the simulator as free-running: `info` says so and `reset`/`step` queries get `busy`.
    pub fn set_free_run(&mut self, on: bool) {
        self.free_run = on;
    }

    /// What the simulator is.
    pub fn info(&self) -> &SimInfo {
        &self.info
    }

    /// The current step index.
    pub fn k(&self) -> u64 {
        self.k
    }

    /// The counters so far.
    pub fn stats(&self) -> &AdapterStats {
        &self.stats
    }

    /// The counters, for the free-run loop to update.
    pub fn stats_mut(&mut self) -> &mut AdapterStats {
        &mut self.stats
    }

    /// Answers one query on `leaf` with request body `body`; an error reply is counted in
    /// `stats.errors`.
    pub fn answer(&mut self, leaf: SimLeaf, body: &[u8]) -> Reply {
        let r = self.answer_inner(leaf, body);
        if r.is_err() {
            self.stats.errors += 1;
        }
        r
    }

    /// Answers a `collect` query: the reply chunks of the requested block, run in-process by
    /// the backend, or a typed error (counted in `stats.errors`). The backend is reset many
    /// times, so the lockstep state is gone afterwards: the next `step` needs a `reset`.
    pub fn answer_collect(&mut self, body: &[u8]) -> std::result::Result<Vec<Vec<u8>>, ErrorReply> {
        let r = self.collect_inner(body);
        if r.is_err() {
            self.stats.errors += 1;
        }
        r
    }

    fn collect_inner(&mut self, body: &[u8]) -> std::result::Result<Vec<Vec<u8>>, ErrorReply> {
        self.lockstep_only("collect")?;
        let req: CollectRequest = crate::services::parse_json("collect request", body)?;
        let plan = CollectPlan::new(&self.info, &req)?;
        self.has_state = false;
        self.k = 0;
        self.cache.clear();
        let w = self.backend.collect(&plan).map_err(|e| e.reply())?;
        plan.check(&w)?;
        self.stats.collected_windows += plan.windows as u64;
        Ok(plan.chunks(&w))
    }

    /// Counts and returns an error reply decided outside (e.g. a payload over the size limit).
    pub fn refuse(&mut self, e: ErrorReply) -> Reply {
        self.stats.errors += 1;
        Err(e)
    }

    fn answer_inner(&mut self, leaf: SimLeaf, body: &[u8]) -> Reply {
        match leaf {
            SimLeaf::Info => {
                let reply = InfoReply {
                    protocol_version: PROTOCOL_VERSION,
                    id: self.id.clone(),
                    mode: if self.free_run {
                        "free-run"
                    } else {
                        "lockstep"
                    }
                    .into(),
                    k: self.k,
                    sim: self.info.clone(),
                    stats: self.stats.clone(),
                };
                crate::services::to_json(&reply)
            }
            SimLeaf::Reset => {
                self.lockstep_only("reset")?;
                let req: ResetRequest = if body.iter().all(|b| b.is_ascii_whitespace()) {
                    ResetRequest::default()
                } else {
                    serde_json::from_slice(body).map_err(|e| {
                        ErrorReply::new(
                            ErrorCode::BadRequest,
                            format!("reset request is not valid JSON: {e}"),
                        )
                    })?
                };
                let x = self.reset(&req)?;
                Ok(StepReply {
                    k: 0,
                    t: 0.0,
                    x,
                    status: StepStatus::EMPTY,
                }
                .encode())
            }
            SimLeaf::Step => {
                self.lockstep_only("step")?;
                let req = StepRequest::decode(body).map_err(|e| e.to_reply())?;
                self.answer_step(&req)
            }
            SimLeaf::State | SimLeaf::Command => {
                Err(ErrorReply::new(ErrorCode::Unsupported, "not a queryable"))
            }
            SimLeaf::Collect => Err(ErrorReply::new(
                ErrorCode::Internal,
                "collect is answered in chunks (Lockstep::answer_collect)",
            )),
        }
    }

    fn lockstep_only(&self, what: &str) -> std::result::Result<(), ErrorReply> {
        if self.free_run {
            return Err(ErrorReply::new(
                ErrorCode::Busy,
                format!("this simulator is free-running; {what} is lockstep only"),
            ));
        }
        Ok(())
    }

    fn answer_step(&mut self, req: &StepRequest) -> Reply {
        self.check_input(&req.u)?;
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
        let (x, status) = self.step_reporting(&req.u)?;
        let reply = StepReply {
            k: self.k,
            t: self.k as f64 * self.info.dt,
            x,
            status,
        }
        .encode();
        self.cache.push_back(Cached {
            k: req.k,
            u: bits,
            reply: reply.clone(),
        });
        while self.cache.len() > self.cache_len {
            self.cache.pop_front();
        }
        Ok(reply)
    }

    /// `u` has `nu` finite values (`dimension` / `bad_request` otherwise).
    pub fn check_input(&self, u: &[f64]) -> std::result::Result<(), ErrorReply> {
        if u.len() != self.info.nu() {
            return Err(ErrorReply::new(
                ErrorCode::Dimension,
                format!(
                    "u has {} values, the simulator has {} inputs",
                    u.len(),
                    self.info.nu()
                ),
            ));
        }
        if !u.iter().all(|v| v.is_finite()) {
            return Err(ErrorReply::new(ErrorCode::BadRequest, "u is not finite"));
        }
        Ok(())
    }

    /// Resets the backend (checking `x0` first): `k = 0`, the cache is cleared. Returns `x_0`.
    pub fn reset(&mut self, req: &ResetRequest) -> std::result::Result<Vec<f64>, ErrorReply> {
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

    /// Steps the backend with `u` (already checked) and returns the next state; `k` advances.
    pub fn step(&mut self, u: &[f64]) -> std::result::Result<Vec<f64>, ErrorReply> {
        let x = self.backend.step(u).map_err(|e| e.reply())?;
        self.advanced(&x)?;
        Ok(x)
    }

    /// [`Self::step`] with the status the backend reports for the step (the lockstep reply's).
    fn step_reporting(
        &mut self,
        u: &[f64],
    ) -> std::result::Result<(Vec<f64>, StepStatus), ErrorReply> {
        let (x, status) = self.backend.step_reporting(u).map_err(|e| e.reply())?;
        self.advanced(&x)?;
        Ok((x, status))
    }

    /// Checks the state a step returned and counts the step (`k` advances).
    fn advanced(&mut self, x: &[f64]) -> std::result::Result<(), ErrorReply> {
        self.check_state(x)?;
        self.k += 1;
        self.stats.steps += 1;
        Ok(())
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
}
