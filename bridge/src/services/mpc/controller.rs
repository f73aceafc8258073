//! The controllers the MPC service keeps per model: `koopman::mpc::served`'s controller (Koopman
//! MPC on a lifted model, sequential convex MPC on a bilinear one, random shooting on an NNDM
//! — the same code path as the exported FMU), with the wire's statuses and error codes.

use std::time::Duration;

pub use koopman::mpc::LoadedModel;
use koopman::mpc::{ModelController, ModelPlan, MpcConfig, OffsetFreeConfig, PlanStatus};

use crate::codec::SolveStatus;
use crate::error::{Error, ErrorCode, Result};

/// One model's controller ([`koopman::mpc::ModelController`]).
pub struct ServiceController(ModelController);

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

impl ServiceController {
    /// The controller of `model` with `cfg` ([`LoadedModel::controller`]).
    pub fn build(
        model: &LoadedModel,
        cfg: &MpcConfig,
        offset_free: Option<&OffsetFreeConfig>,
    ) -> Result<Self> {
        Ok(ServiceController(model.controller(cfg, offset_free)?))
    }

    /// State dimension.
    pub fn nx(&self) -> usize {
        self.0.nx()
    }

    /// Input dimension.
    pub fn nu(&self) -> usize {
        self.0.nu()
    }

    /// Horizon H.
    pub fn horizon(&self) -> usize {
        self.0.horizon()
    }

    /// Plans from `x` towards `reference` (nx values, or the stacked H·nx).
    ///
    /// Errors: wrong lengths, non-finite values, a failed QP without fallback.
    pub fn solve(&mut self, x: &[f64], reference: &[f64]) -> Result<ServicePlan> {
        self.solve_with_feedforward(x, reference, &[])
    }

    /// [`ServiceController::solve`], or with a non-empty `feedforward` (H·nu values) the
    /// error-state MPC about the plan whose state at this step is `reference` (nx values;
    /// [`koopman::mpc::ModelController::solve_about_plan`]: the Koopman MPC's, or random shooting
    /// about the plan on an NNDM).
    ///
    /// Errors: as `solve`; a feed-forward for a bilinear model is `unsupported`.
    pub fn solve_with_feedforward(
        &mut self,
        x: &[f64],
        reference: &[f64],
        feedforward: &[f64],
    ) -> Result<ServicePlan> {
        let plan = if feedforward.is_empty() {
            self.0.solve(x, reference)?
        } else if !self.0.takes_feedforward() {
            return Err(Error::protocol(
                ErrorCode::Unsupported,
                format!(
                    "a feed-forward (error-state MPC) needs a lifted-linear model or an NNDM; \
                     this one is {}",
                    self.0.kind()
                ),
            ));
        } else {
            self.0.solve_about_plan(x, reference, feedforward)?
        };
        Ok(wire_plan(plan))
    }
}

fn wire_plan(p: ModelPlan) -> ServicePlan {
    ServicePlan {
        status: match p.status {
            PlanStatus::Solved => SolveStatus::Solved,
            PlanStatus::Inaccurate => SolveStatus::Inaccurate,
            PlanStatus::Suboptimal => SolveStatus::Suboptimal,
            PlanStatus::Fallback => SolveStatus::Fallback,
        },
        iterations: p.iterations,
        solve_time: p.solve_time,
        u: p.u,
    }
}
