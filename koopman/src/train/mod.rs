//! Training of neural Koopman models exactly as SPEC.md: losses with hand-written gradients,
//! Adam with step decay and gradient clipping, validation and best-checkpoint selection.

pub mod adam;
pub mod bilinear;
pub mod checkpoint;
pub mod eval;
pub mod loss;
pub mod nndm;
mod parts;
pub mod pinv;
mod regular;
mod run;
pub mod stand_in;
mod tracker;

pub use checkpoint::Checkpoint;
pub use run::{run_fingerprint, train, train_bilinear, train_bilinear_resumable, train_resumable};

use crate::data::Dataset;
use crate::model::koopman::KoopmanModel;
use crate::Result;
use serde::{Deserialize, Serialize};

/// Floating-point precision of the training arithmetic.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// Single precision (default; what the reference trains in).
    #[default]
    F32,
    /// Double precision.
    F64,
}

/// Every setting of a training run; `Default` is SPEC.md's recipe.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct TrainConfig {
    /// Encoder output width as a multiple of nx (n_enc = n_mult·nx).
    pub n_mult: usize,
    /// Hidden widths of the encoder.
    pub hidden: Vec<usize>,
    /// Optimiser iterations.
    pub iterations: usize,
    /// Windows per batch.
    pub batch: usize,
    /// Initial learning rate.
    pub lr: f64,
    /// Learning-rate factor applied every `lr_step` iterations.
    pub lr_decay: f64,
    /// Iterations between learning-rate decays.
    pub lr_step: usize,
    /// Global gradient-norm clipping threshold.
    pub clip: f64,
    /// Discount γ of the multi-step losses.
    pub gamma: f64,
    /// Inverse-control loss on.
    pub ctrl: bool,
    /// Covariance loss on.
    pub cov: bool,
    /// Training seed (initialisation and batch sampling).
    pub seed: u64,
    /// Iterations between validations (the last iteration is always validated).
    pub validate_every: usize,
    /// Train on the first m windows of the training pool (all when `None`).
    pub train_samples: Option<usize>,
    /// Arithmetic precision.
    pub precision: Precision,
    /// Threads for the large products (0 = rayon's pool size).
    pub threads: usize,
    /// Bilinear latent dynamics `z⁺ = A z + B u + Σ_i u_i N_i z` (N_i start at zero) instead of
    /// SPEC's linear ones; train with [`train_bilinear`].
    pub bilinear: bool,
    /// Train on z-scored states and inputs (SPEC.md for legged robots): the statistics are
    /// fitted on the whole training pool, the model keeps them
    /// ([`KoopmanModel::normalisation`]) and the reported prediction errors are in normalised
    /// units. Linear Koopman models only.
    pub normalise: bool,
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig {
            n_mult: 16,
            hidden: vec![256, 256, 256],
            iterations: 60_000,
            batch: 64,
            lr: 1e-3,
            lr_decay: 0.9,
            lr_step: 1000,
            clip: 0.1,
            gamma: 0.8,
            ctrl: true,
            cov: true,
            seed: 17382,
            validate_every: 1000,
            train_samples: None,
            precision: Precision::F32,
            threads: 0,
            bilinear: false,
            normalise: false,
        }
    }
}

impl TrainConfig {
    /// Settles the inverse-control loss for data with `nu` inputs. An autonomous system
    /// (`nu = 0`) has no `B` to invert, so the loss has nothing to train: the default turns off
    /// (returns `true` when it did, so callers can say so), and an explicit request
    /// (`explicitly_requested`) is refused with the reason rather than silently dropped.
    pub fn settle_ctrl_for(&mut self, nu: usize, explicitly_requested: bool) -> Result<bool> {
        if nu > 0 || !self.ctrl {
            return Ok(false);
        }
        if explicitly_requested {
            return Err(crate::Error::InvalidArgument(AUTONOMOUS_CTRL.into()));
        }
        self.ctrl = false;
        Ok(true)
    }
}

/// Why the inverse-control loss cannot be trained on data without inputs.
pub const AUTONOMOUS_CTRL: &str = "the inverse-control loss (ctrl) needs inputs, and this data \
     has none (nu = 0, an autonomous system): it reconstructs u from the latent step through \
     pinv(B), and there is no B; leave ctrl off (cov and the prediction loss still apply)";

