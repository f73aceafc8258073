//! A lockstep client of one simulator: `info` as the readiness barrier, `reset`, `step` with
//! idempotent retries, and requests that found no route re-sent while the step timeout lasts.

use std::time::{Duration, Instant};

use super::{Client, Liveliness, PendingQuery};
use crate::codec::{StepReply, StepRequest, PROTOCOL_VERSION};
use crate::error::{Error, ErrorCode, Result};
use crate::keyexpr::{Role, SimLeaf};
use crate::messages::{InfoReply, ResetRequest};

/// A lockstep client of one simulator: `info`, `reset`, `step` with idempotent retries.
pub struct SimClient {
    client: Client,
    /// The simulator id.
    pub id: String,
    /// Its `info` reply (from [`SimClient::connect`]).
    pub info: InfoReply,
    /// The step index of its current state.
    pub k: u64,
    /// Timeout of one step attempt.
    pub timeout: Duration,
    /// How many times a timed-out step is re-sent (the adapter answers retries from its cache).
    pub retries: usize,
    step_key: String,
}

impl SimClient {
    /// The readiness barrier for one simulator: `info` is queried until it answers (a `get` sent
    /// before the queryable is routed gets no reply) or `timeout` passes. Checks the version.
    pub fn connect(client: &Client, id: &str, timeout: Duration) -> Result<Self> {
        let key = client.keys.sim(id, SimLeaf::Info)?;
        let who = format!("simulator '{id}'");
        let deadline = Instant::now() + timeout;
        let bytes = loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match client.query(&key, Vec::new(), left.min(Duration::from_secs(2)), &who) {
                Ok(b) => break b,
                Err(Error::Timeout { .. }) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(50))
                }
                // The whole wait, not the last query's remnant of it.
                Err(Error::Timeout { who, .. }) => {
                    return Err(Error::Timeout {
                        who,
                        what: "info (no reply; is it running, on this session and reachable?)"
                            .into(),
                        after_ms: timeout.as_millis() as u64,
                    })
                }
                Err(e) => return Err(e),
            }
        };
        let info: InfoReply = serde_json::from_slice(&bytes).map_err(|e| {
            Error::protocol(
                ErrorCode::BadRequest,
                format!("{who}: info reply is not valid: {e}"),
            )
        })?;
        if info.protocol_version != PROTOCOL_VERSION {
            return Err(Error::protocol(
                ErrorCode::VersionMismatch,
                format!(
                    "{who} speaks protocol version {}, this orchestrator speaks {PROTOCOL_VERSION}",
                    info.protocol_version
                ),
            ));
        }
        Ok(SimClient {
            client: client.clone(),
            id: id.to_string(),
            k: info.k,
            info,
            timeout: Duration::from_secs(10),
            retries: 2,
            step_key: client.keys.sim(id, SimLeaf::Step)?,
        })
    }

    fn who(&self) -> String {
        format!("simulator '{}'", self.id)
    }

    /// The session client this simulator is reached through.
    pub fn client(&self) -> &Client {
        &self.client
    }

    /// Re-reads `info` (e.g. for the adapter's counters).
    pub fn refresh_info(&mut self) -> Result<&InfoReply> {
        let key = self.client.keys.sim(&self.id, SimLeaf::Info)?;
        let b = self
            .client
            .query(&key, Vec::new(), self.timeout, &self.who())?;
        self.info = serde_json::from_slice(&b)
            .map_err(|e| Error::protocol(ErrorCode::BadRequest, format!("info reply: {e}")))?;
        Ok(&self.info)
    }

    /// Resets; returns the first state.
    pub fn reset(&mut self, req: &ResetRequest) -> Result<StepReply> {
        self.reset_watched(req, None)
    }

    /// Resets, as [`SimClient::reset`]; with `live`, a simulator that loses its liveliness
    /// token ends the wait at once with [`Error::Gone`] (a reset re-sent while the simulator is
    /// unroutable would otherwise wait out the step timeout for a simulator that died).
    pub fn reset_watched(
        &mut self,
        req: &ResetRequest,
        live: Option<&Liveliness>,
    ) -> Result<StepReply> {
        let key = self.client.keys.sim(&self.id, SimLeaf::Reset)?;
        let body = serde_json::to_vec(req).map_err(|e| Error::Config(e.to_string()))?;
        let began = Instant::now();
        let mut unroutable = 0;
        let b = loop {
            let watch = live.map(|l| (l, Role::Sim, self.id.as_str()));
            let pending = self
                .client
                .start(&key, body.clone(), self.timeout, &self.who())?;
            match pending.wait(watch) {
                Err(Error::Timeout { after_ms, .. })
                    if self.may_resend_unroutable(began, after_ms, unroutable) =>
                {
                    self.wait_unroutable("reset", &mut unroutable, live)?
                }
                Err(e) => return Err(whole_wait(e, began)),
                Ok(b) => break b,
            }
        };
        let r = StepReply::decode(&b)?;
        self.k = r.k;
        Ok(r)
    }

    /// Sends the step request for the current `k` without waiting.
    pub fn start_step(&self, u: &[f64]) -> Result<PendingQuery> {
        let body = StepRequest {
            k: self.k,
            u: u.to_vec(),
        }
        .encode();
        self.client
            .start(&self.step_key, body, self.timeout, &self.who())
    }

    /// Whether a request whose query ended after `after_ms` with no reply found no route to the
    /// simulator and may be sent again: it ended well before its deadline (nothing answered it,
    /// so nothing was applied twice: the adapter answers a repeated step from its cache) and
    /// the backoff of resend no. `unroutable` still fits in the step timeout counted from `began`.
    /// Seen through a router re-establishing a simulator's link under load (a TLS router in CI):
    /// the queryable is unroutable for a moment and every query ends at once.
    fn may_resend_unroutable(&self, began: Instant, after_ms: u64, unroutable: u32) -> bool {
        let ended_early = u128::from(after_ms) * 2 < self.timeout.as_millis();
        ended_early && began.elapsed() + unroutable_backoff(unroutable) < self.timeout
    }

    /// Sleeps resend no. `unroutable`'s backoff (warning on the first) and counts it. With
    /// `live`, ends early with [`Error::Gone`] once the simulator's liveliness token is withdrawn:
    /// a simulator that died is unroutable too, and its token may be withdrawn only after the
    /// query that found no route has ended.
    fn wait_unroutable(
        &self,
        what: &str,
        unroutable: &mut u32,
        live: Option<&Liveliness>,
    ) -> Result<()> {
        if *unroutable == 0 {
            tracing::warn!(
                "{} is not routable for {what} {}; re-sending until it is (for up to {:?})",
                self.who(),
                self.k,
                self.timeout
            );
        }
        let until = Instant::now() + unroutable_backoff(*unroutable);
        *unroutable += 1;
        loop {
            if live.is_some_and(|l| l.is_gone(Role::Sim, &self.id)) {
                return Err(Error::Gone(self.who()));
            }
            let left = until.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(());
            }
            std::thread::sleep(left.min(Duration::from_millis(10)));
        }
    }

    /// Waits for a step started by [`SimClient::start_step`]; a request that found no route is
    /// re-sent with backoff while the step timeout lasts; one that timed out is re-sent up to
    /// `retries` times; checks that the reply's k is k + 1.
    pub fn finish_step(
        &mut self,
        pending: PendingQuery,
        u: &[f64],
        live: Option<&Liveliness>,
    ) -> Result<StepReply> {
        let mut pending = pending;
        let mut attempt = 0;
        let began = Instant::now();
        let mut unroutable = 0;
        loop {
            let watch = live.map(|l| (l, Role::Sim, self.id.as_str()));
            match pending.wait(watch) {
                Ok(b) => {
                    let r = StepReply::decode(&b)?;
                    if r.k != self.k + 1 {
                        return Err(Error::protocol(
                            ErrorCode::OutOfOrder,
                            format!(
                                "{} answered step {} with k = {}, expected {}",
                                self.who(),
                                self.k,
                                r.k,
                                self.k + 1
                            ),
                        ));
                    }
                    if r.x.len() != self.info.sim.nx() {
                        return Err(Error::protocol(
                            ErrorCode::Dimension,
                            format!(
                                "{} returned {} state values, info says {}",
                                self.who(),
                                r.x.len(),
                                self.info.sim.nx()
                            ),
                        ));
                    }
                    self.k = r.k;
                    return Ok(r);
                }
                Err(Error::Timeout { after_ms, .. })
                    if self.may_resend_unroutable(began, after_ms, unroutable) =>
                {
                    self.wait_unroutable("step", &mut unroutable, live)?;
                    pending = self.start_step(u)?;
                }
                Err(Error::Timeout { .. }) if attempt < self.retries => {
                    attempt += 1;
                    tracing::warn!(
                        "{} did not answer step {}; retry {attempt}",
                        self.who(),
                        self.k
                    );
                    pending = self.start_step(u)?;
                }
                Err(e) => return Err(whole_wait(e, began)),
            }
        }
    }

    /// One step: send `u_k`, wait for `x_{k+1}`.
    pub fn step(&mut self, u: &[f64], live: Option<&Liveliness>) -> Result<StepReply> {
        let p = self.start_step(u)?;
        self.finish_step(p, u, live)
    }
}

