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
        let c = koopman::model::store::read_config(&path)
            .map_err(|e| bad(format!("{} is not a model folder ({e})", path.display())))?;
        let kind = ModelKind::parse(c["kind"].as_str().unwrap_or("koopman")).map_err(bad)?;
        if let Some(t) = sc
            .tracks
            .iter()
            .find(|t| t.error_state && sc.tracked_id(t) == sim && !kind.plans_about_feedforward())
        {
            return Err(bad(format!(
                "a {kind} model cannot be a row of the `error_state` task{} (the error-state \
                 MPC needs a lifted-linear model or an NNDM)",
                t.label
                    .as_ref()
                    .map_or(String::new(), |l| format!(" '{l}'"))
            )));
        }
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

/// Copies the files of model folder `from` to `to`, replacing it atomically
/// ([`koopman::fsutil::write_dir_atomic`]): a reader never sees half a model.
fn copy_model(from: &Path, to: &Path) -> koopman::Result<()> {
    let io = |p: &Path, e| koopman::Error::io(p, e);
    koopman::fsutil::write_dir_atomic(to, |tmp| {
        for e in std::fs::read_dir(from).map_err(|e| io(from, e))? {
            let e = e.map_err(|e| io(from, e))?;
            if e.file_type().is_ok_and(|t| t.is_file()) {
                std::fs::copy(e.path(), tmp.join(e.file_name())).map_err(|x| io(&e.path(), x))?;
            }
        }
        Ok(())
    })
}
