//! Key expressions of the protocol (`koopbridge/{session}/…`), built from validated chunks.

use crate::error::{Error, ErrorCode, Result};

/// The root of every key expression.
pub const ROOT: &str = "koopbridge";

/// Checks that `chunk` is a non-empty `[a-z0-9_-]+` string (no `/`, `*`, `@`, `$`).
pub fn validate_chunk(what: &str, chunk: &str) -> Result<()> {
    if chunk.is_empty() || chunk.len() > 64 {
        return Err(Error::protocol(
            ErrorCode::BadRequest,
            format!("{what} must be 1 to 64 characters, got {:?}", chunk),
        ));
    }
    if let Some(c) = chunk
        .chars()
        .find(|c| !(c.is_ascii_lowercase() || c.is_ascii_digit() || *c == '_' || *c == '-'))
    {
        return Err(Error::protocol(
            ErrorCode::BadRequest,
            format!("{what} {chunk:?} contains {c:?}; only [a-z0-9_-] is allowed"),
        ));
    }
    Ok(())
}

/// A fresh session id: `s` + 16 hex digits from the clock, the process id and a counter.
pub fn fresh_session_id() -> String {
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0);
    let mut h = nanos ^ (u64::from(std::process::id()) << 32);
    h ^= COUNTER
        .fetch_add(1, Ordering::Relaxed)
        .wrapping_mul(0x9E37_79B9_7F4A_7C15);
    h = (h ^ (h >> 31)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    format!("s{:016x}", h ^ (h >> 29))
}

/// Builds the key expressions of one session (`koopbridge/{session}/…`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Keys {
    session: String,
}

impl Keys {
    /// Keys for session `session` (validated).
    pub fn new(session: &str) -> Result<Self> {
        validate_chunk("session id", session)?;
        Ok(Keys {
            session: session.to_string(),
        })
    }

    /// The session id.
    pub fn session(&self) -> &str {
        &self.session
    }

    fn key(&self, parts: &[&str]) -> String {
        let mut s = format!("{ROOT}/{}", self.session);
        for p in parts {
            s.push('/');
            s.push_str(p);
        }
        s
    }

    fn checked(&self, what: &str, id: &str, parts: &[&str]) -> Result<String> {
        validate_chunk(what, id)?;
        Ok(self.key(parts))
    }

    /// `…/sim/{id}/{leaf}` where leaf is `info`, `reset`, `step`, `state`, `command` or `collect`.
    pub fn sim(&self, id: &str, leaf: SimLeaf) -> Result<String> {
        self.checked("sim id", id, &["sim", id, leaf.as_str()])
    }

    /// `…/trainer/{id}/jobs`.
    pub fn trainer_jobs(&self, id: &str) -> Result<String> {
        self.checked("trainer id", id, &["trainer", id, "jobs"])
    }

    /// `…/trainer/{id}/jobs/{job}` (job status queries are served under the `jobs/**` queryable).
    pub fn trainer_job(&self, id: &str, job: &str) -> Result<String> {
        validate_chunk("job id", job)?;
        self.checked("trainer id", id, &["trainer", id, "jobs", job])
    }

    /// `…/trainer/{id}/jobs/{job}/progress`.
    pub fn trainer_progress(&self, id: &str, job: &str) -> Result<String> {
        validate_chunk("job id", job)?;
        self.checked("trainer id", id, &["trainer", id, "jobs", job, "progress"])
    }

    /// `…/models/{name}`.
    pub fn model(&self, name: &str) -> Result<String> {
        self.checked("model name", name, &["models", name])
    }

    /// `…/mpc/{id}/solve`.
    pub fn mpc_solve(&self, id: &str) -> Result<String> {
        self.checked("mpc id", id, &["mpc", id, "solve"])
    }

    /// `…/mpc/{id}/configure`.
    pub fn mpc_configure(&self, id: &str) -> Result<String> {
        self.checked("mpc id", id, &["mpc", id, "configure"])
    }

    /// `…/mpc/{id}/attach`.
    pub fn mpc_attach(&self, id: &str) -> Result<String> {
        self.checked("mpc id", id, &["mpc", id, "attach"])
    }

    /// `…/planner/{id}/plan` (a trajectory planner's queryable).
    pub fn planner_plan(&self, id: &str) -> Result<String> {
        self.checked("planner id", id, &["planner", id, "plan"])
    }

    /// `…/data/{name}`.
    pub fn data(&self, name: &str) -> Result<String> {
        self.checked("dataset name", name, &["data", name])
    }