/// What the trainer reports to its observer after every iteration.
#[derive(Clone, Debug, Serialize)]
pub struct Progress {
    /// Iterations done (1-based).
    pub iteration: usize,
    /// Iterations in total.
    pub total: usize,
    /// Loss terms of this iteration's batch.
    pub loss: loss::LossParts,
    /// Learning rate used in this iteration.
    pub lr: f64,
    /// Validation prediction error, when it was just computed.
    pub validation: Option<f64>,
    /// Best validation prediction error so far.
    pub best_validation: Option<f64>,
    /// Average iterations per second so far (excluding validation time).
    pub iterations_per_second: f64,
}

/// The figures of a finished run (saved as `metrics.json`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TrainMetrics {
    /// Test prediction error of the best checkpoint (None without a test set).
    pub test_prediction_error: Option<f64>,
    /// Lowest validation prediction error.
    pub best_validation_prediction_error: f64,
    /// Iteration (1-based) of the best checkpoint.
    pub best_iteration: usize,
    /// Iterations run.
    pub iterations: usize,
    /// Training iterations per second (wall time of the iterations, validation excluded).
    pub iterations_per_second: f64,
    /// Wall time of the whole run in seconds (validation and test included).
    pub wall_seconds: f64,
    /// Windows of the training pool used (m).
    pub train_samples: usize,
    /// Number of trainable parameters.
    pub num_params: usize,
    /// Loss terms of the last batch.
    pub final_loss: loss::LossParts,
    /// Input/transition pairing of the training data.
    pub pairing: crate::data::Pairing,
    /// Environment of the training data.
    pub env: String,
    /// The configuration of the run.
    pub config: TrainConfig,
}

/// A trained model and its metrics.
pub struct TrainOutcome {
    /// The best checkpoint (by validation prediction error), in f64.
    pub model: KoopmanModel,
    /// Figures of the run.
    pub metrics: TrainMetrics,
}

/// A trained bilinear model and its metrics.
pub struct BilinearOutcome {
    /// The best checkpoint (by validation prediction error), in f64.
    pub model: crate::model::bilinear::BilinearModel,
    /// Figures of the run.
    pub metrics: TrainMetrics,
}

/// SPEC's prediction error of a bilinear model (the rollout with `Σ u_i N_i ẑ`), as
/// [`prediction_error`].
pub fn bilinear_prediction_error(
    model: &crate::model::bilinear::BilinearModel,
    data: &Dataset,
    gamma: f64,
) -> Result<f64> {
    let mut ev =
        eval::PredEval::<f64>::with_dynamics(model.arch(), 4096, faer::Par::rayon(0), true);
    ev.pred_loss(&model.params(), data, gamma)
}

/// SPEC's prediction error of `model` on `data` (f64): `L_pred` with discount `gamma` over all
/// windows, each encoded once at its first state.
pub fn prediction_error(model: &KoopmanModel, data: &Dataset, gamma: f64) -> Result<f64> {
    let mut ev = eval::PredEval::<f64>::new(model.arch(), 4096, faer::Par::rayon(0));
    ev.pred_loss(model.params(), data, gamma)
}

/// Checks the settings every trainer (Koopman and NNDM) shares: iterations, batch, learning rate
/// and its schedule, γ, clipping and the validation period.
pub(crate) fn check_optimiser_settings(cfg: &TrainConfig) -> Result<()> {
    let bad = |m: &str| Err(crate::Error::InvalidArgument(m.to_string()));
    if cfg.iterations == 0 {
        return bad("iterations must be ≥ 1");
    }
    if cfg.batch == 0 {
        return bad("batch must be ≥ 1");
    }
    if !(cfg.lr > 0.0 && cfg.lr.is_finite()) {
        return bad("lr must be a positive number");
    }
    if !(cfg.gamma > 0.0 && cfg.gamma.is_finite()) {
        return bad("gamma must be a positive number");
    }
    if cfg.clip.is_nan()
        || cfg.clip <= 0.0
        || cfg.lr_decay.is_nan()
        || cfg.lr_decay <= 0.0
        || cfg.lr_step == 0
        || cfg.validate_every == 0
    {
        return bad("clip and lr_decay must be > 0, lr_step and validate_every ≥ 1");
    }
    Ok(())
}
