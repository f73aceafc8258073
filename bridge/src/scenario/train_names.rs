//! What a scenario's `[train]` kinds mean for the rest of the file: the model store's names and
//! the checks of the kinds against `[control]`, and the tests of `[train]` as a scenario reads it.

use super::Scenario;
use crate::error::{Error, Result};
use crate::services::model_kind::{check_settings_for, ModelKind};

impl Scenario {
    /// The name in the model store of simulator `sim`'s model of kind `kind`: `{name}-{sim}`
    /// for `koopman`, `{name}-{sim}-{kind}` for the others (so that no two kinds share a
    /// folder, and a `koopman` model keeps the name it always had).
    pub fn model_name(&self, sim: &str, kind: ModelKind) -> String {
        match kind {
            ModelKind::Koopman => format!("{}-{sim}", self.name),
            k => format!("{}-{sim}-{k}", self.name),
        }
    }

    /// The kinds this run trains: `[train]`'s ([`super::train::TrainSpec::kinds`]), none without
    /// `[train]` or without `[collect]` (no data: the models are `[train] pretrained`).
    pub fn trained_kinds(&self) -> Vec<ModelKind> {
        match &self.train {
            Some(t) if self.collect.collects() => t.kinds(),
            _ => Vec::new(),
        }
    }

    /// The `TrainConfig` fields simulator `sim`'s models are trained with: `[train].config` (with
    /// `--full`, merged with `[full].train_config`), its `[[sims]]` `train_config` over them.
    /// Empty without `[train]`.
    pub fn train_config_of(&self, sim: &str) -> serde_json::Map<String, serde_json::Value> {
        let mut c = self
            .train
            .as_ref()
            .map(|t| t.config.clone())
            .unwrap_or_default();
        if let Some(s) = self.sims.iter().find(|s| s.id == sim) {
            for (k, v) in &s.train_config {
                c.insert(k.clone(), v.clone());
            }
        }
        c
    }

