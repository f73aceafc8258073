//! A scenario's `[train]` table: which kinds of model to train (`model`, one or a list), the
//! training settings they share (`config`) and the models trained elsewhere (`pretrained`),
//! checked together when the file is read.

use serde::{Deserialize, Serialize};

use super::pretrained::PretrainedSpec;
use crate::error::{Error, Result};
use crate::services::model_kind::{check_settings_for, ModelKind};

/// Training through the trainer service: one model of each kind in `model` per simulator (each
/// then controlled by the MPC service, with the controller of its kind).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainSpec {
    /// The kinds of model to train: `"koopman"` (the default), `"bilinear"`, `"edmd"`, `"nndm"`,
    /// or a list of distinct kinds (`["koopman", "edmd"]`) to train each and control with each
    /// (the report sets them side by side). Absent: `koopman`, or `bilinear` when `config` has
    /// `bilinear = true` (the older spelling).
    #[serde(
        default,
        deserialize_with = "kinds",
        skip_serializing_if = "Option::is_none"
    )]
    pub model: Option<Vec<ModelKind>>,
    /// `koopman::train::TrainConfig` fields to override (JSON object; the rest = SPEC defaults),
    /// for every kind that uses them ([`crate::services::model_kind`]).
    #[serde(default)]
    pub config: serde_json::Map<String, serde_json::Value>,
    /// Model folders trained elsewhere, scored by the tracking tasks beside the models trained
    /// here (one row each; [`super::pretrained`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub pretrained: Vec<PretrainedSpec>,
}

/// `model = "kind"` or `model = ["kind", …]`; an unknown kind names itself and the valid ones.
fn kinds<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> std::result::Result<Option<Vec<ModelKind>>, D::Error> {
    use serde::de::Error as _;
    let names: Vec<String> = match toml::Value::deserialize(d)? {
        toml::Value::String(s) => vec![s],
        toml::Value::Array(a) => a
            .into_iter()
            .map(|v| match v {
                toml::Value::String(s) => Ok(s),
                v => Err(D::Error::custom(format!(
                    "[train].model: a model kind is a string, got {v}"
                ))),
            })
            .collect::<std::result::Result<_, _>>()?,
        v => {
            return Err(D::Error::custom(format!(
                "[train].model must be a kind or a list of kinds, got {v}"
            )))
        }
    };
    names
        .iter()
        .map(|n| ModelKind::parse(n))
        .collect::<std::result::Result<Vec<_>, _>>()
        .map(Some)
        .map_err(|e| D::Error::custom(format!("[train].model: {e}")))
}

impl TrainSpec {
    /// The kinds to train, in order ([`TrainSpec::model`], or what `config` implies without it).
    pub fn kinds(&self) -> Vec<ModelKind> {
        match &self.model {
            Some(k) => k.clone(),
            None if self.config.get("bilinear") == Some(&serde_json::Value::Bool(true)) => {
                vec![ModelKind::Bilinear]
            }
            None => vec![ModelKind::Koopman],
        }
    }

    /// Checks the kinds against each other and against the settings in force: at least one
    /// kind, no kind twice, no `bilinear` setting beside `model` (in `config` or `full_config`,
    /// `[full].train_config`: the older spelling contradicts `model` either way), and no
    /// setting of `config` that a listed kind cannot honour ([`check_settings_for`]). `config`
    /// is what training uses: `[train].config`, or with `--full` the merge
    /// ([`crate::scenario::Scenario::apply_full`]); `[full].train_config` alone is not in force
    /// without `--full`, so a setting there that a kind cannot honour is refused only then.
    pub fn check(&self, full_config: &serde_json::Map<String, serde_json::Value>) -> Result<()> {
        let bad = |m: String| Err(Error::Config(format!("[train]: {m}")));
        if let Some(k) = &self.model {
            if k.is_empty() {
                return bad("`model` lists no kind (give one of koopman, bilinear, edmd, nndm, or a list of them)".into());
            }
            if let Some(i) = (1..k.len()).find(|&i| k[..i].contains(&k[i])) {
                return bad(format!(
                    "model kind '{}' is listed twice in `model` (each kind trains one model per simulator)",
                    k[i]
                ));
            }
            for (table, c) in [
                ("config", &self.config),
                ("[full].train_config", full_config),
            ] {
                if c.contains_key("bilinear") {
                    return bad(format!(
                        "`bilinear` in {table} is the older spelling of model = \"bilinear\"; \
                         with `model` given, list the kinds there only"
                    ));
                }
            }
        }
        check_settings_for(&self.kinds(), &self.config)
            .map_err(|m| Error::Config(format!("[train] config: {m}")))?;
        Ok(())
    }
}
