//! The models a scenario names under `[train] pretrained`: each folder checked (its kind, its
//! `nx`/`nu` against its simulator's) and copied into the run's model store, `OUT/models/{name}`,
//! where the MPC service finds it by name.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::commands::Placeholders;
use super::reference::reference_path;
use crate::error::{Error, Result};
use crate::messages::SimInfo;
use crate::scenario::Scenario;
use crate::services::model_kind::ModelKind;

/// A model trained elsewhere, installed in the run's model store.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pretrained {
    /// Its name in the store (and its rows' name).
    pub name: String,
    /// The simulator whose tracking tasks score it.
    pub sim: String,
    /// Its kind (`config.json`'s `kind`).
    pub kind: ModelKind,
    /// The folder it was copied from.
    pub path: PathBuf,
}

/// Checks every `[train] pretrained` model of `sc` that exists already (with `only_present`:
/// those whose path does not name `{out}`, which a hook may still write), and with `store` copies
/// each into it; `infos[j]` is `sc.sims[j]`'s. An error names the model and what is wrong (a
/// missing folder, no `config.json`, an unknown kind, dimensions that are not the simulator's).
pub fn install(
    sc: &Scenario,
    ph: &Placeholders,
    infos: &[&SimInfo],
    only_present: bool,
    store: Option<&Path>,
) -> Result<Vec<Pretrained>> {
    let Some(t) = &sc.train else {
        return Ok(Vec::new());
    };
    let mut out = Vec::new();
    for p in t
        .pretrained
        .iter()
        .filter(|p| !(only_present && p.path.contains("{out}")))
    {
        let bad = |m: String| Error::Config(format!("[train] pretrained '{}': {m}", p.name));
        let j = match &p.sim {
            Some(s) => sc.sims.iter().position(|x| &x.id == s).unwrap_or(0),
            None => 0,
        };
        let (sim, info) = (&sc.sims[j].id, infos[j]);
        let path = reference_path(&p.path, ph);
        let config = path.join("config.json");
        let text = std::fs::read_to_string(&config).map_err(|e| {
            bad(format!(
                "{} is not a model folder ({}: {e})",
                path.display(),
                config.display()
            ))
        })?;
        let c: serde_json::Value =
            serde_json::from_str(&text).map_err(|e| bad(format!("{}: {e}", config.display())))?;
        let kind = ModelKind::parse(c["kind"].as_str().unwrap_or("koopman")).map_err(bad)?;
        let dims = (c["nx"].as_u64(), c["nu"].as_u64());
        if dims != (Some(info.nx() as u64), Some(info.nu() as u64)) {
            return Err(bad(format!(
                "its nx/nu are {}/{}, simulator '{sim}' has {}/{}",
                dims.0.map_or("?".into(), |v| v.to_string()),
                dims.1.map_or("?".into(), |v| v.to_string()),
                info.nx(),
                info.nu()
            )));
        }
        if let Some(out_dir) = store {
            copy_model(&path, &out_dir.join("models").join(&p.name)).map_err(|e| {
                bad(format!(
                    "copying {} into the model store: {e}",
                    path.display()
                ))
            })?;
        }
        out.push(Pretrained {
            name: p.name.clone(),
            sim: sim.clone(),
            kind,
            path,
        });
    }
    Ok(out)
}

/// Copies the files of model folder `from` to `to` (replacing it): into a temporary sibling
/// first, renamed into place, so that a reader never sees half a model.
fn copy_model(from: &Path, to: &Path) -> std::io::Result<()> {
    let parent = to.parent().expect("a store path has a parent");
    std::fs::create_dir_all(parent)?;
    let name = to.file_name().and_then(|n| n.to_str()).unwrap_or("model");
    let tmp = parent.join(format!(".{name}.installing"));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp)?;
    }
    std::fs::create_dir(&tmp)?;
    for e in std::fs::read_dir(from)? {
        let e = e?;
        if e.file_type()?.is_file() {
            std::fs::copy(e.path(), tmp.join(e.file_name()))?;
        }
    }
    if to.exists() {
        std::fs::remove_dir_all(to)?;
    }
    std::fs::rename(&tmp, to)
}
