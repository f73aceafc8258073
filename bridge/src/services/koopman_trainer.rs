//! The trainer service's [`Trainer`] for every model kind of `koopman` ([`ModelKind`], named by
//! the job config's `"kind"`): the neural Koopman model (linear, or bilinear), the NNDM baseline
//! and EDMD; loads the job's datasets (files or recordings fetched over Zenoh), trains a Koopman
//! model from scratch or from the job's checkpoint (checkpointing at every validation; an NNDM
//! or EDMD job starts anew), saves the model.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use koopman::data::Dataset;
use koopman::model::arch::Arch;
use koopman::train::run_fingerprint;
use koopman::train::{train_bilinear_resumable, train_resumable, Checkpoint, TrainConfig};
use zenoh::Session;

use super::model_kind::ModelKind;
use super::trainer::{serve_with, DatasetRef, JobSpec, TrainProgress, Trainer};
use crate::client::Client;
use crate::error::{Error, ErrorCode, ErrorReply, Result};
use crate::fsutil::DataRoot;
use crate::keyexpr::{validate_chunk, Keys};

/// Threads (and so row parts of the gradient) of a job that does not set `threads`. The
/// gradient is summed over one row part per thread, so the bits of a trained model depend on this
/// number; the service fixes it (instead of "all cores") so that the same job gives the same
/// model on every machine.
pub const DEFAULT_TRAIN_THREADS: usize = 2;

/// Trains `koopman::model::koopman::KoopmanModel`s.
pub struct KoopmanTrainer {
    client: Client,
    fetch_dir: PathBuf,
    threads: usize,
}

impl KoopmanTrainer {
    /// A trainer that fetches recordings through `client` into `fetch_dir` and trains jobs that
    /// do not set `threads` with [`DEFAULT_TRAIN_THREADS`].
    pub fn new(client: Client, fetch_dir: PathBuf) -> Self {
        KoopmanTrainer {
            client,
            fetch_dir,
            threads: DEFAULT_TRAIN_THREADS,
        }
    }

