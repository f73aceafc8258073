//! JSON control-plane messages: simulator info, reset and collect requests, adapter statistics.

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
    /// Lower input bounds (`nu`); `-inf` for an unbounded input, `null` on the wire (JSON has no
    /// infinities).
    #[serde(with = "lower_bounds")]
    pub u_min: Vec<f64>,
    /// Upper input bounds (`nu`); `+inf` for an unbounded input, `null` on the wire.
    #[serde(with = "upper_bounds")]
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

/// Input bounds on the wire: a finite value as a number, an infinite one as `null` (JSON has no
/// infinities; serde_json would write `null` and then refuse to read it back). `null` reads back
/// as the infinity of the side (`SIGN`: −1 for lower bounds, +1 for upper bounds); NaN is refused
/// when writing, so it can never come back as an infinity.
mod bounds {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &[f64], s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::{Error, SerializeSeq};
        let mut seq = s.serialize_seq(Some(v.len()))?;
        for &b in v {
            if b.is_nan() {
                return Err(S::Error::custom("an input bound is NaN"));
            }
            if b.is_finite() {
                seq.serialize_element(&b)?;
            } else {
                seq.serialize_element(&Option::<f64>::None)?;
            }
        }
        seq.end()
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D, sign: f64) -> Result<Vec<f64>, D::Error> {
        let v: Vec<Option<f64>> = Vec::deserialize(d)?;
        Ok(v.into_iter()
            .map(|b| b.unwrap_or(sign * f64::INFINITY))
            .collect())
    }
}

/// `u_min` on the wire (`null` = −∞).
mod lower_bounds {
    pub use super::bounds::serialize;
    pub fn deserialize<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<f64>, D::Error> {
        super::bounds::deserialize(d, -1.0)
    }
}

/// `u_max` on the wire (`null` = +∞).
mod upper_bounds {
    pub use super::bounds::serialize;
    pub fn deserialize<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<f64>, D::Error> {
        super::bounds::deserialize(d, 1.0)
    }
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
    /// Windows run in-process for `collect` requests.
    #[serde(default)]
    pub collected_windows: u64,
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
/// explicit initial state. Both absent: the simulator's default initial state. A perturbation,
/// when given, holds for the episode the reset starts (until the next reset).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ResetRequest {
    /// Seed for the initial-state draw.
    #[serde(default)]
    pub seed: Option<u64>,
    /// Explicit initial state (`nx` values).
    #[serde(default)]
    pub x0: Option<Vec<f64>>,
    /// A perturbation of the episode (PROTOCOL.md "reset"); absent = the nominal simulator. A
    /// simulator that cannot apply it answers `unsupported`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub perturbation: Option<Perturbation>,
}

/// A perturbation of one episode, applied by the simulator (the legged adapters: the base body's
/// mass, the feet's friction, a push); every field absent = nominal.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Perturbation {
    /// Scale of the base body's mass (Go2: trunk, G1: torso), > 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mass_scale: Option<f64>,
    /// Scale of the feet's sliding friction, > 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub friction_scale: Option<f64>,
    /// A push during the episode.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub push: Option<Push>,
    /// The actuators realise `command_gain · u` for a command `u` (an actuator mismatch no
    /// model was told about; the Kinova's), > 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub command_gain: Option<f64>,
}

/// A push: right before the simulator integrates step `step` (from state `step` to `step + 1`,
/// counted from the reset), the base's horizontal velocity changes by `velocity` (m/s, world x
/// and y).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Push {
    /// The step it is applied at.
    pub step: u64,
    /// The change of the base's world-frame horizontal velocity, m/s.
    pub velocity: [f64; 2],
}

impl Perturbation {
    /// Checks the values: scales and the command gain finite and > 0, the push's velocity finite.
    pub fn check(&self) -> Result<(), String> {
        for (k, v) in [
            ("mass_scale", self.mass_scale),
            ("friction_scale", self.friction_scale),
            ("command_gain", self.command_gain),
        ] {
            if let Some(v) = v.filter(|v| !(v.is_finite() && *v > 0.0)) {
                return Err(format!(
                    "perturbation.{k} must be a finite number > 0, got {v}"
                ));
            }
        }
        if let Some(p) = &self.push {
            if !p.velocity.iter().all(|v| v.is_finite()) {
                return Err(format!(
                    "perturbation.push.velocity must be finite, got {:?}",
                    p.velocity
                ));
            }
        }
        Ok(())
    }
}

/// A bound of a [`CollectPolicy`]: one value for every input, or one per input.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum InputBound {
    /// The same bound for every input.
    All(f64),
    /// One bound per input (`nu` values).
    Each(Vec<f64>),
}

impl InputBound {
    /// The bound as `nu` values, or `None` if it has another length.
    pub fn resolve(&self, nu: usize) -> Option<Vec<f64>> {
        match self {
            InputBound::All(v) => Some(vec![*v; nu]),
            InputBound::Each(v) if v.len() == nu => Some(v.clone()),
            InputBound::Each(_) => None,
        }
    }
}

