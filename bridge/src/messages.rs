//! JSON control-plane messages: simulator info, reset requests, adapter statistics.

use serde::{Deserialize, Serialize};

/// What a simulator is: dimensions, names, timing, bounds. Provided by the backend.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SimInfo {
    /// Environment or model name (e.g. `damped-pendulum`).
    pub env: String,
    /// Simulator kind (e.g. `koopbridge-rust`, `fmu`, `mujoco`).
    pub kind: String,
    /// Simulator version string.
    pub version: String,
    /// Sampling period in seconds (one `step`).
    pub dt: f64,
    /// Names of the state components (`nx` of them).
    pub state_names: Vec<String>,
    /// Names of the input components (`nu` of them).
    pub input_names: Vec<String>,
    /// Lower input bounds (`nu`).
    pub u_min: Vec<f64>,
    /// Upper input bounds (`nu`).
    pub u_max: Vec<f64>,
    /// Indices of angle components of the state (wrapped when measuring errors).
    #[serde(default)]
    pub angle_indices: Vec<usize>,
}

impl SimInfo {
    /// State dimension.
    pub fn nx(&self) -> usize {
        self.state_names.len()
    }
    /// Input dimension.
    pub fn nu(&self) -> usize {
        self.input_names.len()
    }
    /// The info of a built-in reference system.
    pub fn from_system(sys: &dyn koopman::systems::System) -> Self {
        let (u_min, u_max) = sys.input_bounds();
        SimInfo {
            env: sys.name().to_string(),
            kind: "koopbridge-rust".into(),
            version: env!("CARGO_PKG_VERSION").into(),
            dt: sys.dt(),
            state_names: sys.state_names(),
            input_names: sys.input_names(),
            u_min,
            u_max,
            angle_indices: sys.angle_indices(),
        }
    }
}

/// Counters kept by an adapter (returned in `info` and by `serve`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct AdapterStats {
    /// Steps actually taken by the backend (lockstep and free-run).
    pub steps: u64,
    /// Resets.
    pub resets: u64,
    /// Step requests answered from the per-k cache (retries), not stepped again.
    pub cache_hits: u64,
    /// Requests answered with an error reply.
    pub errors: u64,
    /// Free-run: states published.
    pub published: u64,
    /// Free-run: ticks whose latest command answered an older state than the current one.
    pub late_commands: u64,
    /// Free-run: ticks without any new command (after the first one arrived).
    pub missing_commands: u64,
    /// Free-run: ticks that started more than one period after their deadline.
    pub overruns: u64,
    /// Free-run: the largest lateness of a tick against its deadline, in microseconds.
    pub max_lateness_us: u64,
    /// Free-run: simulated time over wall time since the start of the run.
    pub real_time_factor: f64,
}

/// The JSON reply of `…/sim/{id}/info`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InfoReply {
    /// Protocol version spoken by the adapter.
    pub protocol_version: u8,
    /// The adapter's id (the `{id}` chunk).
    pub id: String,
    /// `lockstep` or `free-run`.
    pub mode: String,
    /// Current step index.
    pub k: u64,
    /// What the simulator is.
    #[serde(flatten)]
    pub sim: SimInfo,
    /// Counters so far.
    pub stats: AdapterStats,
}

/// The JSON query of `…/sim/{id}/reset`: a seed (initial state drawn by the simulator) or an
/// explicit initial state. Both absent: the simulator's default initial state.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ResetRequest {
    /// Seed for the initial-state draw.
    #[serde(default)]
    pub seed: Option<u64>,
    /// Explicit initial state (`nx` values).
    #[serde(default)]
    pub x0: Option<Vec<f64>>,
}
