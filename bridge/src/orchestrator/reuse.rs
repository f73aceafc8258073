//! Reuse of a previous run's work in the same output folder: the collected datasets when the
//! scenario's `[[sims]]` and `[collect]` sections and the simulators' `info` are unchanged, a
//! trained model when, in addition, `[train]` is unchanged. Each finished phase writes a record
//! (its inputs as a key, its report) atomically; a phase about to run removes its record first,
//! so a record never describes files that a later, interrupted run half replaced.

use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::fsutil::write_atomic;
use crate::messages::SimInfo;
use crate::scenario::{Scenario, TrainSpec};

#[derive(Serialize, Deserialize)]
struct Record<T> {
    key: serde_json::Value,
    report: T,
}

/// What the collected data depends on: the simulators (spec and `info`) and `[collect]`.
pub fn collect_key(sc: &Scenario, infos: &[&SimInfo]) -> serde_json::Value {
    serde_json::json!({"sims": sc.sims, "infos": infos, "collect": sc.collect})
}

/// What a trained model depends on: the data (`collect_key`) and `[train]`.
pub fn train_key(collect_key: &serde_json::Value, train: &TrainSpec) -> serde_json::Value {
    serde_json::json!({"collect": collect_key, "train": train})
}

/// The record of the collection phase in `out_dir`.
pub fn collect_record(out_dir: &Path) -> PathBuf {
    out_dir.join("data").join("collect.json")
}

/// The record of the training of simulator `sim`'s model in `out_dir`.
pub fn train_record(out_dir: &Path, sim: &str) -> PathBuf {
    out_dir
        .join("state")
        .join("orchestrator")
        .join(format!("train-{sim}.json"))
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
}