/// `e`, a timeout naming the whole wait since `began` (its retries and resends included).
fn whole_wait(e: Error, began: Instant) -> Error {
    match e {
        Error::Timeout { who, what, .. } => Error::Timeout {
            who,
            what,
            after_ms: began.elapsed().as_millis() as u64,
        },
        e => e,
    }
}

/// The wait before resend no. `n` of a request that found no route: 25 ms, doubling to 400 ms.
fn unroutable_backoff(n: u32) -> Duration {
    Duration::from_millis(25 << n.min(4))
}

/// Steps every simulator concurrently (all requests first, then all replies) with its own input.
/// The first failure is returned, naming its simulator.
pub fn step_all(
    sims: &mut [SimClient],
    inputs: &[Vec<f64>],
    live: Option<&Liveliness>,
) -> Result<Vec<StepReply>> {
    if sims.len() != inputs.len() {
        return Err(Error::Config(format!(
            "{} simulators but {} inputs",
            sims.len(),
            inputs.len()
        )));
    }
    let pending: Vec<PendingQuery> = sims
        .iter()
        .zip(inputs)
        .map(|(s, u)| s.start_step(u))
        .collect::<Result<_>>()?;
    sims.iter_mut()
        .zip(pending)
        .zip(inputs)
        .map(|((s, p), u)| s.finish_step(p, u, live))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::keyexpr::Keys;
    use crate::session::{open_session, ZenohOptions};
    use zenoh::Wait;

    /// A simulator that never answers: the timeout names the whole wait, not the last query's
    /// remnant of it (it used to say "after 0 ms").
    #[test]
    fn connecting_to_an_absent_simulator_times_out_naming_the_whole_wait() {
        let s = open_session(&ZenohOptions::default()).unwrap();
        let c = Client::new(s, Keys::new("absent-sim-test").unwrap());
        let wait = Duration::from_millis(2500);
        let t = Instant::now();
        match SimClient::connect(&c, "nobody", wait) {
            Err(Error::Timeout { who, after_ms, .. }) => {
                assert_eq!(after_ms, 2500);
                assert!(who.contains("nobody"), "{who}");
            }
            Err(e) => panic!("expected a timeout, got {e}"),
            Ok(_) => panic!("connected to a simulator that does not exist"),
        }
        assert!(t.elapsed() >= wait, "gave up early: {:?}", t.elapsed());
    }

    /// A lockstep client of simulator `id` without its `info` barrier: `nx` 1, at step 0.
    fn bare_sim_client(c: &Client, id: &str, timeout: Duration) -> SimClient {
        let info = InfoReply {
            protocol_version: PROTOCOL_VERSION,
            id: id.into(),
            mode: "lockstep".into(),
            k: 0,
            sim: crate::messages::SimInfo {
                env: "test".into(),
                kind: "test".into(),
                version: "0".into(),
                dt: 0.1,
                state_names: vec!["x".into()],
                input_names: vec!["u".into()],
                u_min: vec![f64::NEG_INFINITY],
                u_max: vec![f64::INFINITY],
                angle_indices: vec![],
                extra: Default::default(),
            },
            stats: Default::default(),
        };
        SimClient {
            client: c.clone(),
            id: id.into(),
            info,
            k: 0,
            timeout,
            retries: 2,
            step_key: c.keys.sim(id, SimLeaf::Step).unwrap(),
        }
    }

    /// A step sent while the simulator's queryable is not routable (every query ends at once)
    /// is sent again until it is: here the queryable appears 400 ms later, well past the two
    /// retries' worth of immediate failures, and the step gets its reply.
    #[test]
    fn a_step_is_resent_until_the_simulator_is_routable() {
        let s = open_session(&ZenohOptions::default()).unwrap();
        let c = Client::new(s.clone(), Keys::new("unroutable-sim-test").unwrap());
        let key = c.keys.sim("late", SimLeaf::Step).unwrap();
        let server = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(400));
            let q = s.declare_queryable(key).wait().unwrap();
            let query = q.recv().unwrap();
            let req = StepRequest::decode(&query.payload().unwrap().to_bytes()).unwrap();
            let reply = StepReply {
                k: req.k + 1,
                t: 0.1,
                x: vec![req.u[0] * 2.0],
                status: Default::default(),
            };
            query
                .reply(query.key_expr().clone(), reply.encode())
                .wait()
                .unwrap();
            std::thread::sleep(Duration::from_millis(200));
        });
        let mut sim = bare_sim_client(&c, "late", Duration::from_secs(3));
        let t = Instant::now();
        let r = sim.step(&[0.5], None).unwrap();
        assert_eq!((r.k, r.x.clone()), (1, vec![1.0]));
        assert!(
            t.elapsed() >= Duration::from_millis(400),
            "{:?}",
            t.elapsed()
        );
        server.join().unwrap();
    }

    /// A simulator that never becomes routable: the step gives up once its timeout has passed
    /// (not after the retries' few immediate failures) and the error names the whole wait.
    #[test]
    fn an_unroutable_simulator_times_out_after_the_step_timeout() {
        let s = open_session(&ZenohOptions::default()).unwrap();
        let c = Client::new(s, Keys::new("unroutable-sim-test-2").unwrap());
        let wait = Duration::from_millis(800);
        let mut sim = bare_sim_client(&c, "nobody", wait);
        let t = Instant::now();
        match sim.step(&[0.5], None) {
            Err(Error::Timeout { after_ms, .. }) => {
                assert!(after_ms >= 400, "gave up after {after_ms} ms");
                assert!(t.elapsed() < wait * 2, "{:?}", t.elapsed());
            }
            other => panic!("expected a timeout, got {other:?}"),
        }
    }

    /// A simulator that dies is unroutable too: once its liveliness token is withdrawn the
    /// resending of `request` stops and it fails as gone, long before the step timeout (a killed
    /// adapter used to hold a run for the whole step timeout).
    fn request_to_a_dying_simulator_fails_as_gone(
        prefix: &str,
        request: impl FnOnce(&mut SimClient, &Liveliness) -> Result<StepReply>,
    ) {
        let s = open_session(&ZenohOptions::default()).unwrap();
        let c = Client::new(s.clone(), Keys::new(prefix).unwrap());
        let live = Liveliness::new(&c).unwrap();
        let token = s
            .liveliness()
            .declare_token(c.keys.alive(Role::Sim, "dying").unwrap())
            .wait()
            .unwrap();
        live.wait_for(&[(Role::Sim, "dying".into())], Duration::from_secs(5))
            .unwrap();
        let withdraw = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(1200));
            token.undeclare().wait().unwrap();
        });
        let mut sim = bare_sim_client(&c, "dying", Duration::from_secs(10));
        let t = Instant::now();
        let r = request(&mut sim, &live);
        withdraw.join().unwrap();
        assert!(matches!(r, Err(Error::Gone(_))), "{r:?}");
        assert!(t.elapsed() < Duration::from_secs(3), "{:?}", t.elapsed());
    }

    #[test]
    fn a_step_to_a_simulator_whose_token_is_withdrawn_fails_as_gone_at_once() {
        request_to_a_dying_simulator_fails_as_gone("dying-sim-step", |sim, live| {
            sim.step(&[0.5], Some(live))
        });
    }

    #[test]
    fn a_reset_of_a_simulator_whose_token_is_withdrawn_fails_as_gone_at_once() {
        request_to_a_dying_simulator_fails_as_gone("dying-sim-reset", |sim, live| {
            sim.reset_watched(&ResetRequest::default(), Some(live))
        });
    }
}