    /// `…/recorder/{id}/record` (control: start/stop a recording).
    pub fn recorder(&self, id: &str) -> Result<String> {
        self.checked("recorder id", id, &["recorder", id, "record"])
    }

    /// `…/view/events`: the run's events for a viewer (PROTOCOL.md §10).
    pub fn view_events(&self) -> String {
        self.key(&["view", "events"])
    }

    /// `…/view/{sim}/step`: simulator `sim`'s closed-loop states for a viewer.
    pub fn view_step(&self, sim: &str) -> Result<String> {
        self.checked("sim id", sim, &["view", sim, "step"])
    }

    /// `…/alive/{role}/{id}`.
    pub fn alive(&self, role: Role, id: &str) -> Result<String> {
        self.checked("participant id", id, &["alive", role.as_str(), id])
    }

    /// `…/alive/**`: every liveliness token of the session.
    pub fn alive_all(&self) -> String {
        self.key(&["alive", "**"])
    }

    /// `…/**`: everything of this session (for wildcard queryables like `models/*`).
    pub fn under(&self, parts: &[&str]) -> String {
        self.key(parts)
    }

    /// Parses `…/alive/{role}/{id}` back into `(role, id)`.
    pub fn parse_alive(&self, key: &str) -> Option<(String, String)> {
        let prefix = self.key(&["alive", ""]);
        let rest = key.strip_prefix(&prefix)?;
        let (role, id) = rest.split_once('/')?;
        Some((role.to_string(), id.to_string()))
    }
}

/// The leaves under `…/sim/{id}/`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SimLeaf {
    /// `info` queryable.
    Info,
    /// `reset` queryable.
    Reset,
    /// `step` queryable.
    Step,
    /// `state` publication (free-run).
    State,
    /// `command` subscription (free-run).
    Command,
    /// `collect` queryable (blocks of windows run in-process, replied in chunks).
    Collect,
}

impl SimLeaf {
    /// The chunk.
    pub fn as_str(self) -> &'static str {
        match self {
            SimLeaf::Info => "info",
            SimLeaf::Reset => "reset",
            SimLeaf::Step => "step",
            SimLeaf::State => "state",
            SimLeaf::Command => "command",
            SimLeaf::Collect => "collect",
        }
    }
}

/// Roles of participants (the `{role}` chunk of liveliness tokens).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// A simulator adapter.
    Sim,
    /// A trainer service.
    Trainer,
    /// An MPC service.
    Mpc,
    /// A recorder service.
    Recorder,
    /// A model store.
    Models,
    /// An orchestrator.
    Orchestrator,
    /// A trajectory planner.
    Planner,
    /// A viewer (`python -m koopbridge.view`).
    Viewer,
}

impl Role {
    /// The chunk.
    pub fn as_str(self) -> &'static str {
        match self {
            Role::Sim => "sim",
            Role::Trainer => "trainer",
            Role::Mpc => "mpc",
            Role::Recorder => "recorder",
            Role::Models => "models",
            Role::Orchestrator => "orchestrator",
            Role::Planner => "planner",
            Role::Viewer => "viewer",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_are_built_and_chunks_validated() {
        let k = Keys::new("s1").unwrap();
        assert_eq!(
            k.sim("pend-0", SimLeaf::Step).unwrap(),
            "koopbridge/s1/sim/pend-0/step"
        );
        assert_eq!(
            k.trainer_progress("t", "j1").unwrap(),
            "koopbridge/s1/trainer/t/jobs/j1/progress"
        );
        assert_eq!(
            k.planner_plan("p0").unwrap(),
            "koopbridge/s1/planner/p0/plan"
        );
        assert_eq!(
            k.mpc_configure("m").unwrap(),
            "koopbridge/s1/mpc/m/configure"
        );
        assert_eq!(
            k.alive(Role::Mpc, "m").unwrap(),
            "koopbridge/s1/alive/mpc/m"
        );
        assert_eq!(
            k.parse_alive("koopbridge/s1/alive/sim/a_b"),
            Some(("sim".into(), "a_b".into()))
        );
        for bad in ["", "A", "a/b", "a*", "@x", "a b", "é", &"x".repeat(65)] {
            assert!(Keys::new(bad).is_err(), "{bad:?} accepted");
            assert!(
                k.sim(bad, SimLeaf::Info).is_err(),
                "{bad:?} accepted as sim id"
            );
        }
        let a = fresh_session_id();
        let b = fresh_session_id();
        assert_ne!(a, b);
        assert!(Keys::new(&a).is_ok());
    }
}
