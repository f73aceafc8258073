//! Reuse of a previous run's work in the same output folder: the collected datasets when the
//! scenario's `[[sims]]` and `[collect]` sections and the simulators' `info` are unchanged, a
//! trained model when, in addition, its kind and the `[train]` settings it uses are unchanged.
//! Each finished phase writes a record (its inputs as a key, its report) atomically; a phase
//! about to run removes its record first, so a record never describes files that a later,
//! interrupted run half replaced.

use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::fsutil::write_atomic;
use crate::messages::SimInfo;
use crate::scenario::Scenario;
use crate::services::model_kind::ModelKind;

#[derive(Serialize, Deserialize)]
struct Record<T> {
    key: serde_json::Value,
    report: T,
}

/// What the collected data depends on: the simulators (spec without their `train_config`, and
/// `info`) and `[collect]`.
pub fn collect_key(sc: &Scenario, infos: &[&SimInfo]) -> serde_json::Value {
    let sims: Vec<_> = sc
        .sims
        .iter()
        .map(|s| crate::scenario::SimSpec {
            train_config: serde_json::Map::new(),
            ..s.clone()
        })
        .collect();
    serde_json::json!({"sims": sims, "infos": infos, "collect": sc.collect})
}

/// What a trained model depends on: the data (`collect_key`) and the job config it is trained
/// with (its kind and the `[train].config` settings that kind uses,
/// [`super::train::job_config`]); so adding a kind to `[train].model` retrains no other kind.
pub fn train_key(
    collect_key: &serde_json::Value,
    job_config: &serde_json::Map<String, serde_json::Value>,
) -> serde_json::Value {
    serde_json::json!({"collect": collect_key, "train": job_config})
}

/// The record of the collection phase in `out_dir`.
pub fn collect_record(out_dir: &Path) -> PathBuf {
    out_dir.join("data").join("collect.json")
}

/// The record of the training of simulator `sim`'s model of kind `kind` in `out_dir`
/// (`train-{sim}.json` for `koopman`, `train-{sim}-{kind}.json` for the others).
pub fn train_record(out_dir: &Path, sim: &str, kind: ModelKind) -> PathBuf {
    let file = match kind {
        ModelKind::Koopman => format!("train-{sim}.json"),
        k => format!("train-{sim}-{k}.json"),
    };
    out_dir.join("state").join("orchestrator").join(file)
}

/// The report stored at `path` if the record exists, parses and was made from `key`.
pub fn load<T: DeserializeOwned>(path: &Path, key: &serde_json::Value) -> Option<T> {
    let bytes = std::fs::read(path).ok()?;
    let r: Record<T> = serde_json::from_slice(&bytes).ok()?;
    (r.key == *key).then_some(r.report)
}

/// Writes the record of a finished phase (atomically).
pub fn store<T: Serialize>(path: &Path, key: &serde_json::Value, report: &T) -> Result<()> {
    let bytes = serde_json::to_vec_pretty(&Record {
        key: key.clone(),
        report,
    })
    .map_err(|e| Error::Config(e.to_string()))?;
    Ok(write_atomic(path, &bytes)?)
}

/// Removes the record at `path` (before the phase it describes runs again).
pub fn forget(path: &Path) -> Result<()> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(Error::Io {
            path: path.to_path_buf(),
            source: e,
        }),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_record_is_found_only_under_its_key_and_forgotten() {
        let d = std::env::temp_dir().join(format!("kb-reuse-{}", std::process::id()));
        let p = d.join("r.json");
        let k1 = serde_json::json!({"collect": {"seed": 1}});
        let k2 = serde_json::json!({"collect": {"seed": 2}});
        assert_eq!(load::<u32>(&p, &k1), None);
        store(&p, &k1, &7u32).unwrap();
        assert_eq!(load::<u32>(&p, &k1), Some(7));
        assert_eq!(load::<u32>(&p, &k2), None);
        forget(&p).unwrap();
        forget(&p).unwrap();
        assert_eq!(load::<u32>(&p, &k1), None);
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn a_simulators_training_settings_are_not_what_its_data_depend_on() {
        let text = |own: &str| {
            format!(
                "name = \"k\"\n[[sims]]\nid = \"p\"\nenv = \"damped-pendulum\"\n{own}\n\
                 [collect]\npolicy = {{ kind = \"adapter\" }}\ntrain_windows = 2\n\
                 val_windows = 1\ntest_windows = 1\n[train]\nconfig = {{}}\n"
            )
        };
        let key = |own: &str| collect_key(&Scenario::parse(&text(own)).unwrap(), &[]);
        assert_eq!(key(""), key("train_config = { n_mult = 4 }"));
        assert_ne!(
            key(""),
            key("collect_inputs = { kind = \"uniform\", low = 0.1 }")
        );
    }

    #[test]
    fn each_kind_has_its_own_record_and_key() {
        let d = Path::new("/o");
        let records: Vec<PathBuf> = ModelKind::ALL
            .iter()
            .map(|&k| train_record(d, "pend", k))
            .collect();
        assert_eq!(records[0], d.join("state/orchestrator/train-pend.json"));
        assert_eq!(
            records[2],
            d.join("state/orchestrator/train-pend-edmd.json")
        );
        for (i, r) in records.iter().enumerate() {
            assert!(!records[..i].contains(r), "{r:?} twice");
        }
        let c = serde_json::json!({"seed": 1});
        let fields = serde_json::json!({"iterations": 5})
            .as_object()
            .unwrap()
            .clone();
        let key = |k: ModelKind| train_key(&c, &k.job_config(&fields));
        assert_ne!(key(ModelKind::Koopman), key(ModelKind::Nndm));
        assert_ne!(key(ModelKind::Koopman), key(ModelKind::Bilinear));
    }
}
