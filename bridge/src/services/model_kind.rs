//! The kinds of model the trainer service trains (`koopman`, `bilinear`, `edmd`, `nndm`), which
//! training settings each of them uses, and how a job's config names its kind.
//!
//! A job names its kind with `"kind"` in its config (absent: `koopman`; `"bilinear": true`, the
//! older spelling, makes a `koopman` job bilinear). The other fields are
//! `koopman::train::TrainConfig` fields; each kind uses some of them ([`ModelKind::uses`]):
//!
//! | setting | koopman | bilinear | nndm | edmd |
//! |---|---|---|---|---|
//! | `gamma`, `train_samples` | ✓ | ✓ | ✓ | ✓ |
//! | optimiser and network (`iterations`, `hidden`, `n_mult`, `lr`, …) | ✓ | ✓ | ✓ | – |
//! | `ctrl`, `cov` (the Koopman losses) | ✓ | ✓ | – | – |
//! | `normalise` | ✓ | – | – | – |
//!
//! In a job, a setting its kind does not use is refused when it asks for something the kind
//! cannot do ([`ModelKind::refusal`]: `ctrl`/`cov`/`normalise` = true, or any optimiser setting
//! for EDMD, a least-squares fit) and otherwise ignored (`ctrl = false` for an NNDM, which has no
//! such loss anyway). Settings shared by several kinds (a scenario's) are checked with
//! [`check_settings_for`].

use std::fmt;

use serde::{Deserialize, Serialize};

/// A kind of model.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ModelKind {
    /// The neural Koopman model of SPEC.md (linear latent dynamics; MPC: a QP).
    #[default]
    Koopman,
    /// The bilinear Koopman model `z⁺ = A z + B u + Σ u_i N_i z` (MPC: sequential convex).
    Bilinear,
    /// EDMD with control: polynomial dictionary, least squares (MPC: a QP).
    Edmd,
    /// The NNDM baseline `x⁺ = x + g([x, u])` (MPC: random shooting).
    Nndm,
}

/// The config key that names a job's kind.
pub const KIND_KEY: &str = "kind";

impl ModelKind {
    /// Every kind, in the order messages list them.
    pub const ALL: [ModelKind; 4] = [
        ModelKind::Koopman,
        ModelKind::Bilinear,
        ModelKind::Edmd,
        ModelKind::Nndm,
    ];

