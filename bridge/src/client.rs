//! The querying side: one-reply queries with typed errors and deadlines, liveliness tracking of
//! the session's participants, and a lockstep simulator client with idempotent retries.

use std::collections::HashSet;
use std::sync::mpsc::{self, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use zenoh::query::{ConsolidationMode, Reply};
use zenoh::sample::SampleKind;
use zenoh::{Session, Wait};

use crate::codec::{StepReply, StepRequest, PROTOCOL_VERSION};
use crate::error::{Error, ErrorCode, ErrorReply, Result};
use crate::keyexpr::{Keys, Role, SimLeaf};
use crate::messages::{InfoReply, ResetRequest};

/// A Zenoh session together with the key expressions of one koopbridge session.
#[derive(Clone)]
pub struct Client {
    /// The Zenoh session.
    pub session: Session,
    /// Key expressions of the koopbridge session.
    pub keys: Keys,
}

/// A query in flight; [`PendingQuery::wait`] returns its one reply.
pub struct PendingQuery {
    /// The replies, as the query's callback hands them over; disconnected once Zenoh ends the
    /// query. A callback, not Zenoh's FIFO handler: replies that arrive after the waiter has
    /// what it needs (a second model store answering `query_first_ok`) are dropped quietly
    /// instead of logged as errors on a closed channel.
    rx: mpsc::Receiver<Reply>,
    who: String,
    what: String,
    started: Instant,
    deadline: Instant,
}

impl Client {
    /// Wraps a session.
    pub fn new(session: Session, keys: Keys) -> Self {
        Client { session, keys }
    }

    /// Sends a query to `key` (no consolidation: the reply is delivered as soon as it arrives).
    /// `who` names the participant in errors.
    pub fn start(
        &self,
        key: &str,
        payload: Vec<u8>,
        timeout: Duration,
        who: &str,
    ) -> Result<PendingQuery> {
        let (tx, rx) = mpsc::channel();
        let mut g = self
            .session
            .get(key)
            .consolidation(ConsolidationMode::None)
            .timeout(timeout);
        if !payload.is_empty() {
            g = g.payload(payload);
        }
        g.callback(move |reply| {
            let _ = tx.send(reply);
        })
        .wait()
        .map_err(Error::zenoh)?;
        let started = Instant::now();
        Ok(PendingQuery {
            rx,
            who: who.to_string(),
            what: key.rsplit('/').next().unwrap_or(key).to_string(),
            started,
            deadline: started + timeout,
        })
    }

    /// Sends a query that several participants may answer (e.g. `…/models/{name}` with a model
    /// store on every trainer host) and returns the first successful reply; if none succeeds,
    /// the first error reply (or a timeout).
    pub fn query_first_ok(
        &self,
        key: &str,
        payload: Vec<u8>,
        timeout: Duration,
        who: &str,
    ) -> Result<Vec<u8>> {
        let q = self.start(key, payload, timeout, who)?;
        let mut first_err = None;
        while let Some(reply) = q
            .recv_until(q.deadline + Duration::from_millis(500))
            .ok()
            .flatten()
        {
            match q.decode(&reply) {
                Ok(payload) => return Ok(payload),
                Err(e) => {
                    first_err.get_or_insert(e);
                }
            }
        }
        Err(first_err.unwrap_or_else(|| q.timeout(format!("{} (no reply)", q.what))))
    }

    /// Sends a query and waits for its reply.
    pub fn query(
        &self,
        key: &str,
        payload: Vec<u8>,
        timeout: Duration,
        who: &str,
    ) -> Result<Vec<u8>> {
        self.start(key, payload, timeout, who)?.wait(None)
    }
}

impl PendingQuery {
    /// Waits for the first reply: its payload, or the typed error it carries. With `watch`, fails
    /// early with [`Error::Gone`] when participant `(role, id)` loses its liveliness token.
    pub fn wait(self, watch: Option<(&Liveliness, Role, &str)>) -> Result<Vec<u8>> {
        let mut first = None;
        self.wait_many(watch, |b| {
            first = Some(b);
            Ok(true)
        })?;
        first.ok_or_else(|| Error::Config("a query ended without its reply".into()))
    }

    /// Waits for the replies of a query answered in several replies (the chunks of `collect`):
    /// `on_reply` gets each payload in arrival order and returns `true` once it has all it
    /// needs (or an error, which ends the wait). An error reply ends the wait with its typed
    /// error; the query ending first is a timeout. `watch` as for [`PendingQuery::wait`].
    pub fn wait_many(
        self,
        watch: Option<(&Liveliness, Role, &str)>,
        mut on_reply: impl FnMut(Vec<u8>) -> Result<bool>,
    ) -> Result<()> {
        let mut replies = 0usize;
        loop {
            let now = Instant::now();
            let slice_end =
                (now + Duration::from_millis(25)).min(self.deadline + Duration::from_millis(500));
            match self.recv_until(slice_end) {
                Ok(Some(reply)) => {
                    replies += 1;
                    if on_reply(self.decode(&reply)?)? {
                        return Ok(());
                    }
                }
                Ok(None) => {}
                Err(_) => {
                    // Channel closed: the query finished without (all) its replies. If the
                    // participant is watched, give its liveliness token a moment to be withdrawn
                    // (a process that died takes its queryable and its token down at about the
                    // same time).
                    if let Some((l, role, id)) = watch {
                        let until = Instant::now() + Duration::from_millis(500);
                        while Instant::now() < until {
                            if l.is_gone(role, id) {
                                return Err(Error::Gone(self.who.clone()));
                            }
                            std::thread::sleep(Duration::from_millis(10));
                        }
                    }
                    let what = match replies {
                        0 => format!("{} (no reply)", self.what),
                        n => format!("{} (the query ended after {n} of its replies)", self.what),
                    };
                    return Err(self.timeout(what));
                }
            }
            if let Some((l, role, id)) = watch {
                if l.is_gone(role, id) {
                    return Err(Error::Gone(self.who.clone()));
                }
            }
            if Instant::now() > self.deadline + Duration::from_millis(500) {
                return Err(self.timeout(self.what.clone()));
            }
        }
    }

    /// The reply's payload, or the typed error it carries. Zenoh's own error reply `Timeout`
    /// (sent by this session, or by a router on the way, when no answer came in time) is
    /// [`Error::Timeout`], not an error of the participant: the caller may retry it.
    fn decode(&self, reply: &Reply) -> Result<Vec<u8>> {
        match reply.result() {
            Ok(sample) => Ok(sample.payload().to_bytes().into_owned()),
            Err(e) if e.payload().to_bytes().as_ref() == b"Timeout" => {
                Err(self.timeout(format!("{} (no reply in time)", self.what)))
            }
            Err(e) => Err(Error::Remote {
                who: self.who.clone(),
                reply: ErrorReply::from_json(&e.payload().to_bytes()),
            }),
        }
    }

    /// The next reply: `Ok(None)` when none came by `deadline`, `Err(())` once the query has
    /// ended (every reply delivered).
    fn recv_until(&self, deadline: Instant) -> std::result::Result<Option<Reply>, ()> {
        match self
            .rx
            .recv_timeout(deadline.saturating_duration_since(Instant::now()))
        {
            Ok(r) => Ok(Some(r)),
            Err(RecvTimeoutError::Timeout) => Ok(None),
            Err(RecvTimeoutError::Disconnected) => Err(()),
        }
    }

    /// A timeout of this query waiting for `what`, timed from its start.
    fn timeout(&self, what: String) -> Error {
        Error::Timeout {
            who: self.who.clone(),
            what,
            after_ms: self.started.elapsed().as_millis() as u64,
        }
    }
}

/// Tracks the liveliness tokens of a koopbridge session (`…/alive/{role}/{id}`).
pub struct Liveliness {
    state: Arc<Mutex<LiveState>>,
    _sub: zenoh::pubsub::Subscriber<()>,
}

#[derive(Default)]
struct LiveState {
    alive: HashSet<String>,
    gone: HashSet<String>,
}

impl Liveliness {
    /// Starts tracking (asks for the tokens already alive, then follows changes).
    pub fn new(client: &Client) -> Result<Self> {
        let state = Arc::new(Mutex::new(LiveState::default()));
        let st = state.clone();
        let keys = client.keys.clone();
        let sub = client
            .session
            .liveliness()
            .declare_subscriber(keys.alive_all())
            .history(true)
            .callback(move |s| {
                if let Some((role, id)) = keys.parse_alive(s.key_expr().as_str()) {
                    let name = format!("{role}/{id}");
                    let mut st = st.lock().unwrap_or_else(|e| e.into_inner());
                    match s.kind() {
                        SampleKind::Put => {
                            st.gone.remove(&name);
                            st.alive.insert(name);
                        }
                        SampleKind::Delete => {
                            st.alive.remove(&name);
                            st.gone.insert(name);
                        }
                    }
                }
            })
            .wait()
            .map_err(Error::zenoh)?;
        Ok(Liveliness { state, _sub: sub })
    }

    fn name(role: Role, id: &str) -> String {
        format!("{}/{id}", role.as_str())
    }

    /// Whether `(role, id)` currently holds a token.
    pub fn is_alive(&self, role: Role, id: &str) -> bool {
        self.state
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .alive
            .contains(&Self::name(role, id))
    }

    /// Whether `(role, id)` held a token that has since disappeared.
    pub fn is_gone(&self, role: Role, id: &str) -> bool {
        self.state
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .gone
            .contains(&Self::name(role, id))
    }

    /// Ids of the participants of `role` that currently hold a token, sorted.
    pub fn alive_ids(&self, role: Role) -> Vec<String> {
        let prefix = format!("{}/", role.as_str());
        let st = self.state.lock().unwrap_or_else(|e| e.into_inner());
        let mut ids: Vec<String> = st
            .alive
            .iter()
            .filter_map(|n| n.strip_prefix(&prefix).map(str::to_string))
            .collect();
        ids.sort();
        ids
    }

    /// Waits until every participant in `who` is alive; the error names those still missing.
    pub fn wait_for(&self, who: &[(Role, String)], timeout: Duration) -> Result<()> {
        let deadline = Instant::now() + timeout;
        loop {
            let missing: Vec<String> = who
                .iter()
                .filter(|(r, id)| !self.is_alive(*r, id))
                .map(|(r, id)| Self::name(*r, id))
                .collect();
            if missing.is_empty() {
                return Ok(());
            }
            if Instant::now() > deadline {
                return Err(Error::Timeout {
                    who: missing.join(", "),
                    what: "liveliness token".into(),
                    after_ms: timeout.as_millis() as u64,
                });
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

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
        let key = self.client.keys.sim(&self.id, SimLeaf::Reset)?;
        let body = serde_json::to_vec(req).map_err(|e| Error::Config(e.to_string()))?;
        let began = Instant::now();
        let mut unroutable = 0;
        let b = loop {
            match self
                .client
                .query(&key, body.clone(), self.timeout, &self.who())
            {
                Err(Error::Timeout { after_ms, .. })
                    if self.may_resend_unroutable(began, after_ms, unroutable) =>
                {
                    self.wait_unroutable("reset", &mut unroutable)
                }
                Err(Error::Timeout { who, what, .. }) => {
                    return Err(Error::Timeout {
                        who,
                        what,
                        after_ms: began.elapsed().as_millis() as u64,
                    })
                }
                r => break r?,
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

    /// Sleeps resend no. `unroutable`'s backoff (warning on the first) and counts it.
    fn wait_unroutable(&self, what: &str, unroutable: &mut u32) {
        if *unroutable == 0 {
            tracing::warn!(
                "{} is not routable for {what} {}; re-sending until it is (for up to {:?})",
                self.who(),
                self.k,
                self.timeout
            );
        }
        std::thread::sleep(unroutable_backoff(*unroutable));
        *unroutable += 1;
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
                    self.wait_unroutable("step", &mut unroutable);
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
                Err(Error::Timeout { who, what, .. }) => {
                    return Err(Error::Timeout {
                        who,
                        what,
                        after_ms: began.elapsed().as_millis() as u64,
                    })
                }
                Err(e) => return Err(e),
            }
        }
    }

    /// One step: send `u_k`, wait for `x_{k+1}`.
    pub fn step(&mut self, u: &[f64], live: Option<&Liveliness>) -> Result<StepReply> {
        let p = self.start_step(u)?;
        self.finish_step(p, u, live)
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
    use crate::session::{open_session, ZenohOptions};

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
}