    /// The same trainer with another default thread count (≥ 1) for jobs that do not set
    /// `threads`.
    pub fn with_threads(mut self, threads: usize) -> Self {
        self.threads = threads.max(1);
        self
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

/// The checkpoint in `path` if it can continue this job; `None` (with a warning) if there is none,
/// it is damaged, or it belongs to another configuration or other data.
fn usable_checkpoint(
    path: &Path,
    cfg: &TrainConfig,
    tr: &Dataset,
    va: &Dataset,
) -> Option<Checkpoint> {
    if !path.exists() {
        return None;
    }
    let check = || -> koopman::Result<Checkpoint> {
        let ck = Checkpoint::load(path)?;
        let arch = Arch::new(tr.nx, tr.nu, &cfg.hidden, cfg.n_mult)?;
        let extra = if cfg.bilinear {
            koopman::train::bilinear::bilinear_len(&arch)
        } else {
            0
        };
        ck.check_compatible(cfg, arch.num_params() + extra, run_fingerprint(cfg, tr, va))?;
        Ok(ck)
    };
    match check() {
        Ok(ck) => Some(ck),
        Err(e) => {
            tracing::warn!(
                "ignoring checkpoint {}: {e}; the job starts from scratch",
                path.display()
            );
            None
        }
    }
}

/// `TrainConfig` from SPEC defaults overlaid with the job's fields. An unknown field or a value
/// of the wrong type is a `bad_request` protocol error; an unknown field's error lists the valid
/// settings. `threads` keeps its default (0 = all cores) here; the service fills it in, see
/// [`DEFAULT_TRAIN_THREADS`].
pub fn train_config(fields: &serde_json::Map<String, serde_json::Value>) -> Result<TrainConfig> {
    let mut v =
        serde_json::to_value(TrainConfig::default()).map_err(|e| Error::Config(e.to_string()))?;
    let obj = v
        .as_object_mut()
        .ok_or_else(|| Error::Config("TrainConfig is not an object".into()))?;
    for (k, val) in fields {
        if !obj.contains_key(k) {
            let mut valid: Vec<&str> = obj.keys().map(String::as_str).collect();
            valid.sort_unstable();
            return Err(Error::protocol(
                ErrorCode::BadRequest,
                format!(
                    "unknown training setting '{k}'; valid settings: {}",
                    valid.join(", ")
                ),
            ));
        }
        obj.insert(k.clone(), val.clone());
    }
    serde_json::from_value(v)
        .map_err(|e| Error::protocol(ErrorCode::BadRequest, format!("training config: {e}")))
}

impl Trainer for KoopmanTrainer {
    /// Refuses a job whose settings do not make a `TrainConfig` (`bad_request`, naming the
    /// valid settings) before it is queued.
    fn validate(&self, spec: &JobSpec) -> std::result::Result<(), ErrorReply> {
        job_settings(&spec.config)
            .map(|_| ())
            .map_err(|e| e.to_reply())
    }

    fn train(
        &self,
        spec: &JobSpec,
        out_dir: &Path,
        checkpoint: &Path,
        progress: &mut dyn FnMut(&TrainProgress) -> ControlFlow<()>,
    ) -> Result<serde_json::Value> {
        let (kind, mut cfg) = job_settings(&spec.config)?;
        if !spec.config.contains_key("threads") {
            cfg.threads = self.threads;
        }
        let tr = self.load(&spec.train)?;
        let va = self.load(&spec.val)?;
        let te = spec.test.as_ref().map(|t| self.load(t)).transpose()?;
        let with_kind = |v: serde_json::Value| -> Result<serde_json::Value> {
            let mut v = v;
            if let Some(o) = v.as_object_mut() {
                o.insert("kind".into(), kind.name().into());
            }
            Ok(v)
        };
        match kind {
            ModelKind::Edmd => return with_kind(fit_edmd(&cfg, &tr, &va, te.as_ref(), out_dir)?),
            ModelKind::Nndm => {
                let mut obs = |p: &koopman::train::Progress| {
                    progress(&TrainProgress {
                        resumed_from: 0,
                        train: p.clone(),
                    })
                };
                let o = koopman::train::nndm::train_nndm(&cfg, &tr, &va, te.as_ref(), &mut obs)?;
                o.model.save(out_dir)?;
                return with_kind(
                    serde_json::to_value(&o.metrics).map_err(|e| Error::Config(e.to_string()))?,
                );
            }
            ModelKind::Koopman | ModelKind::Bilinear => {}
        }
        let explicit_ctrl = spec.config.get("ctrl") == Some(&serde_json::Value::Bool(true));
        cfg.settle_ctrl_for(tr.nu, explicit_ctrl)
            .map_err(|e| Error::protocol(ErrorCode::BadRequest, e.to_string()))?;
        let resume = usable_checkpoint(checkpoint, &cfg, &tr, &va);
        let resumed_from = resume.as_ref().map_or(0, |c| c.iteration);
        if resumed_from > 0 {
            tracing::info!(
                "resuming job for model '{}' at iteration {resumed_from}",
                spec.model
            );
        }
        let mut obs = |p: &koopman::train::Progress| {
            progress(&TrainProgress {
                resumed_from: resumed_from as u64,
                train: p.clone(),
            })
        };
        let mut save = |c: &Checkpoint| {
            if let Err(e) = c.save(checkpoint) {
                tracing::warn!("could not write checkpoint {}: {e}", checkpoint.display());
            }
        };
        // `bilinear = true` in the job's config trains (and stores) a bilinear model.
        let trained = if cfg.bilinear {
            let o = train_bilinear_resumable(
                &cfg,
                &tr,
                &va,
                te.as_ref(),
                resume.as_ref(),
                &mut obs,
                &mut save,
            )?;
            o.model.save(out_dir)?;
            o.metrics
        } else {
            let o = train_resumable(
                &cfg,
                &tr,
                &va,
                te.as_ref(),
                resume.as_ref(),
                &mut obs,
                &mut save,
            )?;
            o.model.save(out_dir)?;
            o.metrics
        };
        let mut metrics =
            serde_json::to_value(&trained).map_err(|e| Error::Config(e.to_string()))?;
        if let Some(o) = metrics.as_object_mut() {
            o.insert("resumed_from".into(), resumed_from.into());
        }
        with_kind(metrics)
    }
}

/// A job config's kind and its `TrainConfig` ([`ModelKind::of_job`] over [`train_config`]);
/// what the kind cannot do is a `bad_request` naming it.
pub fn job_settings(
    config: &serde_json::Map<String, serde_json::Value>,
) -> Result<(ModelKind, TrainConfig)> {
    let (kind, fields) = ModelKind::of_job(config)
        .map_err(|m| Error::protocol(ErrorCode::BadRequest, format!("training config: {m}")))?;
    Ok((kind, train_config(&fields)?))
}

/// EDMD with control (`koopman::model::edmd`) on the first `cfg.train_samples` training windows,
/// its dictionary's degree chosen by validation error (`degree_selection` in the metrics), saved
/// into `out_dir`; the metrics are those of `koopbridge train --model edmd` (prediction errors
/// with `cfg.gamma`).
fn fit_edmd(
    cfg: &TrainConfig,
    tr: &Dataset,
    va: &Dataset,
    te: Option<&Dataset>,
    out_dir: &Path,
) -> Result<serde_json::Value> {
    let started = std::time::Instant::now();
    let m = cfg.train_samples.unwrap_or(tr.n);
    let edmd = koopman::model::edmd::EdmdConfig::default();
    let (model, selection) =
        koopman::model::edmd::fit_by_validation(&tr.head(m)?, va, &edmd, cfg.gamma)?;
    let fit_seconds = started.elapsed().as_secs_f64();
    model.save(out_dir)?;
    let test = te
        .map(|t| model.prediction_error(t, cfg.gamma))
        .transpose()?;
    let val = model.prediction_error(va, cfg.gamma)?;
    Ok(serde_json::json!({
        "test_prediction_error": test,
        "validation_prediction_error": val,
        "best_validation_prediction_error": val,
        "fit_seconds": fit_seconds,
        "wall_seconds": started.elapsed().as_secs_f64(),
        "train_samples": m,
        "pairing": tr.meta.pairing,
        "env": tr.meta.env,
        "gamma": cfg.gamma,
        "config": model.config,
        "degree_selection": selection,
        "fit": model.info,
    }))
}

/// Serves trainer `id` with the Koopman trainer (see [`serve_with`]); jobs that do not set
/// `threads` train with `threads` threads; dataset paths must lie inside `data_root`.
#[allow(clippy::too_many_arguments)]
pub fn serve(
    session: &Session,
    keys: &Keys,
    id: &str,
    store: &Path,
    state_dir: &Path,
    data_root: &DataRoot,
    max_jobs: usize,
    threads: usize,
    stop: &AtomicBool,
) -> Result<()> {
    let client = Client::new(session.clone(), keys.clone());
    let trainer =
        Arc::new(KoopmanTrainer::new(client, state_dir.join("fetched")).with_threads(threads));
    serve_with(
        session, keys, id, store, state_dir, data_root, max_jobs, trainer, stop,
    )
}
