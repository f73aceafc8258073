//! Tracking tasks: a `[control]` / `[[control]]` entry with `references = "FILE.npz"` is one
//! ([`TrackSpec`]) — a closed loop per reference, scored by a survival metric, beside the
//! references' own inputs replayed open loop; this module reads and checks those keys.

use serde::{Deserialize, Serialize};

use super::control::{ControlSpec, PerturbationSpec, QFromData, SurvivalSpec};
use crate::error::{Error, Result};
use crate::keyexpr::validate_chunk;

/// A tracking task: every reference of `references` tracked from its own first state by the MPC
/// service (one row per trained model kind), scored by `survival`; beside them the replay row.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrackSpec {
    /// Which simulator (default: the first).
    pub sim: Option<String>,
    /// The row's suffix: a model's row is `{model}+{label}` (`{model}` without one); distinct
    /// among a simulator's tracking entries.
    pub label: Option<String>,
    /// The references: an `.npz` with `x` (N, T+1, nx) and `u` (N, T, nu) as a dataset (`{out}`
    /// expanded; a relative path in the scenario's repository); read when control starts, so
    /// that a hook may write it.
    pub references: String,
    /// The survival metric; absent: no survival, runs to each reference's end (tracking errors).
    pub survival: Option<SurvivalSpec>,
    /// Run each reference to its end (or a fall) after the survival threshold is crossed.
    pub continue_after_failure: bool,
    /// Plan the deviation from each reference with its inputs as feed-forward (error-state MPC;
    /// a lifted-linear model only) instead of SPEC's reference window.
    pub error_state: bool,
    /// Also run the replay row (the references' inputs open loop).
    pub replay: bool,
    /// At most this many steps per reference (default: the references' T).
    pub steps: Option<usize>,
    /// `koopman::mpc::MpcConfig` fields to override.
    pub mpc: serde_json::Map<String, serde_json::Value>,
    /// Q from the training data's spread (overrides `mpc.q`).
    pub q_from_data: Option<QFromData>,
    /// Transitions per on-policy window written from the closed loops (default: `[collect]`'s T).
    pub onpolicy_steps: Option<usize>,
    /// The perturbation of every episode (replay and model rows alike).
    pub perturbation: Option<PerturbationSpec>,
    /// Its closed loops' windows are what `koopbridge run --aggregate` retrains on.
    pub aggregate: bool,
    /// The MPC's offset-free correction, restarted with every reference (about a plan,
    /// `error_state`, the `disturbance` mode only).
    pub offset_free: Option<koopman::mpc::OffsetFreeConfig>,
}