    /// Its name (`koopman`, `bilinear`, `edmd`, `nndm`).
    pub fn name(self) -> &'static str {
        match self {
            ModelKind::Koopman => "koopman",
            ModelKind::Bilinear => "bilinear",
            ModelKind::Edmd => "edmd",
            ModelKind::Nndm => "nndm",
        }
    }

    /// The kind called `name`; an unknown name's error names it and lists the valid ones.
    pub fn parse(name: &str) -> std::result::Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == name)
            .ok_or_else(|| {
                format!(
                    "unknown model kind '{name}'; valid kinds: {}",
                    Self::ALL.map(Self::name).join(", ")
                )
            })
    }

    /// Whether this kind trains with the `TrainConfig` setting `key`.
    pub fn uses(self, key: &str) -> bool {
        use ModelKind::*;
        match key {
            "gamma" | "train_samples" => true,
            "ctrl" | "cov" => matches!(self, Koopman | Bilinear),
            "normalise" => self == Koopman,
            "bilinear" => matches!(self, Koopman | Bilinear),
            _ => self != Edmd,
        }
    }

    /// Why this kind cannot honour the setting `key = value` (`None`: it uses the setting, or
    /// ignoring it changes nothing, as `ctrl = false` for an NNDM).
    pub fn refusal(self, key: &str, value: &serde_json::Value) -> Option<String> {
        if self.uses(key) {
            return None;
        }
        let kind = self.name();
        match key {
            "ctrl" | "cov" => (value == &serde_json::Value::Bool(true)).then(|| {
                format!(
                    "{key} = true asks for a loss of the Koopman models (koopman, bilinear); \
                     a {kind} model has none"
                )
            }),
            "normalise" => (value == &serde_json::Value::Bool(true)).then(|| {
                format!(
                    "normalise = true (z-scored training) is implemented for the koopman model \
                     only, not {kind}"
                )
            }),
            "bilinear" => (value == &serde_json::Value::Bool(true))
                .then(|| format!("bilinear = true asks for a bilinear model, not {kind}")),
            _ => Some(format!(
                "{key} does not apply to an edmd model (a least-squares fit on a polynomial \
                 dictionary: no network, no optimiser; it uses gamma and train_samples only)"
            )),
        }
    }

    /// The job config that trains this kind from `fields` (`TrainConfig` settings, e.g. a
    /// scenario's `[train].config`): the settings this kind uses, `bilinear` dropped, and
    /// [`KIND_KEY`].
    pub fn job_config(
        self,
        fields: &serde_json::Map<String, serde_json::Value>,
    ) -> serde_json::Map<String, serde_json::Value> {
        let mut out: serde_json::Map<String, serde_json::Value> = fields
            .iter()
            .filter(|(k, _)| self.uses(k) && k.as_str() != "bilinear")
            .map(|(k, v)| (k.clone(), v.clone()))
            .collect();
        out.insert(KIND_KEY.into(), self.name().into());
        out
    }

    /// A job config's kind and its `TrainConfig` settings (without [`KIND_KEY`]; for a bilinear
    /// model with `bilinear = true`, which `koopman::train` reads). Refused: an unknown kind, a
    /// `bilinear` setting that contradicts the kind, a setting the kind cannot honour
    /// ([`ModelKind::refusal`]). Settings the kind ignores are dropped.
    pub fn of_job(
        config: &serde_json::Map<String, serde_json::Value>,
    ) -> std::result::Result<(ModelKind, serde_json::Map<String, serde_json::Value>), String> {
        let named = match config.get(KIND_KEY) {
            None => None,
            Some(serde_json::Value::String(s)) => Some(Self::parse(s)?),
            Some(v) => return Err(format!("'{KIND_KEY}' must be a string, got {v}")),
        };
        let bilinear = match config.get("bilinear") {
            None => None,
            Some(serde_json::Value::Bool(b)) => Some(*b),
            Some(v) => return Err(format!("'bilinear' must be true or false, got {v}")),
        };
        let kind = match (named, bilinear) {
            (None | Some(ModelKind::Koopman), Some(true)) => ModelKind::Bilinear,
            (Some(ModelKind::Bilinear), Some(false)) => {
                return Err("kind 'bilinear' with bilinear = false: drop 'bilinear'".into())
            }
            (k, _) => k.unwrap_or_default(),
        };
        let mut fields = serde_json::Map::new();
        for (k, v) in config {
            if k == KIND_KEY {
                continue;
            }
            if let Some(why) = kind.refusal(k, v) {
                return Err(why);
            }
            if kind.uses(k) {
                fields.insert(k.clone(), v.clone());
            }
        }
        if kind == ModelKind::Bilinear {
            fields.insert("bilinear".into(), true.into());
        }
        Ok((kind, fields))
    }

    /// Whether the MPC service plans about a feed-forward with a model of this kind (the
    /// error-state MPC of `error_state` and `feedforward_file`): the Koopman MPC on a
    /// lifted-linear model (koopman, edmd) and random shooting about the plan on an NNDM; not
    /// the bilinear MPC.
    pub fn plans_about_feedforward(self) -> bool {
        !matches!(self, ModelKind::Bilinear)
    }

    /// What the MPC service controls a model of this kind with, in words.
    pub fn controller(self) -> &'static str {
        match self {
            ModelKind::Koopman | ModelKind::Edmd => "Koopman MPC (a QP on the lifted model)",
            ModelKind::Bilinear => "sequential convex MPC on the bilinear model",
            ModelKind::Nndm => "random-shooting MPC on the one-step model",
        }
    }
}

