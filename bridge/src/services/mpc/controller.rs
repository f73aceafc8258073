//! The controllers the MPC service keeps per model: Koopman MPC on a lifted model (`koopman`,
//! `edmd`), or the sequential convex MPC on a bilinear model, whose optional offset-free
//! correction follows the solves of one episode.

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use koopman::model::bilinear::BilinearModel;
use koopman::mpc::{
    BilinearMpc, MpcConfig, MpcController, OffsetFreeConfig, ScpOptions, ScpStatus,
};

use crate::codec::SolveStatus;
use crate::error::{Error, ErrorCode, Result};

/// One model's controller.
pub enum ServiceController {
    /// Koopman MPC on a lifted model (stateless between solves but for its warm start).
    Lifted(Box<MpcController<'static>>),
    /// Sequential convex MPC on a bilinear model. With an offset-free correction, consecutive
    /// solves are one closed loop: each measured state updates the correction before the plan,
    /// and the plan's first input is recorded as applied.
    Bilinear(Box<BilinearMpc<'static>>),
}

/// What one solve returns to the wire.
#[derive(Clone, Debug, PartialEq)]
pub struct ServicePlan {
    /// The input plan, H·nu values.
    pub u: Vec<f64>,
    /// Wire status: a converged linearisation is `solved`, a capped one `suboptimal`.
    pub status: SolveStatus,
    /// QP iterations (summed over linearisations for the bilinear MPC).
    pub iterations: usize,
    /// Solve wall time.
    pub solve_time: Duration,
}

/// A loaded model, before its bounds are known.
#[derive(Clone)]
pub enum LoadedModel {
    /// A lifted model.
    Lifted(Arc<dyn koopman::model::LiftedModel>),
    /// A bilinear model.
    Bilinear(Arc<BilinearModel>),
}

impl LoadedModel {
    /// Loads the model saved in `dir`, dispatching on its kind (`koopman`, `edmd`, `bilinear`).
    pub fn load(dir: &Path) -> Result<Self> {
        match koopman::model::store::read_kind(dir)?.as_str() {
            "bilinear" => Ok(LoadedModel::Bilinear(Arc::new(BilinearModel::load(dir)?))),
            _ => Ok(LoadedModel::Lifted(Arc::from(koopman::model::load_lifted(
                dir,
            )?))),
        }
    }

    /// The controller of this model with `cfg`; `offset_free` only for a bilinear model (a
    /// lifted model with one is refused: its controller has no such correction).
    pub fn controller(
        &self,
        cfg: &MpcConfig,
        offset_free: Option<&OffsetFreeConfig>,
    ) -> Result<ServiceController> {
        match self {
            LoadedModel::Lifted(m) => {
                if offset_free.is_some() {
                    return Err(Error::Config(
                        "offset_free needs a bilinear model (this one is lifted-linear)".into(),
                    ));
                }
                Ok(ServiceController::Lifted(Box::new(
                    MpcController::from_shared(m.clone(), cfg)?,
                )))
            }
            LoadedModel::Bilinear(m) => {
                let mut c = BilinearMpc::from_shared(m.clone(), cfg, ScpOptions::default())?;
                c.set_offset_free(offset_free.cloned())?;
                Ok(ServiceController::Bilinear(Box::new(c)))
            }
        }
    }
}

impl ServiceController {
    /// State dimension.
    pub fn nx(&self) -> usize {
        match self {
            ServiceController::Lifted(c) => c.nx(),
            ServiceController::Bilinear(c) => c.nx(),
        }
    }

    /// Input dimension.
    pub fn nu(&self) -> usize {
        match self {
            ServiceController::Lifted(c) => c.nu(),
            ServiceController::Bilinear(c) => c.nu(),
        }
    }

    /// Horizon H.
    pub fn horizon(&self) -> usize {
        match self {
            ServiceController::Lifted(c) => c.horizon(),
            ServiceController::Bilinear(c) => c.horizon(),
        }
    }

    /// Plans from `x` towards `reference` (nx values, or the stacked H·nx).
    ///
    /// Errors: wrong lengths, non-finite values, a failed QP without fallback.
    pub fn solve(&mut self, x: &[f64], reference: &[f64]) -> Result<ServicePlan> {
        self.solve_with_feedforward(x, reference, &[])
    }

    /// [`ServiceController::solve`], or with a non-empty `feedforward` (H·nu values) the
    /// error-state MPC about the plan whose state at this step is `reference` (nx values;
    /// [`MpcController::solve_about_plan`]).
    ///
    /// Errors: as `solve`; a feed-forward for a bilinear model is `unsupported`.
    pub fn solve_with_feedforward(
        &mut self,
        x: &[f64],
        reference: &[f64],
        feedforward: &[f64],
    ) -> Result<ServicePlan> {
        match self {
            ServiceController::Lifted(c) => {
                let s = if feedforward.is_empty() {
                    c.solve(x, reference)?
                } else {
                    c.solve_about_plan(x, reference, feedforward)?
                };
                Ok(ServicePlan {
                    status: super::wire_status(&s.status),
                    iterations: s.iterations,
                    solve_time: s.solve_time,
                    u: s.u,
                })
            }
            ServiceController::Bilinear(_) if !feedforward.is_empty() => Err(Error::protocol(
                ErrorCode::Unsupported,
                "a feed-forward (error-state MPC) needs a lifted-linear model; this one is bilinear",
            )),
            ServiceController::Bilinear(c) => {
                let nx = c.nx();
                if reference.len() < nx {
                    return Err(Error::from(koopman::Error::dimension(
                        "reference",
                        nx,
                        reference.len(),
                    )));
                }
                c.observe(x, &reference[..nx])?;
                let s = c.solve(x, reference)?;
                c.record(x, &s.u[..c.nu()]);
                Ok(ServicePlan {
                    status: match s.status {
                        ScpStatus::Converged => SolveStatus::Solved,
                        ScpStatus::NotConverged => SolveStatus::Suboptimal,
                        ScpStatus::Fallback(_) => SolveStatus::Fallback,
                    },
                    iterations: s.qp_iterations,
                    solve_time: s.solve_time,
                    u: s.u,
                })
            }
        }
    }
}