impl TrackSpec {
    /// The tracking task of a control entry with `references`, `None` without; an error names
    /// a key that does not belong to a tracking task (or only to one) or a bad value.
    pub fn of(c: &ControlSpec, sim: &str) -> Result<Option<TrackSpec>> {
        let bad = |m: String| Err(Error::Config(format!("[control] for '{sim}': {m}")));
        let Some(references) = &c.references else {
            let only = [
                ("survival", c.survival.is_some()),
                ("continue_after_failure", c.continue_after_failure),
                ("error_state", c.error_state),
                ("replay", c.replay.is_some()),
                ("q_from_data", c.q_from_data.is_some()),
                ("onpolicy_steps", c.onpolicy_steps.is_some()),
                ("aggregate", c.aggregate),
            ];
            if let Some((k, _)) = only.iter().find(|(_, set)| *set) {
                return bad(format!(
                    "`{k}` belongs to a tracking task and needs `references = \"FILE.npz\"`"
                ));
            }
            if c.x0.is_empty() || c.steps == 0 {
                return bad(
                    "needs `x0` and `steps` ≥ 1 (or `references` for a tracking task)".into(),
                );
            }
            return Ok(None);
        };
        let not_here = [
            ("x0", !c.x0.is_empty()),
            ("reference", c.reference.is_some()),
            ("reference_file", c.reference_file.is_some()),
            ("feedforward_file", c.feedforward_file.is_some()),
            ("position_loop", c.position_loop.is_some()),
            ("model", c.model.is_some()),
            ("observation_noise", c.observation_noise.is_some()),
            (
                "controller",
                c.controller != super::control::Controller::Mpc,
            ),
        ];
        if let Some((k, _)) = not_here.iter().find(|(_, set)| *set) {
            return bad(format!(
                "`{k}` is not a key of a tracking task (`references`): its rows are the trained \
                 and `[train] pretrained` models, each reference from its own first state; use \
                 `error_state = true` to plan about the references' inputs"
            ));
        }
        if references.trim().is_empty() {
            return bad("`references` is empty".into());
        }
        if let Some(l) = &c.label {
            validate_chunk("[control].label", l)?;
        }
        if let Some(s) = &c.survival {
            if !(s.threshold.is_finite() && s.threshold > 0.0) {
                return bad(format!(
                    "survival.threshold must be a finite number > 0, got {}",
                    s.threshold
                ));
            }
            if s.states.is_empty() {
                return bad("survival.states must name at least one state index".into());
            }
        }
        if let Some(q) = &c.q_from_data {
            if let Err(m) = q.check() {
                return bad(m);
            }
        }
        if c.onpolicy_steps == Some(0) {
            return bad("onpolicy_steps must be ≥ 1".into());
        }
        if let Some(p) = &c.perturbation {
            if let Err(m) = p.check() {
                return bad(m);
            }
        }
        Ok(Some(TrackSpec {
            sim: c.sim.clone(),
            label: c.label.clone(),
            references: references.clone(),
            survival: c.survival.clone(),
            continue_after_failure: c.continue_after_failure,
            error_state: c.error_state,
            replay: c.replay.unwrap_or(true),
            steps: (c.steps > 0).then_some(c.steps),
            mpc: c.mpc.clone(),
            q_from_data: c.q_from_data.clone(),
            onpolicy_steps: c.onpolicy_steps,
            perturbation: c.perturbation.clone(),
            aggregate: c.aggregate,
            offset_free: c.offset_free.clone(),
        }))
    }

    /// The row name of model `model` in this task.
    pub fn row(&self, model: &str) -> String {
        match &self.label {
            Some(l) => format!("{model}+{l}"),
            None => model.to_string(),
        }
    }

