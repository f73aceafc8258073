//! The keys of a `[control]` / `[[control]]` entry: one closed loop ([`ControlSpec`]'s `x0`,
//! `reference`, ...), or a tracking task with `references` (its survival metric, Q from the data,
//! perturbation: the types here; [`super::track`] reads them into a `TrackSpec`), and how the
//! file gives them: one table or several, `[control_defaults]` merged in.

use serde::{Deserialize, Serialize};

/// Closed-loop control of one simulator with the MPC service.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlSpec {
    /// Initial state (`nx` values) of the controlled simulator (not with `references`: each
    /// reference starts from its own first state).
    #[serde(default)]
    pub x0: Vec<f64>,
    /// Reference state (`nx` values, or `horizon·nx`: the stacked x_1..x_H); exactly one of
    /// `reference` and `reference_file`.
    #[serde(default)]
    pub reference: Option<Vec<f64>>,
    /// A time-varying reference: a float64 `.npy` of shape (T, nx), row k the reference state
    /// at step k (rows past the end repeat the last). May hold `{out}` (the run's output
    /// folder); a relative path resolves in the scenario's repository.
    #[serde(default)]
    pub reference_file: Option<String>,
    /// The inputs that realise `reference_file` (a plan): a float64 `.npy` of shape (T, nu), row
    /// k the input planned at step k (rows past the end repeat the last); placeholders and paths
    /// as `reference_file`. With it the MPC service plans the deviation from the plan
    /// (error-state MPC: the model's own rollout of the plan is the reference, so its bias along
    /// the plan cancels; a lifted-linear model only).
    #[serde(default)]
    pub feedforward_file: Option<String>,
    /// A position loop on the plan (arms commanded in joint velocities; needs
    /// `feedforward_file`): at every step the orchestrator corrects the planned velocities — in
    /// the feed-forward window and in the planned state alike — by `−gain · (q − q_plan)`, and
    /// the error-state MPC plans about the corrected plan. What corrects an actuator mismatch
    /// that no MPC weighting of the model does (docs/log/2026-12.md, session 8).
    #[serde(default)]
    pub position_loop: Option<PositionLoopSpec>,
    /// Closed-loop steps (with `references`: at most this many per reference, default all).
    #[serde(default)]
    pub steps: usize,
    /// A tracking task ([`TrackSpec`]): an `.npz` of references, `x` (N, T+1, nx) and `u`
    /// (N, T, nu) (the inputs that realised them), the layout of a collected dataset; one
    /// closed loop per reference from its first state, and the replay row.
    #[serde(default)]
    pub references: Option<String>,
    /// The survival metric of a tracking task ([`SurvivalSpec`]).
    #[serde(default)]
    pub survival: Option<SurvivalSpec>,
    /// A tracking task runs each reference to its end (or a fall) after the threshold is crossed.
    #[serde(default)]
    pub continue_after_failure: bool,
    /// A tracking task plans about each reference with its inputs as feed-forward.
    #[serde(default)]
    pub error_state: bool,
    /// The row's name: a tracking task's row suffix (`{model}+{label}`); a single closed loop's
    /// name in the report (needed, and distinct, when a simulator has several entries).
    #[serde(default)]
    pub label: Option<String>,
    /// What decides a single closed loop's inputs ([`Controller`]; default the MPC service).
    #[serde(default)]
    pub controller: Controller,
    /// Whether a tracking task runs the replay row (default true).
    #[serde(default)]
    pub replay: Option<bool>,
    /// A tracking task's Q from the training data's spread ([`QFromData`]).
    #[serde(default)]
    pub q_from_data: Option<QFromData>,
    /// Transitions per on-policy window of a tracking task (default: `[collect]`'s T).
    #[serde(default)]
    pub onpolicy_steps: Option<usize>,
    /// The perturbation of every episode ([`PerturbationSpec`]; a single closed loop's is
    /// reference 0's).
    #[serde(default)]
    pub perturbation: Option<PerturbationSpec>,
    /// A tracking task whose closed loops are the training data of `koopbridge run --aggregate`.
    #[serde(default)]
    pub aggregate: bool,
    /// `koopman::mpc::MpcConfig` fields to override (JSON object).
    #[serde(default)]
    pub mpc: serde_json::Map<String, serde_json::Value>,
    /// Which simulator to control (default: the first).
    #[serde(default)]
    pub sim: Option<String>,
    /// The MPC's model by its name in the run's model store: a `[train] pretrained` name, or a
    /// model this run trains (`{scenario}-{sim}`...). Such an entry runs once, not once per
    /// trained kind. Default: the model this run trains for the simulator (one row per kind).
    #[serde(default)]
    pub model: Option<String>,
    /// Gaussian noise on the state the MPC sees ([`ObservationNoise`]; SPEC's figure-8: σ = 0.01
    /// on the end-effector position). A baseline controller sees the true state.
    #[serde(default)]
    pub observation_noise: Option<ObservationNoise>,
    /// Offset-free correction of the MPC (a bilinear or a lifted-linear model; not with
    /// `feedforward_file`), `koopman::mpc::OffsetFreeConfig` fields: `mode` (`trajectory`,
    /// `disturbance` or `integral`), `radius`, `gain` (nx values), `angles`.
    #[serde(default)]
    pub offset_free: Option<koopman::mpc::OffsetFreeConfig>,
}