    /// Checks `[train]` ([`super::train::TrainSpec::check`]) and what its kinds are asked to do elsewhere: no
    /// two models share a name ([`Scenario::model_name`]), and every kind can serve each
    /// `[control]` entry (`feedforward_file` and `error_state`, the error-state MPC, need a
    /// lifted-linear model or an NNDM, not a bilinear one; `offset_free` is not for an NNDM's
    /// random shooting).
    pub(crate) fn check_train(&self) -> Result<()> {
        let Some(t) = &self.train else {
            if let Some(s) = self.sims.iter().find(|s| !s.train_config.is_empty()) {
                return Err(Error::Config(format!(
                    "[[sims]] '{}': train_config needs [train] (it overrides [train].config)",
                    s.id
                )));
            }
            return Ok(());
        };
        for s in self.sims.iter().filter(|s| !s.train_config.is_empty()) {
            let bad = |m: String| {
                Err(Error::Config(format!(
                    "[[sims]] '{}' train_config: {m}",
                    s.id
                )))
            };
            if s.train_config.contains_key("bilinear") {
                return bad(
                    "`bilinear` chooses the model kind, which [train].model sets for every \
                     simulator"
                        .into(),
                );
            }
            check_settings_for(&t.kinds(), &self.train_config_of(&s.id)).or_else(bad)?;
        }
        let empty = serde_json::Map::new();
        t.check(self.full.as_ref().map_or(&empty, |f| &f.train_config))
            .map_err(|e| match e {
                Error::Config(m) if self.full_applied => Error::Config(format!(
                    "{m} (with --full: [train].config merged with [full].train_config)"
                )),
                e => e,
            })?;
        if !self.collect.collects() {
            let trains = t.model.is_some()
                || !t.config.is_empty()
                || self.sims.iter().any(|s| !s.train_config.is_empty());
            if trains {
                return Err(Error::Config(
                    "[train] sets `model` or training settings, but there is no [collect] table \
                     (no data to train on): add one, or keep only `pretrained` in [train] to \
                     score models trained elsewhere"
                        .into(),
                ));
            }
        }
        let kinds = self.trained_kinds();
        let mut names: Vec<(String, &str, ModelKind)> = Vec::new();
        for s in &self.sims {
            for &k in &kinds {
                let name = self.model_name(&s.id, k);
                if let Some((_, o, ok)) = names.iter().find(|(n, _, _)| *n == name) {
                    return Err(Error::Config(format!(
                        "the {ok} model of simulator '{o}' and the {k} model of simulator '{}' \
                         would both be called '{name}': rename one of the simulators",
                        s.id
                    )));
                }
                names.push((name, &s.id, k));
            }
        }
        let sims: Vec<&str> = self.sims.iter().map(|s| s.id.as_str()).collect();
        let trained: Vec<String> = names.iter().map(|(n, _, _)| n.clone()).collect();
        super::pretrained::check(&t.pretrained, &sims, &trained)?;
        for ctrl in &self.control {
            let sim = self.controlled_id(ctrl);
            match &ctrl.model {
                Some(m) if !t.pretrained.iter().any(|p| &p.name == m) && !trained.contains(m) => {
                    return Err(Error::Config(format!(
                        "[control] for '{sim}': model '{m}' is neither a [train] pretrained name \
                         ({:?}) nor a model this run trains ({trained:?})",
                        t.pretrained.iter().map(|p| &p.name).collect::<Vec<_>>()
                    )));
                }
                None if kinds.is_empty() && ctrl.controller == super::Controller::Mpc => {
                    return Err(Error::Config(format!(
                        "[control] for '{sim}': this run trains no model (no [collect]); name the \
                         MPC's model with `model = \"NAME\"` (a [train] pretrained name)"
                    )));
                }
                _ => {}
            }
        }
        if !t.pretrained.is_empty()
            && self.tracks.is_empty()
            && self.control.iter().all(|c| c.model.is_none())
        {
            return Err(Error::Config(
                "[train] pretrained: the models trained elsewhere are rows of tracking tasks \
                 (`[control]` with `references`) or the `model` of a [control] entry; this \
                 scenario has neither"
                    .into(),
            ));
        }
        let riccati = |mpc: &serde_json::Map<String, serde_json::Value>| {
            mpc.get("terminal_riccati") == Some(&serde_json::Value::Bool(true))
        };
        for ctrl in self.control.iter().filter(|c| riccati(&c.mpc)) {
            let with = if ctrl.feedforward_file.is_some() {
                "`feedforward_file` (the error-state MPC)"
            } else if ctrl.offset_free.is_some() {
                "`offset_free`"
            } else {
                continue;
            };
            return Err(Error::Config(format!(
                "[control] for '{}': mpc.terminal_riccati does not combine with {with}",
                self.controlled_id(ctrl)
            )));
        }
        if let Some(t) = self
            .tracks
            .iter()
            .find(|t| t.error_state && riccati(&t.mpc))
        {
            return Err(Error::Config(format!(
                "[control] for '{}': mpc.terminal_riccati does not combine with `error_state` \
                 (the error-state MPC)",
                self.tracked_id(t)
            )));
        }
        for ctrl in &self.control {
            let sim = self.controlled_id(ctrl);
            for &k in &kinds {
                let why = if riccati(&ctrl.mpc)
                    && matches!(k, ModelKind::Bilinear | ModelKind::Nndm)
                {
                    "`mpc.terminal_riccati` (the Riccati cost-to-go of the lifted (A, B)) needs a \
                     lifted-linear model (koopman or edmd)"
                } else if ctrl.feedforward_file.is_some() && !k.plans_about_feedforward() {
                    "`feedforward_file` (the error-state MPC) needs a lifted-linear model \
                     (koopman or edmd) or an NNDM (random shooting about the plan)"
                } else if ctrl.offset_free.is_some() && k == ModelKind::Nndm {
                    "`offset_free` corrects the MPC of a lifted-linear or bilinear model, not the \
                     random shooting of an NNDM"
                } else {
                    continue;
                };
                return Err(Error::Config(format!(
                    "[control] for '{sim}': model kind '{k}' in [train].model cannot do this: {why}"
                )));
            }
        }
        for t in self.tracks.iter().filter(|t| t.offset_free.is_some()) {
            let why = if riccati(&t.mpc) {
                "mpc.terminal_riccati does not combine with `offset_free`".to_string()
            } else if kinds.contains(&ModelKind::Nndm) {
                "model kind 'nndm' in [train].model cannot do this: `offset_free` corrects the \
                 MPC of a lifted-linear or bilinear model, not the random shooting of an NNDM"
                    .to_string()
            } else {
                continue;
            };
            return Err(Error::Config(format!(
                "[control] for '{}': {why}",
                self.tracked_id(t)
            )));
        }
        for t in self.tracks.iter().filter(|t| t.error_state) {
            if let Some(k) = kinds.iter().find(|k| !k.plans_about_feedforward()) {
                return Err(Error::Config(format!(
                    "[control] for '{}': model kind '{k}' in [train].model cannot do this: \
                     `error_state` (the error-state MPC) needs a lifted-linear model (koopman or \
                     edmd) or an NNDM; track it in an entry without `error_state`",
                    self.tracked_id(t)
                )));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use crate::scenario::Scenario;
    use crate::services::model_kind::ModelKind::*;

    const BASE: &str = r#"
name = "demo"
[[sims]]
id = "pend"
env = "damped-pendulum"
[collect]
policy = { kind = "uniform" }
train_windows = 10
val_windows = 2
test_windows = 2
[control]
x0 = [-2.5, 0.1]
reference = [0.0, 0.0]
steps = 20
"#;

    fn with_train(train: &str) -> crate::error::Result<Scenario> {
        Scenario::parse(&format!("{BASE}[train]\n{train}\n"))
    }

    fn err(train: &str) -> String {
        with_train(train).unwrap_err().to_string()
    }

    #[test]
    fn terminal_riccati_is_refused_where_it_cannot_apply() {
        let with = |control_extra: &str, train: &str| {
            let text = BASE.replace(
                "steps = 20\n",
                &format!("steps = 20\nmpc = {{ terminal_riccati = true }}\n{control_extra}"),
            );
            Scenario::parse(&format!("{text}[train]\n{train}\n"))
        };
        assert!(with(
            "",
            "model = [\"koopman\", \"edmd\"]\nconfig = { iterations = 5 }"
        )
        .is_ok());
        let e = with("", "model = \"bilinear\"").unwrap_err().to_string();
        assert!(
            e.contains("terminal_riccati") && e.contains("'bilinear'"),
            "{e}"
        );
        let e = with(
            "offset_free = { mode = \"integral\", radius = 0.3, gain = [0.1, 0.0] }\n",
            "model = \"edmd\"",
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("terminal_riccati does not combine with `offset_free`"),
            "{e}"
        );
    }

    #[test]
    fn one_kind_or_a_list_and_the_defaults() {
        let kinds = |t: &str| with_train(t).unwrap().train.unwrap().kinds();
        assert_eq!(kinds("config = { iterations = 5 }"), vec![Koopman]);
        assert_eq!(kinds("config = { bilinear = true }"), vec![Bilinear]);
        assert_eq!(kinds("model = \"nndm\""), vec![Nndm]);
        assert_eq!(
            kinds("model = [\"koopman\", \"edmd\", \"bilinear\"]\nconfig = { iterations = 5 }"),
            vec![Koopman, Edmd, Bilinear]
        );
    }

    #[test]
    fn bad_kinds_are_refused_with_the_reason() {
        let e = err("model = \"dmd\"");
        assert!(
            e.contains("unknown model kind 'dmd'; valid kinds: koopman, bilinear, edmd, nndm"),
            "{e}"
        );
        let e = err("model = [\"koopman\", \"sindy\"]");
        assert!(e.contains("unknown model kind 'sindy'"), "{e}");
        let e = err("model = [\"koopman\", \"edmd\", \"koopman\"]");
        assert!(e.contains("'koopman' is listed twice"), "{e}");
        assert!(err("model = []").contains("lists no kind"));
        assert!(err("model = 3").contains("a kind or a list of kinds"));
        // An option only some kinds honour.
        // EDMD beside a normalised koopman model: it scales its own dictionary.
        let both = "model = [\"koopman\", \"edmd\"]\nconfig = { normalise = true }";
        assert!(with_train(both).is_ok());
        let e = err("model = [\"koopman\", \"nndm\"]\nconfig = { normalise = true }");
        assert!(
            e.contains("model kind 'nndm'") && e.contains("koopman model only"),
            "{e}"
        );
        let e = err("model = \"edmd\"\nconfig = { iterations = 5 }");
        assert!(
            e.contains("iterations does not apply to an edmd model"),
            "{e}"
        );
        // … but an optimiser setting for the kinds that use it is fine beside EDMD.
        assert!(with_train("model = [\"edmd\", \"nndm\"]\nconfig = { iterations = 5 }").is_ok());
        let e = err("model = \"edmd\"\nconfig = { ctrl = true }");
        assert!(
            e.contains("ctrl = true asks for a loss of the Koopman models"),
            "{e}"
        );
        let e = err("model = \"koopman\"\nconfig = { bilinear = true }");
        assert!(e.contains("older spelling of model = \"bilinear\""), "{e}");
        // A [full] setting is in force with --full only: refused then, not before.
        let full = with_train("model = \"edmd\"\n[full]\ntrain_config = { iterations = 9 }");
        let mut s = full.unwrap();
        s.apply_full();
        let e = s.check_train().unwrap_err().to_string();
        assert!(
            e.contains("iterations does not apply to an edmd model") && e.contains("--full"),
            "{e}"
        );
        let e = err("config = { kind = \"edmd\" }");
        assert!(e.contains("[train].model"), "{e}");
    }

    #[test]
    fn kinds_get_their_own_model_names_and_must_fit_the_control() {
        let s = with_train("model = [\"koopman\", \"edmd\"]").unwrap();
        assert_eq!(s.model_name("pend", Koopman), "demo-pend");
        assert_eq!(s.model_name("pend", Edmd), "demo-pend-edmd");
        // Simulator ids that would give two models one name.
        let two = BASE.replace(
            "[collect]",
            "[[sims]]\nid = \"pend-edmd\"\nenv = \"damped-pendulum\"\n[collect]",
        );
        let e = Scenario::parse(&format!("{two}[train]\nmodel = [\"koopman\", \"edmd\"]\n"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("would both be called 'demo-pend-edmd'"), "{e}");
        let off =
            "offset_free = { mode = \"trajectory\", radius = 1.0, gain = [0.5, 0.5] }\nsteps = 20";
        let nndm = format!(
            "{}[train]\nmodel = [\"koopman\", \"nndm\"]\n",
            BASE.replace("steps = 20", off)
        );
        let e = Scenario::parse(&nndm).unwrap_err().to_string();
        assert!(
            e.contains("model kind 'nndm'") && e.contains("`offset_free`"),
            "{e}"
        );
        let ff = "reference_file = \"r.npy\"\nfeedforward_file = \"u.npy\"";
        let bil = format!(
            "{}[train]\nmodel = [\"edmd\", \"bilinear\"]\n",
            BASE.replace("reference = [0.0, 0.0]", ff)
        );
        let e = Scenario::parse(&bil).unwrap_err().to_string();
        assert!(
            e.contains("model kind 'bilinear'") && e.contains("lifted-linear"),
            "{e}"
        );
    }

    #[test]
    fn a_simulator_trains_with_its_own_settings_over_the_shared_ones() {
        let two = BASE.replace(
            "[collect]",
            "train_config = { n_mult = 4, normalise = true }\n[[sims]]\nid = \"other\"\nenv = \"damped-pendulum\"\n[collect]",
        );
        let s = Scenario::parse(&format!(
            "{two}[train]\nconfig = {{ iterations = 7, n_mult = 8 }}\n"
        ))
        .unwrap();
        let own = s.train_config_of("pend");
        assert_eq!(
            (&own["iterations"], &own["n_mult"], &own["normalise"]),
            (&7.into(), &4.into(), &true.into())
        );
        let shared = s.train_config_of("other");
        assert_eq!(
            (&shared["n_mult"], shared.get("normalise")),
            (&8.into(), None)
        );
        // `--full` merges under it: the simulator's own settings stay on top.
        let mut full = Scenario::parse(&format!(
            "{two}[train]\nconfig = {{ n_mult = 8 }}\n[full]\ntrain_config = {{ n_mult = 16, iterations = 9 }}\n"
        ))
        .unwrap();
        full.apply_full();
        let own = full.train_config_of("pend");
        assert_eq!((&own["n_mult"], &own["iterations"]), (&4.into(), &9.into()));
        assert_eq!(full.train_config_of("other")["n_mult"], 16);
        // Refused, naming the simulator: an unknown setting, a kind, one a kind cannot honour,
        // and no [train] to override.
        let bad = |own: &str, train: &str| {
            let text = BASE.replace("[collect]", &format!("train_config = {own}\n[collect]"));
            let text = match train {
                "" => text.replace(
                    "[control]\nx0 = [-2.5, 0.1]\nreference = [0.0, 0.0]\nsteps = 20\n",
                    "",
                ),
                t => format!("{text}[train]\n{t}\n"),
            };
            Scenario::parse(&text).unwrap_err().to_string()
        };
        let e = bad("{ n_mul = 4 }", "config = {}");
        assert!(
            e.contains("[[sims]] 'pend' train_config") && e.contains("n_mul"),
            "{e}"
        );
        let e = bad("{ bilinear = true }", "config = {}");
        assert!(e.contains("'pend' train_config: `bilinear`"), "{e}");
        let e = bad("{ normalise = true }", "model = \"nndm\"");
        assert!(
            e.contains("'pend' train_config") && e.contains("model kind 'nndm'"),
            "{e}"
        );
        let e = bad("{ n_mult = 4 }", "");
        assert!(e.contains("train_config needs [train]"), "{e}");
    }
}
