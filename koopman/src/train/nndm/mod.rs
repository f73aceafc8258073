//! Training of the NNDM baseline on the same multi-step discounted prediction loss as the
//! Koopman model, with the same optimiser, schedule, clipping, validation and metrics.

pub mod eval;
pub mod loss;
mod run;

pub use eval::{prediction_error, NndmEval};
pub use loss::NndmLossWs;
pub use run::train_nndm;

use super::TrainMetrics;
use crate::model::nndm::NndmModel;
use serde::{Deserialize, Serialize};

/// The figures of a finished NNDM run: the Koopman run's [`TrainMetrics`] (its `num_params` is
/// the NNDM's; `config.ctrl`/`config.cov` are false, the NNDM has no such terms) plus the
/// parameter budget it was matched to.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct NndmMetrics {
    /// The figures every training run reports.
    #[serde(flatten)]
    pub base: TrainMetrics,
    /// Hidden widths of the MLP.
    pub hidden: Vec<usize>,
    /// Parameter count of the Koopman model of the same configuration (n_mult, hidden).
    pub koopman_num_params: usize,
}

/// A trained NNDM and its metrics.
pub struct NndmOutcome {
    /// The best checkpoint (by validation prediction error), in f64.
    pub model: NndmModel,
    /// Figures of the run.
    pub metrics: NndmMetrics,
}