impl ControlSpec {
    /// Checks the keys of a single closed loop (not a tracking task) driving simulator `sim`:
    /// one reference, what a plan, a position loop and a baseline controller need, the label.
    pub fn check_loop(&self, sim: &str) -> crate::error::Result<()> {
        let bad = |m: String| {
            Err(crate::error::Error::Config(format!(
                "[control] for '{sim}': {m}"
            )))
        };
        if self.reference.is_some() == self.reference_file.is_some() {
            return bad("needs exactly one of `reference` and `reference_file`".into());
        }
        if self.feedforward_file.is_some() && self.reference_file.is_none() {
            return bad("`feedforward_file` needs the `reference_file` it realises".into());
        }
        if let Some(pl) = &self.position_loop {
            if self.feedforward_file.is_none() {
                return bad("`position_loop` corrects a plan and needs `feedforward_file`".into());
            }
            if !(pl.gain.is_finite() && pl.gain >= 0.0) {
                return bad(format!(
                    "position_loop.gain must be finite and ≥ 0, got {}",
                    pl.gain
                ));
            }
        }
        if self.controller == Controller::Feedforward && self.feedforward_file.is_none() {
            return bad(
                "controller = \"feedforward\" applies the plan's inputs and needs `feedforward_file`"
                    .into(),
            );
        }
        if let Some(l) = &self.label {
            crate::keyexpr::validate_chunk("[control].label", l)?;
        }
        if let Some(p) = &self.perturbation {
            p.check().or_else(bad)?;
        }
        if self.controller != Controller::Mpc {
            let mpc_only = [
                ("offset_free", self.offset_free.is_some()),
                ("model", self.model.is_some()),
                ("observation_noise", self.observation_noise.is_some()),
            ];
            if let Some((k, _)) = mpc_only.iter().find(|(_, set)| *set) {
                return bad(format!(
                    "`{k}` is the MPC's; controller = \"{}\" has none",
                    self.controller.name()
                ));
            }
        }
        if let Some(m) = &self.model {
            crate::keyexpr::validate_chunk("[control].model", m)?;
        }
        if let Some(n) = &self.observation_noise {
            n.check().or_else(bad)?;
        }
        Ok(())
    }
}

/// What decides a single closed loop's inputs: the MPC service, or a baseline that needs no
/// model, run by the same loop on the same simulator (tracking tasks always use the MPC; their
/// baseline is the replay row).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Controller {
    /// The MPC service with the trained model (the default).
    #[default]
    Mpc,
    /// The plan's inputs (`feedforward_file`) open loop — corrected by `position_loop` when it
    /// is given (a joint P loop about the plan; gain 1/dt about a reference's velocities is the
    /// greedy joint follower).
    Feedforward,
    /// Zero input at every step (what the plant does left alone).
    ZeroInput,
}

impl Controller {
    /// The name a scenario file and report.json use (`mpc`, `feedforward`, `zero-input`).
    pub fn name(self) -> &'static str {
        match self {
            Controller::Mpc => "mpc",
            Controller::Feedforward => "feedforward",
            Controller::ZeroInput => "zero-input",
        }
    }
}