/// How a simulator draws the inputs of the windows it collects itself (`collect` request).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum CollectPolicy {
    /// A fresh `u ~ U(low, high)` every step; absent bounds are the simulator's
    /// `u_min`/`u_max` (which must then be finite).
    Uniform {
        /// Lower bounds (default `info.u_min`).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        low: Option<InputBound>,
        /// Upper bounds (default `info.u_max`).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        high: Option<InputBound>,
        /// Lower corner of the box each window's initial state is drawn from (`nx` values),
        /// with `x0_high`: the window resets to `x0 ~ U(x0_low, x0_high)` drawn from its own
        /// stream instead of a seeded reset; absent = the simulator's own seeded reset.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        x0_low: Option<Vec<f64>>,
        /// Upper corner of the initial-state box (`nx` values), with `x0_low`.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        x0_high: Option<Vec<f64>>,
    },
    /// Windows cut from trajectories the simulator plans itself (SPEC's "constrained,
    /// expert-guided" Kinova data, issue 11): window `i` belongs to plan
    /// `i / windows_per_plan`, whose start and goal the simulator draws from `(seed, plan)`;
    /// each window resets to a planned state and executes the next `steps` planned commands.
    /// Only a simulator with a planner runs it (the Drake Gen3 adapter); every other one answers
    /// `unsupported`.
    Planned {
        /// Windows cut from each plan, evenly spaced along it (≥ 1; absent = the simulator's
        /// default, 20 for the Drake Gen3 adapter).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        windows_per_plan: Option<u32>,
        /// Exploration on every planned command: `U(±dither)` per input and step (input units),
        /// drawn from `(seed, window)` and clipped to the input bounds (≥ 0; absent or 0 = the
        /// planned commands exactly). Without it a velocity-servoed arm follows its commands so
        /// closely that command and measured velocity are collinear (correlation 0.99995 on
        /// the Gen3), and no model can tell the command's effect from the state's.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        dither: Option<f64>,
    },
    /// A legged robot's expert walking policy under random velocity commands, run by the
    /// simulator itself (issue 25: the Go2 adapter's rl_sar expert); windows cut back to back from
    /// episodes, each a function of `(policy, seed, window)`. Every other simulator answers
    /// `unsupported`.
    #[serde(rename = "expert")]
    Expert(ExpertSettings),
    /// The expert with Gaussian noise on its joint targets (`noise`, rad).
    #[serde(rename = "expert+noise")]
    ExpertNoise(ExpertSettings),
}

/// The settings of a legged robot's expert collection ([`CollectPolicy::Expert`],
/// [`CollectPolicy::ExpertNoise`]), all optional (absent = the simulator's default). They travel
/// as they are; the simulator checks them (`bad_request` there).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExpertSettings {
    /// σ of the Gaussian noise on every joint target, rad (`expert+noise` only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise: Option<f64>,
    /// Lower corner of the box of velocity commands (vx m/s, vy m/s, ωz rad/s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub command_low: Option<[f64; 3]>,
    /// Upper corner of the box of velocity commands.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub command_high: Option<[f64; 3]>,
    /// Seconds between two command draws.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub command_every: Option<f64>,
    /// The largest push, m/s (0 = none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub push: Option<f64>,
    /// Seconds between pushes (at window boundaries).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub push_every: Option<f64>,
    /// Seconds walked unrecorded after each reset.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub warmup: Option<f64>,
    /// Windows cut back to back from one episode.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub windows_per_episode: Option<u32>,
}

impl CollectPolicy {
    /// The policy's name in dataset metadata: `adapter-uniform`, or for a planned policy
    /// `adapter-planned` with its settings (`windows_per_plan=K`, absent = the simulator's
    /// default; `dither=D` when there is one).
    pub fn describe(&self) -> String {
        match self {
            CollectPolicy::Uniform { .. } => "adapter-uniform".into(),
            CollectPolicy::Planned {
                windows_per_plan,
                dither,
            } => {
                let k = windows_per_plan.map_or("default".to_string(), |k| k.to_string());
                match dither {
                    Some(d) if *d > 0.0 => {
                        format!("adapter-planned windows_per_plan={k} dither={d}")
                    }
                    _ => format!("adapter-planned windows_per_plan={k}"),
                }
            }
            CollectPolicy::Expert(_) | CollectPolicy::ExpertNoise(_) => {
                format!(
                    "adapter-{}",
                    serde_json::to_string(self).unwrap_or_default()
                )
            }
        }
    }
}

impl Default for CollectPolicy {
    fn default() -> Self {
        CollectPolicy::Uniform {
            low: None,
            high: None,
            x0_low: None,
            x0_high: None,
        }
    }
}

/// The JSON query of `…/sim/{id}/collect`: block `block` of a collection of windows that the
/// simulator runs in its own process. The collection is cut into blocks of `block_windows`
/// windows (block `b` holds windows `b·block_windows ..`); the reply holds the first `windows`
/// (default all) of them, so that a collection's last block may be short. Window `i` depends
/// only on `(policy, seed, i)`: the same request gives the same bytes, and a collection resumes
/// at any block.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CollectRequest {
    /// The input policy.
    #[serde(default)]
    pub policy: CollectPolicy,
    /// The collection's seed.
    pub seed: u64,
    /// The block index.
    pub block: u64,
    /// Windows per block of the collection (≥ 1).
    pub block_windows: u32,
    /// Windows wanted from this block (1 ..= `block_windows`; absent = `block_windows`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub windows: Option<u32>,
    /// Transitions per window T (≥ 1).
    pub steps: u32,
}

