//! `[full]`: the overrides `koopbridge run --full` applies (the SPEC budget), and the control
//! settings in force there.

use serde::{Deserialize, Serialize};

use super::control::ControlSpec;
use super::track::TrackSpec;
use crate::error::{Error, Result};

/// Overrides for `--full`.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FullSpec {
    /// Training windows.
    pub train_windows: Option<usize>,
    /// Validation windows.
    pub val_windows: Option<usize>,
    /// Test windows.
    pub test_windows: Option<usize>,
    /// Training config overrides (merged over `[train.config]`).
    #[serde(default)]
    pub train_config: serde_json::Map<String, serde_json::Value>,
    /// `[control]` keys that replace `[control_defaults]`'s (each key whole) with `--full`: they
    /// reach the entries that take that key from the defaults, never an entry that sets it
    /// itself (so a row written out in full — SPEC's formulation — stays as written).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub control_defaults: Option<toml::Table>,
}

/// The control entries parsed with `[full].control_defaults` in force.
#[derive(Clone, Debug)]
pub(crate) struct FullControls {
    /// The `[control]` entries that are not tracking tasks.
    pub control: Vec<ControlSpec>,
    /// The tracking tasks.
    pub tracks: Vec<TrackSpec>,
}

/// The scenario document as `--full` reads it when `[full]` has `control_defaults`: those keys
/// over `[control_defaults]`'s (a file without `[control_defaults]` gets them as its defaults).
/// `None` without `[full].control_defaults`.
pub(super) fn doc_with_full_control_defaults(doc: &toml::Table) -> Result<Option<toml::Table>> {
    let Some(over) = doc.get("full").and_then(|f| f.get("control_defaults")) else {
        return Ok(None);
    };
    let toml::Value::Table(over) = over else {
        return Err(Error::Config(
            "[full].control_defaults must be a table of [control] keys".into(),
        ));
    };
    let mut full = doc.clone();
    let defaults = full
        .entry("control_defaults")
        .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    let toml::Value::Table(defaults) = defaults else {
        return Err(Error::Config(
            "[control_defaults] must be a table of [control] keys".into(),
        ));
    };
    for (k, v) in over {
        defaults.insert(k.clone(), v.clone());
    }
    Ok(Some(full))
}