/// Gaussian noise on the state the MPC sees: `N(0, sigma²)` added to each of `states` before
/// every solve, drawn from `seed` (deterministic; the simulator steps the true state).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObservationNoise {
    /// The standard deviation, in the states' units (finite, ≥ 0).
    pub sigma: f64,
    /// The noisy state indices (at least one; checked against `nx` with the simulator's info).
    pub states: Vec<usize>,
    /// The seed of the draws.
    #[serde(default)]
    pub seed: u64,
}

impl ObservationNoise {
    /// Checks the values: a finite σ ≥ 0, at least one state, none twice.
    pub fn check(&self) -> std::result::Result<(), String> {
        if !(self.sigma.is_finite() && self.sigma >= 0.0) {
            return Err(format!(
                "observation_noise.sigma must be finite and ≥ 0, got {}",
                self.sigma
            ));
        }
        let mut s = self.states.clone();
        s.sort_unstable();
        s.dedup();
        if s.is_empty() || s.len() != self.states.len() {
            return Err(format!(
                "observation_noise.states must name distinct state indices, at least one; got {:?}",
                self.states
            ));
        }
        Ok(())
    }
}

/// A position loop on a plan: which state components are the joint positions and which their
/// velocities (input `i` commands velocity `velocity[i]` and corrects position `position[i]`),
/// and the loop's gain.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PositionLoopSpec {
    /// State indices of the joint positions (`nu` of them, input order).
    pub position: Vec<usize>,
    /// State indices of the joint velocities (`nu` of them, input order).
    pub velocity: Vec<usize>,
    /// Gain in 1/s: the velocity correction per unit of position error (≥ 0).
    pub gain: f64,
}

/// When a tracked run fails: the mean absolute error over `states` above `threshold`, or a fall
/// the simulator reports (a step flagged `terminated`, PROTOCOL.md §4), or a non-finite state.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SurvivalSpec {
    /// The largest mean absolute error that still counts as tracking (> 0, in the states' units).
    pub threshold: f64,
    /// The state indices the error is taken over (at least one; checked against `nx`).
    pub states: Vec<usize>,
}

/// Q's diagonal from the training data: `1/σ²` of each state's standard deviation over the
/// simulator's training split (the z-score a `normalise = true` model is trained in) on
/// `states`, 0 on every other state (all states when `states` is absent); each group of `also`
/// then weighs its states by `scale/σ²`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QFromData {
    /// The weighted states (default: all).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub states: Option<Vec<usize>>,
    /// Further states at a fraction of their z-score weight (e.g. a legged robot's base at 0.1
    /// beside its joints), applied in order over `states`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub also: Vec<QGroup>,
}

/// A group of states weighted `scale/σ²` in [`QFromData`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QGroup {
    /// The states (at least one).
    pub states: Vec<usize>,
    /// The fraction of the z-score weight (finite, ≥ 0).
    pub scale: f64,
}

impl QFromData {
    /// Checks the groups: each names a state and has a finite scale ≥ 0.
    pub fn check(&self) -> std::result::Result<(), String> {
        for g in &self.also {
            if g.states.is_empty() {
                return Err("q_from_data.also: a group names no state".into());
            }
            if !(g.scale.is_finite() && g.scale >= 0.0) {
                return Err(format!(
                    "q_from_data.also: scale must be finite and ≥ 0, got {}",
                    g.scale
                ));
            }
        }
        Ok(())
    }

    /// Every state index it names (`states` and the groups').
    pub fn named_states(&self) -> impl Iterator<Item = &usize> {
        self.states
            .iter()
            .flatten()
            .chain(self.also.iter().flat_map(|g| &g.states))
    }

    /// Q's diagonal for the states' standard deviations `x_std` (`nx` values; indices checked
    /// against `nx` before).
    pub fn weights(&self, x_std: &[f64]) -> Vec<f64> {
        let z = |i: usize| 1.0 / (x_std[i] * x_std[i]);
        let mut w: Vec<f64> = (0..x_std.len())
            .map(|i| match &self.states {
                Some(s) if !s.contains(&i) => 0.0,
                _ => z(i),
            })
            .collect();
        for g in &self.also {
            for &i in &g.states {
                w[i] = g.scale * z(i);
            }
        }
        w
    }
}