impl CollectRequest {
    /// The index of the block's first window (`None` if it overflows `u64`).
    pub fn first_window(&self) -> Option<u64> {
        self.block.checked_mul(u64::from(self.block_windows))
    }
    /// How many windows the reply holds.
    pub fn window_count(&self) -> u32 {
        self.windows.unwrap_or(self.block_windows)
    }
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

    #[test]
    fn collect_policies_have_one_json_form_each() {
        let req: CollectRequest = serde_json::from_str(
            r#"{"policy":{"kind":"planned","windows_per_plan":20},"seed":42,"block":3,"block_windows":500,"steps":15}"#,
        )
        .unwrap();
        let planned = CollectPolicy::Planned {
            windows_per_plan: Some(20),
            dither: None,
        };
        assert_eq!(req.policy, planned);
        assert_eq!(
            serde_json::to_string(&planned).unwrap(),
            r#"{"kind":"planned","windows_per_plan":20}"#
        );
        let default: CollectPolicy = serde_json::from_str(r#"{"kind":"planned"}"#).unwrap();
        assert_eq!(
            default,
            CollectPolicy::Planned {
                windows_per_plan: None,
                dither: None,
            }
        );
        assert_eq!(
            serde_json::to_string(&default).unwrap(),
            r#"{"kind":"planned"}"#
        );
        let dithered = CollectPolicy::Planned {
            windows_per_plan: Some(20),
            dither: Some(0.25),
        };
        assert_eq!(
            serde_json::to_string(&dithered).unwrap(),
            r#"{"kind":"planned","windows_per_plan":20,"dither":0.25}"#
        );
        assert_eq!(
            dithered.describe(),
            "adapter-planned windows_per_plan=20 dither=0.25"
        );
        assert_eq!(planned.describe(), "adapter-planned windows_per_plan=20");
        let uniform = CollectPolicy::Uniform {
            low: Some(InputBound::All(-0.12)),
            high: Some(InputBound::Each(vec![0.1, 0.2])),
            x0_low: None,
            x0_high: None,
        };
        assert_eq!(
            serde_json::to_string(&uniform).unwrap(),
            r#"{"kind":"uniform","low":-0.12,"high":[0.1,0.2]}"#
        );
        let expert: CollectPolicy =
            serde_json::from_str(r#"{"kind":"expert","windows_per_episode":50}"#).unwrap();
        assert_eq!(
            expert,
            CollectPolicy::Expert(ExpertSettings {
                windows_per_episode: Some(50),
                ..Default::default()
            })
        );
        let noisy: CollectPolicy =
            serde_json::from_str(r#"{"kind":"expert+noise","noise":0.05}"#).unwrap();
        assert_eq!(
            serde_json::to_string(&noisy).unwrap(),
            r#"{"kind":"expert+noise","noise":0.05}"#
        );
        assert_eq!(
            noisy.describe(),
            r#"adapter-{"kind":"expert+noise","noise":0.05}"#
        );
        for bad in [
            r#"{"kind":"expert","speed":1}"#,
            r#"{"kind":"expert","command_low":[0,0]}"#,
            r#"{"kind":"planned","goals":3}"#,
            r#"{"kind":"planned","windows_per_plan":-1}"#,
            r#"{"kind":"planned","low":0.1}"#,
            r#"{"kind":"scripted"}"#,
        ] {
            assert!(serde_json::from_str::<CollectPolicy>(bad).is_err(), "{bad}");
        }
        assert_eq!(uniform.describe(), "adapter-uniform");
        assert_eq!(planned.describe(), "adapter-planned windows_per_plan=20");
    }

    #[test]
    fn unbounded_inputs_travel_as_null_and_come_back_infinite() {
        let sys = koopman::systems::by_name("damped-pendulum").unwrap();
        let mut info = SimInfo::from_system(sys.as_ref());
        info.u_min = vec![f64::NEG_INFINITY];
        info.u_max = vec![f64::INFINITY];
        let text = serde_json::to_string(&info).unwrap();
        assert!(
            text.contains(r#""u_min":[null]"#) && text.contains(r#""u_max":[null]"#),
            "{text}"
        );
        let back: SimInfo = serde_json::from_str(&text).unwrap();
        assert_eq!(back, info);
        // Finite bounds are plain numbers, mixed with unbounded ones.
        info.u_min = vec![-2.0];
        let back: SimInfo = serde_json::from_str(&serde_json::to_string(&info).unwrap()).unwrap();
        assert_eq!((back.u_min[0], back.u_max[0]), (-2.0, f64::INFINITY));
        // NaN is not turned into an infinity.
        info.u_max = vec![f64::NAN];
        assert!(serde_json::to_string(&info).is_err());
    }
}
