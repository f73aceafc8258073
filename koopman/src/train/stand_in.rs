//! Stand-in lifted models for when no trained one is at hand: a random stable model of given
//! dimensions (to check settings), a least-squares fit on random features, or a briefly trained
//! neural Koopman model.

use std::ops::ControlFlow;

use super::{Progress, TrainConfig, TrainOutcome};
use crate::data::{generate, Pairing};
use crate::error::{Error, Result};
use crate::model::matrix::{fit_random_features, MatrixModel};
use crate::model::LiftedModel;
use crate::systems::System;

/// Seed of the data a stand-in is fitted or trained on.
pub const DATA_SEED: u64 = 42;
/// Aligned windows a [`StandIn::Fit`] is fitted on.
pub const FIT_WINDOWS: usize = 2000;
/// Aligned training windows of a [`StandIn::Train`].
pub const TRAIN_WINDOWS: usize = 16_000;
/// Aligned validation windows of a [`StandIn::Train`] (generated after the training ones).
pub const VALIDATION_WINDOWS: usize = 2000;

/// Which stand-in to make.
pub enum StandIn<'s> {
    /// A random stable model with `nx` states, `nu` inputs and no lifting (N = nx, spectral
    /// radius ≤ 0.9, seed 0): for checking settings that depend only on the dimensions, such as
    /// an MPC configuration; it knows nothing of any system.
    Dimensions {
        /// States.
        nx: usize,
        /// Inputs.
        nu: usize,
    },
    /// [`fit_random_features`] with `features` random tanh features (ridge 1e-8, seed 1) on
    /// [`FIT_WINDOWS`] aligned windows of `system`.
    Fit {
        /// The system whose data it is fitted on.
        system: &'s dyn System,
        /// Random tanh features of the lifting.
        features: usize,
    },
    /// A neural Koopman model trained with the SPEC settings except `iterations` (validated five
    /// times) on [`TRAIN_WINDOWS`] aligned windows of `system`, validated on
    /// [`VALIDATION_WINDOWS`] more.
    Train {
        /// The system whose data it is trained on.
        system: &'s dyn System,
        /// Training iterations.
        iterations: usize,
        /// Sees every iteration; `Break` stops the training (an error: [`Error::Cancelled`]).
        observer: &'s mut dyn FnMut(&Progress) -> ControlFlow<()>,
    },
}

/// A stand-in model as made: explicit matrices, or a trained model with its training figures.
pub enum StandInModel {
    /// From [`StandIn::Dimensions`] or [`StandIn::Fit`].
    Matrix(MatrixModel),
    /// From [`StandIn::Train`] (the caller may save `model`).
    Trained(Box<TrainOutcome>),
}

impl StandInModel {
    /// The model as a lifted model, whatever made it.
    pub fn into_lifted(self) -> Box<dyn LiftedModel> {
        match self {
            StandInModel::Matrix(m) => Box::new(m),
            StandInModel::Trained(outcome) => Box::new(outcome.model),
        }
    }
}

/// Makes the stand-in `spec` describes, deterministically (the same spec gives the same model).
///
/// Errors: dimensions of zero, a system without inputs, or a failed fit or training.
pub fn build(spec: StandIn<'_>) -> Result<StandInModel> {
    match spec {
        StandIn::Dimensions { nx, nu } => {
            if nx == 0 || nu == 0 {
                return Err(Error::InvalidArgument(format!(
                    "a stand-in model needs states and inputs (nx = {nx}, nu = {nu})"
                )));
            }
            Ok(StandInModel::Matrix(MatrixModel::random_stable(
                nx, nx, nu, 0.9, 0,
            )?))
        }
        StandIn::Fit { system, features } => {
            let data = generate(
                system,
                FIT_WINDOWS,
                system.window_steps(),
                DATA_SEED,
                Pairing::Aligned,
            )?;
            Ok(StandInModel::Matrix(fit_random_features(
                &data, features, 1e-8, 1,
            )?))
        }
        StandIn::Train {
            system,
            iterations,
            observer,
        } => {
            let data = generate(
                system,
                TRAIN_WINDOWS + VALIDATION_WINDOWS,
                system.window_steps(),
                DATA_SEED,
                Pairing::Aligned,
            )?;
            let train = data.head(TRAIN_WINDOWS)?;
            let val = data
                .select(&(TRAIN_WINDOWS..TRAIN_WINDOWS + VALIDATION_WINDOWS).collect::<Vec<_>>())?;
            let cfg = TrainConfig {
                iterations,
                validate_every: (iterations / 5).max(1),
                ..TrainConfig::default()
            };
            let outcome = super::train(&cfg, &train, &val, None, observer)?;
            Ok(StandInModel::Trained(Box::new(outcome)))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::systems::by_name;

    #[test]
    fn a_dimensions_stand_in_is_stable_with_the_asked_dimensions() {
        let m = build(StandIn::Dimensions { nx: 3, nu: 2 })
            .unwrap()
            .into_lifted();
        assert_eq!((m.nx(), m.nu(), m.latent_dim()), (3, 2, 3));
        // ‖A‖₂ ≤ 0.9 by construction: the free response of any state shrinks.
        let a = m.a();
        let x = [1.0, -2.0, 0.5];
        let ax: Vec<f64> = (0..3)
            .map(|i| (0..3).map(|j| a[(i, j)] * x[j]).sum())
            .collect();
        let norm = |v: &[f64]| v.iter().map(|c| c * c).sum::<f64>().sqrt();
        assert!(norm(&ax) <= 0.9 * norm(&x) + 1e-12);
        assert!(build(StandIn::Dimensions { nx: 2, nu: 0 }).is_err());
    }

    #[test]
    fn a_fit_stand_in_predicts_its_system_one_step_ahead() {
        let system = by_name("damped-pendulum").unwrap();
        let made = build(StandIn::Fit {
            system: system.as_ref(),
            features: 40,
        })
        .unwrap();
        let m = made.into_lifted();
        assert_eq!((m.nx(), m.nu(), m.latent_dim()), (2, 1, 42));
        // One step of the true system against A z + B u, read back through x = P z.
        let (x, u) = ([0.4, -0.3], [0.5]);
        let mut next = [0.0; 2];
        system.step(&x, &u, &mut next);
        let (a, b, z) = (m.a(), m.b(), m.lift(&x));
        for i in 0..2 {
            let pred: f64 = (0..z.len()).map(|j| a[(i, j)] * z[j]).sum::<f64>() + b[(i, 0)] * u[0];
            assert!((pred - next[i]).abs() < 1e-2, "x{i}: {pred} vs {}", next[i]);
        }
    }

    #[test]
    fn a_train_stand_in_runs_the_asked_iterations_and_can_be_stopped() {
        let system = by_name("damped-pendulum").unwrap();
        let mut seen = 0;
        let mut count = |_: &Progress| {
            seen += 1;
            ControlFlow::Continue(())
        };
        let made = build(StandIn::Train {
            system: system.as_ref(),
            iterations: 3,
            observer: &mut count,
        })
        .unwrap();
        assert_eq!(seen, 3);
        assert!(matches!(made, StandInModel::Trained(_)));
        let mut stop = |_: &Progress| ControlFlow::Break(());
        let stopped = build(StandIn::Train {
            system: system.as_ref(),
            iterations: 3,
            observer: &mut stop,
        });
        assert!(
            matches!(stopped, Err(Error::Cancelled)),
            "{:?}",
            stopped.err()
        );
    }
}
