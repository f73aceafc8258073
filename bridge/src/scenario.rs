//! Scenario files (`scenarios/*.toml`): which simulators, how data is collected, how the model
//! is trained and how it is used for control.
//!
//! `[train] model` chooses the kind of model: `"koopman"` (the default), `"bilinear"`, `"edmd"`,
//! `"nndm"`, or a list of distinct kinds (`model = ["koopman", "edmd"]`) to train one model of
//! each per simulator and run `[control]` with each — the MPC service picks the controller by
//! the model's kind — so that the report sets them side by side ([`train`]). An unknown or
//! repeated kind, or one that cannot do what the file asks (a `[train].config` setting it cannot
//! honour, `feedforward_file` with a bilinear or NNDM model, `offset_free` with an NNDM), is
//! refused when the file is read; `bilinear` on a simulator without inputs and `nndm` with
//! `[control].mpc` settings random shooting cannot honour, once the simulators' `info` is known,
//! before collection.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::keyexpr::validate_chunk;

pub mod collect;
pub mod control;
mod data_region;
pub mod extras;
mod full;
mod pretrained;
mod region;
#[cfg(test)]
mod tests_full;
pub mod track;
pub mod train;
mod train_names;

pub use collect::{CollectSpec, Policy};
pub use control::{
    ControlSpec, Controller, ObservationNoise, PerturbationSpec, PositionLoopSpec, QFromData,
    SurvivalSpec,
};
pub use extras::{CommandLine, HookPhase, HookSpec, ParticipantRole, ParticipantSpec};
pub use full::FullSpec;
pub use pretrained::PretrainedSpec;
pub use track::TrackSpec;
pub use train::TrainSpec;

use data_region::with_x0_box;

/// A whole scenario.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// Scenario name (results go to `results/{name}/`); `[a-z0-9_-]`.
    pub name: String,
    /// One-line description.
    #[serde(default)]
    pub description: String,
    /// Simulators to start (each with `koopbridge sim`).
    pub sims: Vec<SimSpec>,
    /// Data collection; absent: none ([`CollectSpec::nothing`]) — the scenario trains nothing
    /// and scores models trained elsewhere (`[train] pretrained`, a `[control]` entry's `model`).
    #[serde(default = "CollectSpec::nothing")]
    pub collect: CollectSpec,
    /// Training (through the trainer service): which kinds of model, with which settings
    /// ([`TrainSpec`]); absent = no training, no control.
    #[serde(default)]
    pub train: Option<TrainSpec>,
    /// Closed-loop control (through the MPC service): one `[control]` table, or one
    /// `[[control]]` entry per controlled simulator (all stepped in one lockstep loop). The
    /// entries with `references` are tracking tasks and move to [`Scenario::tracks`] when the
    /// file is parsed.
    #[serde(default, deserialize_with = "control::one_or_many")]
    pub control: Vec<ControlSpec>,
    /// The tracking tasks (`[control]` entries with `references`, [`TrackSpec`]), run one after
    /// another after the lockstep loop of the others. Not a TOML field of its own.
    #[serde(skip)]
    pub tracks: Vec<TrackSpec>,
    /// Commands run at fixed phases of the run (`[[hooks]]`).
    #[serde(default)]
    pub hooks: Vec<HookSpec>,
    /// Extra participants started beside the simulators (`[[participants]]`).
    #[serde(default)]
    pub participants: Vec<ParticipantSpec>,
    /// Overrides applied with `koopbridge run --full` (the SPEC budget).
    #[serde(default)]
    pub full: Option<FullSpec>,
    /// The folder external simulator commands run in (where `{python}` and their relative
    /// paths resolve): set by [`Scenario::load`] to the repository holding the scenario file
    /// ([`repository_of`]); `None` (parsed text) = the current folder. Not a TOML field.
    #[serde(skip)]
    pub base_dir: Option<PathBuf>,
    /// Whether [`Scenario::apply_full`] merged `[full]` in (the settings in force are then the
    /// merge). Not a TOML field.
    #[serde(skip)]
    pub full_applied: bool,
    /// The `[control]` entries and tracking tasks in force with `--full` when `[full]` has
    /// `control_defaults` (parsed and checked with the file; [`Scenario::apply_full`] swaps them
    /// in). Not a TOML field.
    #[serde(skip)]
    pub(crate) full_controls: Option<full::FullControls>,
}

