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
    /// What the backend says about itself beyond the fields above, free-form JSON (e.g. an FMU
    /// adapter's `{"fmu": {"fmi_version", "units", "start", "variables": [...]}}`); absent for
    /// the built-in systems. Orchestrators pass it through and never depend on it.
    #[serde(default, skip_serializing_if = "serde_json::Map::is_empty")]
    pub extra: serde_json::Map<String, serde_json::Value>,
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
            extra: serde_json::Map::new(),
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
    /// Free-run: commands with a value outside the simulator's `[u_min, u_max]`, applied
    /// clipped to the bounds (the adapter is the last line of defence in front of the plant).
    #[serde(default)]
    pub clipped_commands: u64,
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn extra_info_travels_and_is_absent_when_empty() {
        let sys = koopman::systems::by_name("damped-pendulum").unwrap();
        let mut info = SimInfo::from_system(sys.as_ref());
        let reply = |sim: SimInfo| InfoReply {
            protocol_version: 1,
            id: "p".into(),
            mode: "lockstep".into(),
            k: 0,
            sim,
            stats: AdapterStats::default(),
        };
        let plain = serde_json::to_value(reply(info.clone())).unwrap();
        assert!(plain.get("extra").is_none(), "{plain}");
        assert_eq!(
            plain["state_names"],
            serde_json::json!(["theta", "theta_dot"])
        );
        info.extra.insert(
            "fmu".into(),
            serde_json::json!({"fmi_version": "2.0", "units": {"outputs": ["rad", "rad/s"]}}),
        );
        let text = serde_json::to_string(&reply(info.clone())).unwrap();
        let back: InfoReply = serde_json::from_str(&text).unwrap();
        assert_eq!(back.sim, info);
        assert_eq!(back.sim.extra["fmu"]["fmi_version"], "2.0");
        // A reply without the field (an older adapter) still decodes.
        let old: InfoReply = serde_json::from_value(plain).unwrap();
        assert!(old.sim.extra.is_empty());
    }
}
