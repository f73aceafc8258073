//! The controllers the MPC service keeps per model: Koopman MPC on a lifted model (`koopman`,
//! `edmd`), the sequential convex MPC on a bilinear model, whose optional offset-free
//! correction follows the solves of one episode, or random-shooting MPC on a one-step model
//! (`nndm`, the paper's NNDM baseline).

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use koopman::model::bilinear::BilinearModel;
use std::time::Instant;

use koopman::mpc::controllers::{SHOOTING_SAMPLES, SHOOTING_SEED};
use koopman::mpc::{
    BilinearMpc, MpcConfig, MpcController, OffsetFreeConfig, OneStepModel, RandomShooting,
    ScpOptions, ScpStatus,
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
    /// Random-shooting MPC on a one-step model (SHOOTING_SAMPLES sequences per solve, seeded
    /// once when the controller is built, so a configured episode is reproducible).
    Shooting(Box<Shooting>),
}

/// A random-shooting planner and the one-step model it plans on.
pub struct Shooting {
    planner: RandomShooting,
    model: Arc<dyn OneStepModel>,
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
    /// A one-step model `x⁺ = f(x, u)` (an NNDM).
    OneStep(Arc<dyn OneStepModel>),
}

impl LoadedModel {
    /// Loads the model saved in `dir`, dispatching on its kind (`koopman`, `edmd`, `bilinear`,
    /// `nndm`).
    pub fn load(dir: &Path) -> Result<Self> {
        match koopman::model::store::read_kind(dir)?.as_str() {
            "bilinear" => Ok(LoadedModel::Bilinear(Arc::new(BilinearModel::load(dir)?))),
            "nndm" => Ok(LoadedModel::OneStep(Arc::from(
                koopman::model::load_one_step(dir)?,
            ))),
            _ => Ok(LoadedModel::Lifted(Arc::from(koopman::model::load_lifted(
                dir,
            )?))),
        }
    }

    /// The controller of this model with `cfg`; `offset_free` only for a bilinear model (a
    /// lifted model with one is refused: its controller has no such correction). A one-step
    /// model gets random-shooting MPC, which needs finite input bounds and honours the
    /// horizon and the state weight `q` only (other settings it cannot honour are refused).
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
            LoadedModel::OneStep(m) => {
                if offset_free.is_some() {
                    return Err(Error::Config(
                        "offset_free needs a bilinear model (this one is a one-step NNDM)".into(),
                    ));
                }
                Ok(ServiceController::Shooting(Box::new(Shooting {
                    planner: shooting_planner(m.as_ref(), cfg)?,
                    model: m.clone(),
                })))
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
            ServiceController::Shooting(s) => s.model.nx(),
        }
    }

    /// Input dimension.
    pub fn nu(&self) -> usize {
        match self {
            ServiceController::Lifted(c) => c.nu(),
            ServiceController::Bilinear(c) => c.nu(),
            ServiceController::Shooting(s) => s.model.nu(),
        }
    }

    /// Horizon H.
    pub fn horizon(&self) -> usize {
        match self {
            ServiceController::Lifted(c) => c.horizon(),
            ServiceController::Bilinear(c) => c.horizon(),
            ServiceController::Shooting(s) => s.planner.horizon,
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
            ServiceController::Shooting(_) if !feedforward.is_empty() => Err(Error::protocol(
                ErrorCode::Unsupported,
                "a feed-forward (error-state MPC) needs a lifted-linear model; this one is a one-step NNDM",
            )),
            ServiceController::Shooting(s) => {
                let (nx, h) = (s.model.nx(), s.planner.horizon);
                // One state is held over the horizon; the stacked x_1..x_H is used as it is.
                let stacked = if reference.len() == nx {
                    reference.repeat(h)
                } else if reference.len() == h * nx {
                    reference.to_vec()
                } else {
                    return Err(Error::from(koopman::Error::dimension(
                        "reference (nx or horizon·nx)",
                        h * nx,
                        reference.len(),
                    )));
                };
                koopman::error::ensure_finite("reference", &stacked).map_err(Error::from)?;
                let t = Instant::now();
                let (u, _) = s.planner.plan_sequence(s.model.as_ref(), x, &stacked)?;
                Ok(ServicePlan {
                    status: SolveStatus::Solved,
                    iterations: s.planner.samples,
                    solve_time: t.elapsed(),
                    u,
                })
            }
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

/// The random-shooting planner for `model` with `cfg` (horizon, `q`, the input bounds); the
/// settings it cannot honour (input weight, terminal weight, rate and state bounds) are refused
/// rather than ignored.
fn shooting_planner(model: &dyn OneStepModel, cfg: &MpcConfig) -> Result<RandomShooting> {
    let (nx, nu) = (model.nx(), model.nu());
    let refuse = |what: &str| {
        Err(Error::Config(format!(
            "random-shooting MPC on a one-step NNDM: {what}"
        )))
    };
    if cfg.r.as_ref().is_some_and(|r| r.iter().any(|&v| v != 0.0)) {
        return refuse("no input weight r (the paper's cost is on the states only)");
    }
    if cfg.terminal.is_some() || cfg.has_general_constraints() {
        return refuse("no terminal weight, rate or state bounds (input bounds only)");
    }
    let q = cfg.q.clone().unwrap_or_else(|| vec![1.0; nx]);
    if q.len() != nx {
        return Err(Error::from(koopman::Error::dimension("q", nx, q.len())));
    }
    let (Some(lo), Some(hi)) = (&cfg.u_min, &cfg.u_max) else {
        return refuse("it samples inputs within the bounds: set u_min and u_max");
    };
    if lo.len() != nu || hi.len() != nu {
        return Err(Error::from(koopman::Error::dimension(
            "input bounds",
            nu,
            lo.len().min(hi.len()),
        )));
    }
    Ok(RandomShooting::new(
        SHOOTING_SAMPLES,
        cfg.horizon,
        q,
        lo.clone(),
        hi.clone(),
        SHOOTING_SEED,
    )?)
}
