//! The trainer service's [`Trainer`] for the neural Koopman model of `koopman::train`: loads the
//! job's datasets (files or recordings fetched over Zenoh), trains, saves the model.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use koopman::data::Dataset;
use koopman::train::{train, TrainConfig};
use zenoh::Session;

use super::trainer::{serve_with, DatasetRef, JobSpec, Trainer};
use crate::client::Client;
use crate::error::{Error, Result};
use crate::keyexpr::{validate_chunk, Keys};

/// Trains `koopman::model::koopman::KoopmanModel`s.
pub struct KoopmanTrainer {
    client: Client,
    fetch_dir: PathBuf,
}

impl KoopmanTrainer {
    /// A trainer that fetches recordings through `client` into `fetch_dir`.
    pub fn new(client: Client, fetch_dir: PathBuf) -> Self {
        KoopmanTrainer { client, fetch_dir }
    }

    fn load(&self, r: &DatasetRef) -> Result<Dataset> {
        match r {
            DatasetRef::Path { path } => Ok(Dataset::load_npz(path)?),
            DatasetRef::Recording { recording } => {
                validate_chunk("recording name", recording)?;
                let key = self.client.keys.data(recording)?;
                let bytes = self.client.query(
                    &key,
                    Vec::new(),
                    Duration::from_secs(60),
                    &format!("recorder ({recording})"),
                )?;
                std::fs::create_dir_all(&self.fetch_dir).map_err(|e| Error::Io {
                    path: self.fetch_dir.clone(),
                    source: e,
                })?;
                let p = self.fetch_dir.join(format!("{recording}.npz"));
                crate::fsutil::write_atomic(&p, &bytes)?;
                Ok(Dataset::load_npz(&p)?)
            }
        }
    }
}

/// `TrainConfig` from SPEC defaults overlaid with the job's fields (unknown fields are an error).
pub fn train_config(fields: &serde_json::Map<String, serde_json::Value>) -> Result<TrainConfig> {
    let mut v =
        serde_json::to_value(TrainConfig::default()).map_err(|e| Error::Config(e.to_string()))?;
    let obj = v
        .as_object_mut()
        .ok_or_else(|| Error::Config("TrainConfig is not an object".into()))?;
    for (k, val) in fields {
        if !obj.contains_key(k) {
            return Err(Error::Config(format!("unknown training setting '{k}'")));
        }
        obj.insert(k.clone(), val.clone());
    }
    serde_json::from_value(v).map_err(|e| Error::Config(format!("training config: {e}")))
}

impl Trainer for KoopmanTrainer {
    fn train(
        &self,
        spec: &JobSpec,
        out_dir: &Path,
        progress: &mut dyn FnMut(serde_json::Value) -> ControlFlow<()>,
    ) -> Result<serde_json::Value> {
        let cfg = train_config(&spec.config)?;
        let tr = self.load(&spec.train)?;
        let va = self.load(&spec.val)?;
        let te = spec.test.as_ref().map(|t| self.load(t)).transpose()?;
        let mut obs =
            |p: &koopman::train::Progress| progress(serde_json::to_value(p).unwrap_or_default());
        let outcome = train(&cfg, &tr, &va, te.as_ref(), &mut obs)?;
        outcome.model.save(out_dir)?;
        serde_json::to_value(&outcome.metrics).map_err(|e| Error::Config(e.to_string()))
    }
}

/// Serves trainer `id` with the Koopman trainer (see [`serve_with`]).
pub fn serve(
    session: &Session,
    keys: &Keys,
    id: &str,
    store: &Path,
    state_dir: &Path,
    max_jobs: usize,
    stop: &AtomicBool,
) -> Result<()> {
    let client = Client::new(session.clone(), keys.clone());
    let trainer = Arc::new(KoopmanTrainer::new(client, state_dir.join("fetched")));
    serve_with(session, keys, id, store, state_dir, max_jobs, trainer, stop)
}
