//! The bookkeeping both training loops (Koopman and NNDM) share after each optimiser step:
//! validation when due, the best checkpoint by validation error, time spent iterating, and the
//! progress report to the observer.

use std::ops::ControlFlow;

use super::loss::LossParts;
use super::{Progress, TrainConfig};
use crate::{Error, Result};

/// What one optimiser step reports.
#[derive(Clone, Copy, Debug)]
pub(crate) struct StepInfo {
    /// Iterations done, this one included (1-based).
    pub done: usize,
    /// The batch's loss terms.
    pub loss: LossParts,
    /// The learning rate used.
    pub lr: f64,
}

/// Best-checkpoint and timing state of one run.
pub(crate) struct RunTracker<T> {
    /// Parameters of the best validation so far.
    pub best: Vec<T>,
    /// Lowest validation prediction error so far (∞ before the first validation).
    pub best_val: f64,
    /// Iteration (1-based) of `best`; 0 before the first validation.
    pub best_it: usize,
    /// Seconds spent in the iterations proper (validation excluded).
    pub iter_secs: f64,
}

impl<T: Copy> RunTracker<T> {
    /// A fresh run from `params`.
    pub fn new(params: &[T]) -> Self {
        RunTracker {
            best: params.to_vec(),
            best_val: f64::INFINITY,
            best_it: 0,
            iter_secs: 0.0,
        }
    }

    /// Called after iteration `step.done` has updated `params`: validates with `validate`
    /// when due (every `validate_every` iterations and the last one; a failed validation counts
    /// as ∞), keeps the best parameters, and reports to `observer`. Returns the validation error
    /// when one was computed; `Error::Cancelled` when the observer breaks.
    pub fn after_step(
        &mut self,
        cfg: &TrainConfig,
        step: StepInfo,
        params: &[T],
        validate: impl FnOnce(&[T]) -> Result<f64>,
        observer: &mut dyn FnMut(&Progress) -> ControlFlow<()>,
    ) -> Result<Option<f64>> {
        let StepInfo { done, loss, lr } = step;
        let validation = if done % cfg.validate_every == 0 || done == cfg.iterations {
            let v = validate(params).unwrap_or(f64::INFINITY);
            if v < self.best_val || self.best_it == 0 {
                self.best_val = v;
                self.best_it = done;
                self.best.copy_from_slice(params);
            }
            Some(v)
        } else {
            None
        };
        let progress = Progress {
            iteration: done,
            total: cfg.iterations,
            loss,
            lr,
            validation,
            best_validation: self.best_validation(),
            iterations_per_second: done as f64 / self.iter_secs.max(1e-12),
        };
        if observer(&progress).is_break() {
            return Err(Error::Cancelled);
        }
        Ok(validation)
    }

    /// The best validation error, if any was finite.
    pub fn best_validation(&self) -> Option<f64> {
        self.best_val.is_finite().then_some(self.best_val)
    }

    /// Ends the run: an error when no validation was finite.
    pub fn finish(self) -> Result<Self> {
        if self.best_val.is_finite() {
            Ok(self)
        } else {
            Err(Error::Numerical(
                "the validation prediction error is not finite at any checkpoint".into(),
            ))
        }
    }
}