impl fmt::Display for ModelKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Why `kinds` cannot all train with the settings `fields` (`TrainConfig` settings shared by
/// every kind, e.g. a scenario's `[train].config`), or `Ok`: a setting that asks a
/// gradient-trained kind for something it cannot do ([`ModelKind::refusal`] of
/// `ctrl`/`cov`/`normalise`/`bilinear`: `normalise = true` for nndm or bilinear, `ctrl = true`
/// for nndm) is refused, naming the kind; EDMD, a least-squares fit, ignores the settings meant
/// for the gradient-trained kinds listed beside it; a setting that no listed kind uses is
/// refused (an optimiser setting, or `normalise`, with EDMD alone).
pub fn check_settings_for(
    kinds: &[ModelKind],
    fields: &serde_json::Map<String, serde_json::Value>,
) -> std::result::Result<(), String> {
    for (k, v) in fields {
        if k == KIND_KEY {
            return Err(format!(
                "'{KIND_KEY}' is not a training setting: the model kind is [train].model"
            ));
        }
        let refusals: Vec<(ModelKind, String)> = kinds
            .iter()
            .filter_map(|&kind| kind.refusal(k, v).map(|why| (kind, why)))
            .collect();
        let flag = matches!(k.as_str(), "ctrl" | "cov" | "normalise" | "bilinear");
        let everyone = refusals.len() == kinds.len();
        // A gradient-trained kind's reason first (EDMD's, "does not apply", says less).
        let pick = refusals
            .iter()
            .find(|(kind, _)| flag && *kind != ModelKind::Edmd)
            .or(refusals.first().filter(|_| everyone));
        if let Some((kind, why)) = pick {
            return Err(format!("model kind '{kind}': {why}"));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn map(v: serde_json::Value) -> serde_json::Map<String, serde_json::Value> {
        v.as_object().unwrap().clone()
    }

    #[test]
    fn kinds_parse_and_unknown_ones_list_the_valid() {
        for k in ModelKind::ALL {
            assert_eq!(ModelKind::parse(k.name()), Ok(k));
            assert_eq!(serde_json::to_value(k).unwrap(), json!(k.name()));
        }
        let e = ModelKind::parse("dmd").unwrap_err();
        assert_eq!(
            e,
            "unknown model kind 'dmd'; valid kinds: koopman, bilinear, edmd, nndm"
        );
    }

    #[test]
    fn a_job_config_names_its_kind_and_keeps_what_the_kind_uses() {
        let fields = map(json!({"iterations": 300, "ctrl": false, "gamma": 0.9}));
        let edmd = ModelKind::Edmd.job_config(&fields);
        assert_eq!(edmd, map(json!({"kind": "edmd", "gamma": 0.9})));
        let nndm = ModelKind::Nndm.job_config(&fields);
        assert_eq!(
            nndm,
            map(json!({"kind": "nndm", "iterations": 300, "gamma": 0.9}))
        );
        // Back on the service: the kind, and the TrainConfig settings.
        assert_eq!(
            ModelKind::of_job(&edmd),
            Ok((ModelKind::Edmd, map(json!({"gamma": 0.9}))))
        );
        let bil = ModelKind::Bilinear.job_config(&fields);
        let (k, f) = ModelKind::of_job(&bil).unwrap();
        assert_eq!(k, ModelKind::Bilinear);
        assert_eq!(f["bilinear"], json!(true));
        assert_eq!(f["ctrl"], json!(false));
        // No kind: koopman; the older `bilinear = true`: bilinear.
        assert_eq!(
            ModelKind::of_job(&map(json!({}))).unwrap().0,
            ModelKind::Koopman
        );
        let old = map(json!({"bilinear": true, "iterations": 5}));
        assert_eq!(ModelKind::of_job(&old).unwrap().0, ModelKind::Bilinear);
        // What a kind cannot do is refused with the reason.
        let e = ModelKind::of_job(&map(json!({"kind": "edmd", "iterations": 5}))).unwrap_err();
        assert!(
            e.contains("iterations does not apply to an edmd model"),
            "{e}"
        );
        let e = ModelKind::of_job(&map(json!({"kind": "nndm", "normalise": true}))).unwrap_err();
        assert!(e.contains("koopman model only, not nndm"), "{e}");
        let e = ModelKind::of_job(&map(json!({"kind": "nndm", "bilinear": true}))).unwrap_err();
        assert!(
            e.contains("bilinear = true asks for a bilinear model"),
            "{e}"
        );
        let e = ModelKind::of_job(&map(json!({"kind": "bilinear", "bilinear": false})));
        assert!(e.is_err());
        let e = ModelKind::of_job(&map(json!({"kind": "dmd"}))).unwrap_err();
        assert!(
            e.contains("valid kinds: koopman, bilinear, edmd, nndm"),
            "{e}"
        );
        assert!(ModelKind::of_job(&map(json!({"kind": 3}))).is_err());
    }

    #[test]
    fn shared_settings_are_checked_against_every_kind() {
        use ModelKind::*;
        let budget = map(json!({"iterations": 300, "hidden": [32]}));
        assert_eq!(check_settings_for(&[Koopman, Edmd], &budget), Ok(()));
        let e = check_settings_for(&[Edmd], &budget).unwrap_err();
        assert!(e.starts_with("model kind 'edmd': "), "{e}");
        let norm = map(json!({"normalise": true}));
        assert_eq!(check_settings_for(&[Koopman], &norm), Ok(()));
        let e = check_settings_for(&[Koopman, Nndm], &norm).unwrap_err();
        assert!(
            e.contains("'nndm'") && e.contains("koopman model only"),
            "{e}"
        );
        let e = check_settings_for(&[Edmd, Bilinear], &norm).unwrap_err();
        assert!(e.contains("'bilinear'"), "{e}");
        // EDMD ignores what is meant for the gradient-trained kinds beside it, not alone.
        assert_eq!(check_settings_for(&[Koopman, Edmd], &norm), Ok(()));
        assert!(check_settings_for(&[Edmd], &norm).is_err());
        let ctrl = map(json!({"ctrl": true}));
        assert_eq!(check_settings_for(&[Bilinear, Edmd], &ctrl), Ok(()));
        let e = check_settings_for(&[Nndm, Edmd], &ctrl).unwrap_err();
        assert!(e.contains("'nndm'"), "{e}");
        assert_eq!(
            check_settings_for(&[Nndm, Edmd], &map(json!({"ctrl": false}))),
            Ok(())
        );
        let e = check_settings_for(&[Koopman], &map(json!({"kind": "edmd"}))).unwrap_err();
        assert!(e.contains("[train].model"), "{e}");
    }
}