/// The repository a file belongs to: the nearest folder above it that holds `.git`, else the
/// file's own folder.
pub fn repository_of(file: &Path) -> PathBuf {
    let dir = std::fs::canonicalize(file)
        .ok()
        .and_then(|p| p.parent().map(Path::to_path_buf))
        .unwrap_or_else(|| PathBuf::from("."));
    dir.ancestors()
        .find(|d| d.join(".git").exists())
        .map_or_else(|| dir.clone(), Path::to_path_buf)
}

with_x0_box! {
    /// A simulator to start.
    #[derive(Clone, Debug, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct SimSpec {
        /// Its id (`[a-z0-9_-]`).
        pub id: String,
        /// The built-in system (`koopbridge sim --env`); required without `command`. With
        /// `command`, optionally the reference system the external simulator implements (for
        /// reports).
        #[serde(default)]
        pub env: String,
        /// An external adapter to start instead of `koopbridge sim` (program and arguments). It
        /// runs in the repository of the scenario file ([`Scenario::base_dir`]): relative paths
        /// resolve there, and `{python}` as the program means that repository's venv Python
        /// (`.venv/bin/python`, else `python3` from `PATH`). The orchestrator appends
        /// `--id ID --session S --stdin-lifeline --connect ENDPOINT`.
        #[serde(default)]
        pub command: Option<Vec<String>>,
        @x0_box("This simulator's own initial-state box, over `[collect]`'s \
                 (`Scenario::sim_region`): `x0_low`/`x0_high` or `x0_center`/`x0_radius`."),
        /// Lower bounds of its uniform random inputs (one value or `nu`), over the policy's.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pub u_low: Option<crate::messages::InputBound>,
        /// Upper bounds of its uniform random inputs (one value or `nu`), over the policy's.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pub u_high: Option<crate::messages::InputBound>,
        /// This simulator's own collect inputs, in place of the `inputs` of `[collect] policy =
        /// { kind = "adapter" }` (a `collect` request's `policy`, PROTOCOL.md "Collect"): e.g.
        /// `{ kind = "expert" }` for a legged robot that walks with its expert beside simulators
        /// that draw uniform inputs (`Scenario::sim_policy`). Only with the adapter policy; a
        /// planned or expert policy only for an external adapter (`command`: a built-in system
        /// draws uniform inputs only) and without a data region (`x0_*`, `u_low`/`u_high`).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pub collect_inputs: Option<crate::messages::CollectPolicy>,
        /// `koopman::train::TrainConfig` fields for this simulator's models only, over
        /// `[train].config` (and, with `--full`, over its merge with `[full].train_config`): e.g.
        /// a z-scored, smaller model for a 35-state robot beside small systems
        /// (`Scenario::train_config_of`). Needs `[train]`; checked as `[train].config` is, against
        /// every kind of `[train].model`; not part of what the collected data depend on.
        #[serde(default, skip_serializing_if = "serde_json::Map::is_empty")]
        pub train_config: serde_json::Map<String, serde_json::Value>,
    }
}

impl SimSpec {
    /// A built-in reference system served by `koopbridge sim --env ENV`.
    pub fn builtin(id: impl Into<String>, env: impl Into<String>) -> Self {
        SimSpec {
            id: id.into(),
            env: env.into(),
            command: None,
            x0_low: None,
            x0_high: None,
            x0_center: None,
            x0_radius: None,
            u_low: None,
            u_high: None,
            collect_inputs: None,
            train_config: serde_json::Map::new(),
        }
    }
}