/// A perturbation of every episode of a tracking task or of a single closed loop (the simulator
/// applies it; PROTOCOL.md "reset"): the same for every reference except the push, whose step and direction are drawn per reference
/// from `seed` (deterministic: reference i's push is the same in every row and every run).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PerturbationSpec {
    /// Scale of the base body's mass (Go2: trunk, G1: torso), > 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mass_scale: Option<f64>,
    /// Scale of the feet's sliding friction, > 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub friction_scale: Option<f64>,
    /// A push of this size (m/s, a change of the base's horizontal velocity) in a uniformly
    /// random direction at a uniformly random step of `push_steps`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub push: Option<f64>,
    /// The steps `[first, end)` a push is drawn from (default [20, 80)).
    #[serde(default = "default_push_steps")]
    pub push_steps: [u64; 2],
    /// The seed of the pushes' draws.
    #[serde(default)]
    pub seed: u64,
    /// The actuators realise `command_gain · u` for a command `u` (an actuator mismatch), > 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub command_gain: Option<f64>,
}

fn default_push_steps() -> [u64; 2] {
    [20, 80]
}

impl PerturbationSpec {
    /// Reference `i`'s perturbation.
    pub fn for_reference(&self, i: usize) -> crate::messages::Perturbation {
        let push = self.push.map(|size| {
            let mut rng = koopman::rng::Rng::derive(self.seed, i as u64);
            let [lo, hi] = self.push_steps;
            let step = lo + rng.below((hi - lo) as usize) as u64;
            let angle = rng.uniform(0.0, std::f64::consts::TAU);
            crate::messages::Push {
                step,
                velocity: [size * angle.cos(), size * angle.sin()],
            }
        });
        crate::messages::Perturbation {
            mass_scale: self.mass_scale,
            friction_scale: self.friction_scale,
            push,
            command_gain: self.command_gain,
        }
    }

    /// Checks the values (scales > 0, a push ≥ 0 m/s, `push_steps` a non-empty range).
    pub fn check(&self) -> std::result::Result<(), String> {
        if let Some(p) = self.push.filter(|p| !(p.is_finite() && *p >= 0.0)) {
            return Err(format!(
                "perturbation.push must be a finite speed ≥ 0 (m/s), got {p}"
            ));
        }
        let [lo, hi] = self.push_steps;
        if hi <= lo {
            return Err(format!("perturbation.push_steps [{lo}, {hi}) is empty"));
        }
        // The draws need the non-empty window checked above.
        self.for_reference(0).check()
    }
}

/// Merges `[control_defaults]` (a table of `[control]` keys) into every `[control]` /
/// `[[control]]` entry that does not set the key itself, and removes it: what several entries
/// share (a survival metric, the references, the MPC settings) is written once. True when
/// there was such a table.
pub(super) fn apply_control_defaults(doc: &mut toml::Table) -> crate::error::Result<bool> {
    let Some(defaults) = doc.remove("control_defaults") else {
        return Ok(false);
    };
    let toml::Value::Table(defaults) = defaults else {
        return Err(crate::error::Error::Config(
            "[control_defaults] must be a table of [control] keys".into(),
        ));
    };
    let entries: Vec<&mut toml::Table> = match doc.get_mut("control") {
        Some(toml::Value::Table(t)) => vec![t],
        Some(toml::Value::Array(a)) => a.iter_mut().filter_map(|v| v.as_table_mut()).collect(),
        _ => {
            return Err(crate::error::Error::Config(
                "[control_defaults] needs [control] or [[control]] entries to apply to".into(),
            ))
        }
    };
    for entry in entries {
        for (k, v) in &defaults {
            entry.entry(k.clone()).or_insert_with(|| v.clone());
        }
    }
    Ok(true)
}

/// `[control]` (one table) or `[[control]]` (an array of tables).
pub(super) fn one_or_many<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> std::result::Result<Vec<ControlSpec>, D::Error> {
    // Read as a value first, then as the one or the other, so that the error names the field.
    let v = toml::Value::deserialize(d)?;
    match v {
        toml::Value::Array(_) => Vec::<ControlSpec>::deserialize(v),
        _ => ControlSpec::deserialize(v).map(|c| vec![c]),
    }
    .map_err(serde::de::Error::custom)
}
