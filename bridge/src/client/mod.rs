//! The querying side: one-reply queries with typed errors and deadlines, liveliness tracking of
//! the session's participants, and ([`sim`]) a lockstep simulator client with idempotent retries.

mod sim;

pub use sim::{step_all, SimClient};

use std::collections::HashSet;
use std::sync::mpsc::{self, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use zenoh::query::{ConsolidationMode, Reply};
use zenoh::sample::SampleKind;
use zenoh::{Session, Wait};

use crate::error::{Error, ErrorReply, Result};
use crate::keyexpr::{Keys, Role};

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