    /// Checks the state indices against the simulator's `nx` (survival and `q_from_data`).
    pub fn check_states(&self, nx: usize, sim: &str) -> Result<()> {
        let survival = self.survival.iter().flat_map(|s| &s.states);
        let q = self.q_from_data.iter().flat_map(|q| q.named_states());
        let lists: [(&str, Vec<usize>); 2] = [
            ("survival.states", survival.copied().collect()),
            ("q_from_data", q.copied().collect()),
        ];
        for (key, list) in lists {
            if let Some(&i) = list.iter().find(|&&i| i >= nx) {
                return Err(Error::Config(format!(
                    "[control] for '{sim}': {key} names state {i}, the simulator has {nx} \
                     states (0..{})",
                    nx.saturating_sub(1)
                )));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pushes_are_drawn_per_reference_in_the_window_and_of_the_given_size() {
        let p: PerturbationSpec = toml::from_str("push = 0.8\nmass_scale = 1.2\nseed = 3").unwrap();
        let draws: Vec<_> = (0..50).map(|i| p.for_reference(i)).collect();
        for d in &draws {
            let push = d.push.as_ref().unwrap();
            assert!((20..80).contains(&push.step), "{push:?}");
            assert!((push.velocity[0].hypot(push.velocity[1]) - 0.8).abs() < 1e-12);
            assert_eq!(d.mass_scale, Some(1.2));
        }
        assert_eq!(
            draws[7],
            p.for_reference(7),
            "deterministic by seed and reference"
        );
        assert_ne!(draws[7], draws[8], "each reference its own push");
        let steps: std::collections::BTreeSet<u64> = draws
            .iter()
            .map(|d| d.push.as_ref().unwrap().step)
            .collect();
        assert!(
            steps.len() > 20,
            "the steps spread over the window: {steps:?}"
        );
        let other = PerturbationSpec {
            seed: 4,
            ..p.clone()
        };
        assert_ne!(
            other.for_reference(7),
            draws[7],
            "another seed, other pushes"
        );
        let none: PerturbationSpec = toml::from_str("friction_scale = 0.6").unwrap();
        assert!(none.for_reference(0).push.is_none());
    }

    fn spec(extra: &str) -> ControlSpec {
        toml::from_str(&format!("references = \"r.npz\"\n{extra}")).unwrap()
    }

    #[test]
    fn a_tracking_entry_is_read_and_its_bad_keys_are_named() {
        let t = TrackSpec::of(
            &spec("survival = { threshold = 0.16, states = [1, 2] }\nlabel = \"es\""),
            "go2",
        )
        .unwrap()
        .unwrap();
        assert!(t.replay && !t.error_state && t.steps.is_none());
        assert_eq!(t.row("m"), "m+es");
        let err = |extra: &str| TrackSpec::of(&spec(extra), "go2").unwrap_err().to_string();
        assert!(err("x0 = [0.0]\nsteps = 3").contains("`x0` is not a key"));
        assert!(err("survival = { threshold = 0.0, states = [1] }").contains("threshold"));
        assert!(err("survival = { threshold = 0.1, states = [] }").contains("at least one"));
        assert!(err("onpolicy_steps = 0").contains("onpolicy_steps"));
        assert!(err("label = \"A B\"").contains("label"));
        assert!(err("perturbation = { mass_scale = 0.0 }").contains("mass_scale"));
        assert!(err("perturbation = { push = 1.0, push_steps = [5, 5] }").contains("empty"));
        assert!(t
            .check_states(2, "go2")
            .unwrap_err()
            .to_string()
            .contains("state 2"));
        t.check_states(3, "go2").unwrap();
        // The tracking keys without `references` are refused, naming the key.
        let plain: ControlSpec =
            toml::from_str("x0 = [0.0]\nsteps = 3\nreference = [0.0]\nerror_state = true").unwrap();
        let e = TrackSpec::of(&plain, "p").unwrap_err().to_string();
        assert!(
            e.contains("`error_state` belongs to a tracking task"),
            "{e}"
        );
        let plain: ControlSpec = toml::from_str("reference = [0.0]").unwrap();
        let e = TrackSpec::of(&plain, "p").unwrap_err().to_string();
        assert!(e.contains("needs `x0` and `steps`"), "{e}");
    }

    #[test]
    fn q_from_data_weighs_its_states_and_each_group_by_its_fraction_of_the_z_score() {
        let q: QFromData =
            toml::from_str("states = [1, 2]\nalso = [{ states = [0, 2], scale = 0.1 }]").unwrap();
        let sd = [2.0, 0.5, 4.0, 1.0];
        // Written out: 1/σ² on 1 and 2, then 0.1/σ² on 0 and 2 (the group wins), 0 on 3.
        assert_eq!(q.weights(&sd), vec![0.1 / 4.0, 4.0, 0.1 / 16.0, 0.0]);
        assert_eq!(
            QFromData::default().weights(&sd),
            vec![0.25, 4.0, 1.0 / 16.0, 1.0]
        );
        let bad = |t: &str| toml::from_str::<QFromData>(t).unwrap().check().unwrap_err();
        assert!(bad("also = [{ states = [], scale = 1.0 }]").contains("names no state"));
        assert!(bad("also = [{ states = [0], scale = -1.0 }]").contains("scale"));
        let c: ControlSpec = toml::from_str(
            "references = \"r.npz\"\nq_from_data = { also = [{ states = [9], scale = 1.0 }] }",
        )
        .unwrap();
        let t = TrackSpec::of(&c, "pend").unwrap().unwrap();
        let e = t.check_states(4, "pend").unwrap_err().to_string();
        assert!(e.contains("q_from_data names state 9"), "{e}");
    }
}
