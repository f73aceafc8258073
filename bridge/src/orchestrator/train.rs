//! Training one simulator's model through the trainer service for a run — the first model and
//! each aggregation round's — and the report of it.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{Cluster, Event, RunOptions, SERVICES_ID};
use crate::error::{Error, ErrorCode, Result};
use crate::keyexpr::Role;
use crate::scenario::Scenario;
use crate::services::model_kind::ModelKind;
use crate::services::trainer::{submit_and_wait_watching, DatasetRef, JobSpec};

/// Training result of one simulator's model.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TrainReport {
    /// Simulator id.
    pub sim: String,
    /// Model name in the store.
    pub model: String,
    /// Trainer job id.
    pub job: String,
    /// Metrics reported by the trainer.
    pub metrics: serde_json::Value,
    /// True when this run reused the model a previous run trained into the same folder from
    /// the same data and `[train]` section.
    #[serde(default)]
    pub reused: bool,
}

/// Trains model `model` of simulator `sim` through the trainer service on the training windows
/// in file `train` (validation and test: the collected `val.npz`/`test.npz` of `sim`), with the
/// scenario's `[train]` settings and its first model kind (what aggregation retrains; a run
/// trains each kind with [`train_model_as`]).
pub fn train_model(
    sc: &Scenario,
    opts: &RunOptions,
    cluster: &Cluster,
    sim: &str,
    model: &str,
    train: &Path,
    on: &mut dyn FnMut(Event<'_>),
) -> Result<TrainReport> {
    let kind = sc
        .train
        .as_ref()
        .map(|t| t.kinds()[0])
        .ok_or_else(|| Error::Config("no [train]".into()))?;
    train_model_as(sc, opts, cluster, sim, kind, model, train, on)
}

/// The job config of simulator `sim`'s `kind` model with the scenario's `[train].config` and
/// the simulator's own `train_config` over it ([`Scenario::train_config_of`];
/// [`ModelKind::job_config`]: the settings the kind uses, and the kind).
pub fn job_config(
    sc: &Scenario,
    sim: &str,
    kind: ModelKind,
) -> Result<serde_json::Map<String, serde_json::Value>> {
    if sc.train.is_none() {
        return Err(Error::Config("no [train]".into()));
    }
    Ok(kind.job_config(&sc.train_config_of(sim)))
}

/// [`train_model`] of a model of kind `kind` (the trainer service trains each kind with its own
/// `koopman` training path, the MPC service controls it with its kind's controller).
#[allow(clippy::too_many_arguments)]
pub fn train_model_as(
    sc: &Scenario,
    opts: &RunOptions,
    cluster: &Cluster,
    sim: &str,
    kind: ModelKind,
    model: &str,
    train: &Path,
    on: &mut dyn FnMut(Event<'_>),
) -> Result<TrainReport> {
    let config = job_config(sc, sim, kind)?;
    let dir = opts.out_dir.join("data").join(sim);
    let abs = |p: PathBuf| -> DatasetRef {
        DatasetRef::Path {
            path: std::fs::canonicalize(&p).unwrap_or(p),
        }
    };
    let spec = JobSpec {
        model: model.to_string(),
        train: abs(train.to_path_buf()),
        val: abs(dir.join("val.npz")),
        test: (sc.collect.test_windows > 0).then(|| abs(dir.join("test.npz"))),
        config,
    };
    // The simulators are needed again after training: a lost one ends the run now.
    let sims: Vec<(Role, String)> = sc.sims.iter().map(|s| (Role::Sim, s.id.clone())).collect();
    let (client, live) = (&cluster.client, &cluster.live);
    let rec = submit_and_wait_watching(client, live, SERVICES_ID, &spec, &sims, &mut |p| {
        on(Event::Train(p))
    })
    .map_err(|e| match e {
        // A trainer started separately (--attach-existing) reads only its own data root.
        Error::Remote { who, mut reply } if reply.code == ErrorCode::Forbidden => {
            reply.message.push_str(&format!(
                "; a trainer started separately needs a --data-root that holds this run's \
                 data folder {}",
                opts.out_dir.join("data").display()
            ));
            Error::Remote { who, reply }
        }
        e => e,
    })?;
    Ok(TrainReport {
        sim: sim.to_string(),
        model: model.to_string(),
        job: rec.job,
        metrics: rec.metrics.unwrap_or_default(),
        reused: false,
    })
}
