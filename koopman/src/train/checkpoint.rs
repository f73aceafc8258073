//! Resumable snapshots of a training run (parameters, Adam moments, sampler state, best so far),
//! saved atomically as one safetensors file, so that an interrupted run continues bit for bit.

use super::loss::LossParts;
use super::TrainConfig;
use crate::data::Dataset;
use crate::fsutil::write_atomic;
use crate::model::store::{read_file, read_tensor};
use crate::{Error, Result};
use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::Path;

/// Version of the checkpoint file layout.
const FORMAT: u32 = 1;
/// Metadata key of the scalar state in the safetensors header.
const META_KEY: &str = "koopbridge_checkpoint";

/// Everything the training loop needs to continue after `iteration` iterations exactly as if it
/// had never stopped. Vectors are in f64 (an f32 run's values convert exactly both ways).
#[derive(Clone, Debug, PartialEq)]
pub struct Checkpoint {
    /// Iterations done when the snapshot was taken.
    pub iteration: usize,
    /// The run's configuration (a resume must use the same one, `threads` aside).
    pub config: TrainConfig,
    /// [`data_fingerprint`] of the run's data (a resume must see the same data).
    pub data_fingerprint: u64,
    /// Current parameters.
    pub params: Vec<f64>,
    /// Adam's first moments.
    pub adam_m: Vec<f64>,
    /// Adam's second moments.
    pub adam_v: Vec<f64>,
    /// Adam steps taken.
    pub adam_steps: u64,
    /// State of the batch sampler's generator (see `Rng::state`).
    pub rng: [u64; 4],
    /// Cached normal draw of the sampler's generator.
    pub rng_spare: Option<f64>,
    /// Best parameters so far (by validation error).
    pub best: Vec<f64>,
    /// Best validation error so far (`None` when no finite one yet).
    pub best_validation: Option<f64>,
    /// Iteration (1-based) of the best parameters (0 = none yet).
    pub best_iteration: usize,
    /// Seconds spent iterating so far (validation excluded).
    pub iter_seconds: f64,
    /// Loss terms of the last batch.
    pub last_loss: LossParts,
}

/// The scalar part of a checkpoint, stored as JSON in the safetensors metadata.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Header {
    format: u32,
    iteration: usize,
    config: TrainConfig,
    data_fingerprint: u64,
    adam_steps: u64,
    rng: [u64; 4],
    /// f64 values travel as bit patterns, so that they come back exactly.
    rng_spare: Option<u64>,
    best_validation: Option<u64>,
    best_iteration: usize,
    iter_seconds: u64,
    /// pred, ctrl, cov, total.
    last_loss: [u64; 4],
}

const TENSORS: [&str; 4] = ["params", "adam_m", "adam_v", "best"];

impl Checkpoint {
    /// The four parameter-sized vectors, in file order.
    fn vectors(&self) -> [&Vec<f64>; 4] {
        [&self.params, &self.adam_m, &self.adam_v, &self.best]
    }

    /// Writes the checkpoint to `path` atomically (temporary file + rename).
    pub fn save(&self, path: &Path) -> Result<()> {
        let header = Header {
            format: FORMAT,
            iteration: self.iteration,
            config: self.config.clone(),
            data_fingerprint: self.data_fingerprint,
            adam_steps: self.adam_steps,
            rng: self.rng,
            rng_spare: self.rng_spare.map(f64::to_bits),
            best_validation: self.best_validation.map(f64::to_bits),
            best_iteration: self.best_iteration,
            iter_seconds: self.iter_seconds.to_bits(),
            last_loss: [
                self.last_loss.pred,
                self.last_loss.ctrl,
                self.last_loss.cov,
                self.last_loss.total,
            ]
            .map(f64::to_bits),
        };
        let meta = serde_json::to_string(&header)
            .map_err(|e| Error::InvalidArgument(format!("checkpoint header: {e}")))?;
        let bytes: Vec<Vec<u8>> = self
            .vectors()
            .iter()
            .map(|v| v.iter().flat_map(|x| x.to_le_bytes()).collect())
            .collect();
        let mut views = Vec::new();
        for ((name, v), b) in TENSORS.iter().zip(self.vectors()).zip(&bytes) {
            let view = TensorView::new(Dtype::F64, vec![v.len()], b)
                .map_err(|e| Error::InvalidArgument(format!("checkpoint tensor {name}: {e}")))?;
            views.push((name.to_string(), view));
        }
        let data = safetensors::serialize(views, Some(HashMap::from([(META_KEY.into(), meta)])))
            .map_err(|e| Error::InvalidArgument(format!("checkpoint serialisation: {e}")))?;
        write_atomic(path, &data)
    }