impl Scenario {
    /// Reads and validates a scenario file.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::Io {
            path: path.to_path_buf(),
            source: e,
        })?;
        let mut s =
            Self::parse(&text).map_err(|e| Error::Config(format!("{}: {e}", path.display())))?;
        s.base_dir = Some(repository_of(path));
        Ok(s)
    }

    /// Parses and validates scenario text (with `[full].control_defaults`, the entries in force
    /// under `--full` too).
    pub fn parse(text: &str) -> Result<Self> {
        let doc: toml::Table = toml::from_str(text).map_err(|e| Error::Config(e.to_string()))?;
        let full_doc = full::doc_with_full_control_defaults(&doc)?;
        let mut s = Self::from_doc(doc, Some(text))?;
        if let Some(d) = full_doc {
            let f = Self::from_doc(d, None).map_err(|e| {
                Error::Config(format!(
                    "with --full ([full].control_defaults over [control_defaults]): {e}"
                ))
            })?;
            s.full_controls = Some(full::FullControls {
                control: f.control,
                tracks: f.tracks,
            });
        }
        Ok(s)
    }

    /// Parses a scenario document (`text`, when given, is its source: the errors of a file
    /// without `[control_defaults]` then name the innermost key and the line).
    fn from_doc(mut doc: toml::Table, text: Option<&str>) -> Result<Self> {
        // A `[collect]` table written with no training windows is a mistake, not "collect
        // nothing" (which is no table at all).
        let collect_written = doc.contains_key("collect");
        let merged = control::apply_control_defaults(&mut doc)?;
        let mut s: Scenario = match text {
            Some(text) if !merged => {
                toml::from_str(text).map_err(|e| Error::Config(e.to_string()))?
            }
            _ => toml::Value::Table(doc)
                .try_into()
                .map_err(|e: toml::de::Error| Error::Config(e.to_string()))?,
        };
        s.split_tracks()?;
        if collect_written {
            s.collect.check()?;
        }
        s.validate()?;
        s.check_settings()?;
        Ok(s)
    }

    /// Moves the `[control]` entries with `references` (tracking tasks) to [`Scenario::tracks`];
    /// an error names a key that does not fit its entry.
    pub fn split_tracks(&mut self) -> Result<()> {
        let mut plain = Vec::new();
        for c in std::mem::take(&mut self.control) {
            let id = self.controlled_id(&c).to_string();
            match TrackSpec::of(&c, &id)? {
                Some(t) => {
                    if self
                        .tracks
                        .iter()
                        .any(|o| o.label == t.label && self.tracked_id(o) == id)
                    {
                        return Err(Error::Config(format!(
                            "simulator '{id}' has two tracking entries labelled {:?}: give each a distinct `label`",
                            t.label.as_deref().unwrap_or("(none)")
                        )));
                    }
                    self.tracks.push(t)
                }
                None => plain.push(c),
            }
        }
        self.control = plain;
        Ok(())
    }

    /// Checks names, counts and references.
    pub fn validate(&self) -> Result<()> {
        validate_chunk("scenario name", &self.name)?;
        if self.sims.is_empty() {
            return Err(Error::Config(
                "a scenario needs at least one [[sims]] entry".into(),
            ));
        }
        for (i, s) in self.sims.iter().enumerate() {
            validate_chunk("sim id", &s.id)?;
            if s.command.is_none() && s.env.is_empty() {
                return Err(Error::Config(format!(
                    "sim '{}' needs `env` (a built-in system) or `command` (an external adapter)",
                    s.id
                )));
            }
            if self.sims[..i].iter().any(|o| o.id == s.id) {
                return Err(Error::Config(format!("sim id '{}' appears twice", s.id)));
            }
        }
        if self.collect.collects() {
            self.collect.check()?;
        }
        for j in 0..self.sims.len() {
            self.sim_region(j)?;
        }
        for t in &self.tracks {
            if t.q_from_data.is_some() && !self.collect.collects() {
                return Err(Error::Config(format!(
                    "[control] for '{}': `q_from_data` weighs by the spread of this run's \
                     training data, and this scenario collects none (no [collect]): give \
                     `mpc.q` instead",
                    self.tracked_id(t)
                )));
            }
            if t.aggregate && !self.collect.collects() {
                return Err(Error::Config(format!(
                    "[control] for '{}': `aggregate = true` adds its windows to the training \
                     data, and this scenario collects none (no [collect])",
                    self.tracked_id(t)
                )));
            }
            if t.aggregate && t.onpolicy_steps.is_some_and(|n| n != self.collect.steps) {
                return Err(Error::Config(format!(
                    "[control] for '{}': `aggregate = true` adds its windows to the training \
                     data, whose windows have [collect].steps = {} transitions: onpolicy_steps \
                     must be that (or absent)",
                    self.tracked_id(t),
                    self.collect.steps
                )));
            }
            if let Some(id) = &t.sim {
                if !self.sims.iter().any(|s| &s.id == id) {
                    return Err(Error::Config(format!(
                        "control.sim '{id}' is not among [[sims]]"
                    )));
                }
            }
        }
        if !(self.control.is_empty() && self.tracks.is_empty()) && self.train.is_none() {
            return Err(Error::Config(
                "[control] needs [train] (the model comes from training)".into(),
            ));
        }
        for (i, ctrl) in self.control.iter().enumerate() {
            if let Some(id) = &ctrl.sim {
                if !self.sims.iter().any(|s| &s.id == id) {
                    return Err(Error::Config(format!(
                        "control.sim '{id}' is not among [[sims]]"
                    )));
                }
            }
            ctrl.check_loop(self.controlled_id(ctrl))?;
            let id = self.controlled_id(ctrl);
            if let Some(o) = self.control[..i]
                .iter()
                .find(|o| self.controlled_id(o) == id)
            {
                if o.label.is_none() || ctrl.label.is_none() || o.label == ctrl.label {
                    return Err(Error::Config(format!(
                        "simulator '{id}' has several [[control]] entries: give each a distinct \
                         `label` (they run one after another, each from its own x0), or name \
                         another simulator with `sim`"
                    )));
                }
            }
        }
        extras::validate(&self.hooks, &self.participants)?;
        Ok(())
    }

    /// Checks the free-form settings tables against the settings they override, so that an
    /// unknown key is refused (naming it and the valid ones) when the file is read:
    /// `[train].config` and `[full].train_config` (`TrainConfig`), every `[control].mpc`
    /// (`MpcConfig`), and the uniform policy's `low`/`high` (finite, `low ≤ high`; their length
    /// against `nu` is checked with the simulators' `info`).
    pub fn check_settings(&self) -> Result<()> {
        use crate::services::koopman_trainer::train_config;
        let config = |what: &str, e: Error| {
            let m = match e {
                Error::Protocol { message, .. } => message,
                e => e.to_string(),
            };
            Error::Config(format!("{what}: {m}"))
        };
        if let Some(t) = &self.train {
            // The model kind is `model`, not a TrainConfig field: checked with the kinds.
            let mut c = t.config.clone();
            c.remove(crate::services::model_kind::KIND_KEY);
            train_config(&c).map_err(|e| config("[train].config", e))?;
        }
        for s in self.sims.iter().filter(|s| !s.train_config.is_empty()) {
            let mut c = self.train_config_of(&s.id);
            c.remove(crate::services::model_kind::KIND_KEY);
            train_config(&c)
                .map_err(|e| config(&format!("[[sims]] '{}' train_config", s.id), e))?;
        }
        self.check_train()?;
        if let Some(f) = &self.full {
            train_config(&f.train_config).map_err(|e| config("[full].train_config", e))?;
        }
        for ctrl in &self.control {
            serde_json::from_value::<koopman::mpc::MpcConfig>(serde_json::Value::Object(
                ctrl.mpc.clone(),
            ))
            .map_err(|e| {
                Error::Config(format!(
                    "[control].mpc for '{}': {e}",
                    self.controlled_id(ctrl)
                ))
            })?;
        }
        for t in &self.tracks {
            serde_json::from_value::<koopman::mpc::MpcConfig>(serde_json::Value::Object(
                t.mpc.clone(),
            ))
            .map_err(|e| {
                Error::Config(format!("[control].mpc for '{}': {e}", self.tracked_id(t)))
            })?;
        }
        Ok(())
    }

    /// The index in `sims` of the simulator a control entry drives (`sim`, else the first).
    pub fn controlled_index(&self, ctrl: &ControlSpec) -> usize {
        ctrl.sim
            .as_ref()
            .and_then(|id| self.sims.iter().position(|s| &s.id == id))
            .unwrap_or(0)
    }

    /// The index in `sims` of the simulator a tracking task drives (`sim`, else the first).
    pub fn tracked_index(&self, t: &TrackSpec) -> usize {
        t.sim
            .as_ref()
            .and_then(|id| self.sims.iter().position(|s| &s.id == id))
            .unwrap_or(0)
    }

    /// The id of the simulator a tracking task drives.
    pub fn tracked_id(&self, t: &TrackSpec) -> &str {
        self.sims
            .get(self.tracked_index(t))
            .map_or("", |s| s.id.as_str())
    }

    /// The id of the simulator a control entry drives.
    pub fn controlled_id(&self, ctrl: &ControlSpec) -> &str {
        self.sims
            .get(self.controlled_index(ctrl))
            .map_or("", |s| s.id.as_str())
    }

    /// Applies the `[full]` overrides: the windows, `train_config` over `[train].config`, and
    /// the control entries parsed with `[full].control_defaults`.
    pub fn apply_full(&mut self) {
        self.full_applied = true;
        if let Some(fc) = self.full_controls.take() {
            self.control = fc.control;
            self.tracks = fc.tracks;
        }
        if let Some(f) = self.full.clone() {
            if let Some(n) = f.train_windows {
                self.collect.train_windows = n;
            }
            if let Some(n) = f.val_windows {
                self.collect.val_windows = n;
            }
            if let Some(n) = f.test_windows {
                self.collect.test_windows = n;
            }
            if let Some(t) = &mut self.train {
                for (k, v) in f.train_config {
                    t.config.insert(k, v);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn commands_resolve_against_the_scenario_files_repository() {
        let root = std::env::temp_dir().join(format!("kb-repo-{}", std::process::id()));
        let sc = root.join("scenarios/deep");
        std::fs::create_dir_all(&sc).unwrap();
        std::fs::create_dir_all(root.join(".git")).unwrap();
        let file = sc.join("s.toml");
        std::fs::write(&file, GOOD).unwrap();
        let s = Scenario::load(&file).unwrap();
        let root = std::fs::canonicalize(&root).unwrap();
        assert_eq!(s.base_dir.as_deref(), Some(root.as_path()));
        // Outside any repository: the file's folder.
        std::fs::remove_dir_all(root.join(".git")).unwrap();
        assert_eq!(repository_of(&file), std::fs::canonicalize(&sc).unwrap());
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn control_defaults_fill_every_entry_that_does_not_set_the_key() {
        let base = GOOD.split("[control]").next().unwrap().to_string();
        let text = format!(
            "{base}[control_defaults]\nreferences = \"r.npz\"\n\
             survival = {{ threshold = 0.2, states = [0] }}\n\
             [[control]]\n\
             [[control]]\nlabel = \"tight\"\nsurvival = {{ threshold = 0.1, states = [0, 1] }}\n"
        );
        let s = Scenario::parse(&text).unwrap();
        assert_eq!(s.tracks.len(), 2);
        assert_eq!(s.tracks[0].references, "r.npz");
        assert_eq!(s.tracks[0].survival.as_ref().unwrap().threshold, 0.2);
        assert_eq!(
            s.tracks[1].survival.as_ref().unwrap().states,
            vec![0, 1],
            "its own wins"
        );
        assert_eq!(s.tracks[1].references, "r.npz");
        let bad =
            format!("{base}[control_defaults]\nwind = 1\n[[control]]\nreferences = \"r.npz\"\n");
        let e = Scenario::parse(&bad).unwrap_err().to_string();
        assert!(e.contains("wind"), "an unknown default is named: {e}");
    }

    #[test]
    fn a_collect_table_without_a_policy_is_specs_uniform_one() {
        let text = GOOD.replace(
            "policy = { kind = \"scripted\", inputs = [[1.0], [-1.0]] }\n",
            "",
        );
        assert_ne!(text, GOOD, "the example names a policy");
        let s = Scenario::parse(&text).unwrap();
        assert_eq!(s.collect.policy, Policy::uniform());
    }

    const GOOD: &str = r#"
name = "demo"
[[sims]]
id = "pend"
env = "damped-pendulum"
[collect]
policy = { kind = "scripted", inputs = [[1.0], [-1.0]] }
train_windows = 10
val_windows = 2
test_windows = 2
[train]
config = { iterations = 5 }
[control]
x0 = [-2.5, 0.1]
reference = [0.0, 0.0]
steps = 20
[full]
train_windows = 1000
train_config = { iterations = 60000 }
"#;

    #[test]
    fn parses_validates_and_applies_full() {
        let mut s = Scenario::parse(GOOD).unwrap();
        assert_eq!(s.collect.steps, 15);
        assert_eq!(
            s.collect.policy,
            Policy::Scripted {
                inputs: vec![vec![1.0], vec![-1.0]]
            }
        );
        s.apply_full();
        assert_eq!(s.collect.train_windows, 1000);
        assert_eq!(s.train.unwrap().config["iterations"], 60000);
        assert!(Scenario::parse(&GOOD.replace("\"demo\"", "\"De mo\"")).is_err());
        assert!(Scenario::parse(&GOOD.replace("train_windows = 10", "train_windows = 0")).is_err());
        // (The line above also breaks [full]'s `1000`; this one changes [collect]'s only.)
        let e = Scenario::parse(&GOOD.replace("train_windows = 10\n", "train_windows = 0\n"));
        let e = e.unwrap_err().to_string();
        assert!(e.contains("must be positive"), "{e}");
        assert!(Scenario::parse(&GOOD.replace("steps = 20", "steps = 20\nbogus = 1")).is_err());
        // `env` is required for a built-in simulator only.
        let no_env = GOOD.replace("env = \"damped-pendulum\"", "");
        assert!(Scenario::parse(&no_env).is_err());
        let cmd = no_env.replace("id = \"pend\"", "id = \"pend\"\ncommand = [\"my-adapter\"]");
        assert_eq!(Scenario::parse(&cmd).unwrap().sims[0].env, "");
        assert!(Scenario::parse(&GOOD.replace("[[sims]]", "base_dir = \"/\"\n[[sims]]")).is_err());
        // A feed-forward realises a trajectory: without `reference_file` it is refused.
        let ff = GOOD.replace("steps = 20", "steps = 20\nfeedforward_file = \"u.npy\"");
        let e = Scenario::parse(&ff).unwrap_err().to_string();
        assert!(
            e.contains("`feedforward_file` needs the `reference_file`"),
            "{e}"
        );
        let plan = ff.replace("reference = [0.0, 0.0]", "reference_file = \"r.npy\"");
        assert!(Scenario::parse(&plan).is_ok());
        // A position loop corrects a plan: without `feedforward_file`, or with a bad gain, refused.
        let looped = "steps = 20\nposition_loop = { position = [0], velocity = [1], gain = 30.0 }";
        let pl = plan.replace("steps = 20", looped);
        assert!(Scenario::parse(&pl).is_ok());
        let e = Scenario::parse(&GOOD.replace("steps = 20", looped))
            .unwrap_err()
            .to_string();
        assert!(e.contains("needs `feedforward_file`"), "{e}");
        let e = Scenario::parse(&pl.replace("gain = 30.0", "gain = -1.0"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("position_loop.gain"), "{e}");
        assert!(Scenario::parse(&GOOD.replace(
            "[[sims]]\nid = \"pend\"",
            "[[sims]]\nid = \"pend\"\n[[sims]]\nid = \"pend\""
        ))
        .is_err());
    }
}