    /// Reads a checkpoint written by [`Checkpoint::save`]; a damaged or foreign file is an
    /// [`Error::Format`].
    pub fn load(path: &Path) -> Result<Self> {
        let bytes = read_file(path)?;
        let st = SafeTensors::deserialize(&bytes)
            .map_err(|e| Error::format(path, format!("not a safetensors file: {e}")))?;
        let (_, meta) = SafeTensors::read_metadata(&bytes)
            .map_err(|e| Error::format(path, format!("not a safetensors file: {e}")))?;
        let json = meta
            .metadata()
            .as_ref()
            .and_then(|m| m.get(META_KEY))
            .ok_or_else(|| Error::format(path, "not a koopbridge training checkpoint"))?;
        let h: Header = serde_json::from_str(json)
            .map_err(|e| Error::format(path, format!("checkpoint header: {e}")))?;
        if h.format != FORMAT {
            return Err(Error::format(
                path,
                format!("checkpoint format {} (this build reads {FORMAT})", h.format),
            ));
        }
        let len = st
            .tensor("params")
            .map_err(|e| Error::format(path, format!("tensor 'params': {e}")))?
            .shape()
            .iter()
            .product::<usize>();
        let mut v = TENSORS
            .iter()
            .map(|n| read_tensor(&st, path, n, &[len]))
            .collect::<Result<Vec<_>>>()?;
        let best = v.pop().unwrap_or_default();
        let adam_v = v.pop().unwrap_or_default();
        let adam_m = v.pop().unwrap_or_default();
        let params = v.pop().unwrap_or_default();
        Ok(Checkpoint {
            iteration: h.iteration,
            config: h.config,
            data_fingerprint: h.data_fingerprint,
            params,
            adam_m,
            adam_v,
            adam_steps: h.adam_steps,
            rng: h.rng,
            rng_spare: h.rng_spare.map(f64::from_bits),
            best,
            best_validation: h.best_validation.map(f64::from_bits),
            best_iteration: h.best_iteration,
            iter_seconds: f64::from_bits(h.iter_seconds),
            last_loss: LossParts {
                pred: f64::from_bits(h.last_loss[0]),
                ctrl: f64::from_bits(h.last_loss[1]),
                cov: f64::from_bits(h.last_loss[2]),
                total: f64::from_bits(h.last_loss[3]),
            },
        })
    }

    /// Checks that this checkpoint can continue a run of `cfg` with `num_params` parameters on
    /// data with fingerprint `fingerprint`; the mismatch is named in the error.
    pub fn check_compatible(
        &self,
        cfg: &TrainConfig,
        num_params: usize,
        fingerprint: u64,
    ) -> Result<()> {
        let bad = |m: String| Err(Error::InvalidArgument(format!("cannot resume: {m}")));
        let mut mine = self.config.clone();
        mine.threads = cfg.threads;
        if &mine != cfg {
            return bad(format!(
                "the checkpoint was taken with another training configuration ({:?} vs {:?})",
                self.config, cfg
            ));
        }
        if self.data_fingerprint != fingerprint {
            return bad("the checkpoint was taken on other data".into());
        }
        if self.params.len() != num_params {
            return bad(format!(
                "the checkpoint has {} parameters, the model {num_params}",
                self.params.len()
            ));
        }
        if self.iteration > cfg.iterations || self.best_iteration > self.iteration {
            return bad(format!(
                "the checkpoint is at iteration {} (best {}), the run has {}",
                self.iteration, self.best_iteration, cfg.iterations
            ));
        }
        Ok(())
    }
}

/// A 64-bit FNV-1a hash of what a run trains and validates on: the dimensions, the first `m`
/// training windows and every validation window (bit patterns of the values).
pub fn data_fingerprint(train: &Dataset, m: usize, val: &Dataset) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |v: u64| {
        for b in v.to_le_bytes() {
            h ^= b as u64;
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    };
    for d in [train.nx, train.nu, train.steps, m, val.n] {
        eat(d as u64);
    }
    let m = m.min(train.n);
    let xs = &train.x[..(m * (train.steps + 1) * train.nx).min(train.x.len())];
    let us = &train.u[..(m * train.steps * train.nu).min(train.u.len())];
    for v in xs.iter().chain(us).chain(&val.x).chain(&val.u) {
        eat(v.to_bits());
    }
    h
}
