//! A saved model directory + [`MpcConfig`] → the controller that turns a measured state and a
//! reference into an input plan: the one code path shared by the MPC service (`bridge`) and
//! the exported FMU (`koopbridge-fmu`).
//!
//! [`LoadedModel::load`] dispatches on the model's kind (`koopman`/`edmd`: Koopman MPC,
//! `bilinear`: sequential convex MPC with an optional offset-free correction, `nndm`:
//! random-shooting MPC); [`ModelController::solve`] plans. Consecutive solves of one
//! controller are one closed loop (warm starts, the bilinear offset-free estimate).

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use super::bilinear::{BilinearMpc, ScpOptions, ScpStatus};
use super::config::{ControlLaw, MpcConfig};
use super::controller::{MpcController, SolveStatus};
use super::controllers::{SHOOTING_SAMPLES, SHOOTING_SEED};
use super::lqr_law::LqrLaw;
pub use super::model_plan::{ModelPlan, PlanStatus};
use super::offset_free::OffsetFreeConfig;
use super::shooting::{OneStepModel, RandomShooting};
use crate::error::{ensure_finite, Error, Result};
use crate::model::bilinear::BilinearModel;
use crate::model::LiftedModel;

/// Why an MPC cannot be built for a model of a system without inputs.
pub const AUTONOMOUS_MPC: &str = "the model is of an autonomous system (nu = 0): an MPC needs at \
     least one input to plan; such a model predicts (koopbridge sim, eval, scenarios without \
     [control]) but cannot control";

/// A loaded model, before its controller's settings are known.
#[derive(Clone)]
pub enum LoadedModel {
    /// A lifted model (`koopman`, `edmd`).
    Lifted(Arc<dyn LiftedModel>),
    /// A bilinear model.
    Bilinear(Arc<BilinearModel>),
    /// A one-step model `x⁺ = f(x, u)` (an NNDM).
    OneStep(Arc<dyn OneStepModel>),
}

impl LoadedModel {
    /// Loads the model saved in `dir`, dispatching on its kind (`koopman`, `edmd`, `bilinear`,
    /// `nndm`).
    pub fn load(dir: &Path) -> Result<Self> {
        match crate::model::store::read_kind(dir)?.as_str() {
            "bilinear" => Ok(LoadedModel::Bilinear(Arc::new(BilinearModel::load(dir)?))),
            "nndm" => Ok(LoadedModel::OneStep(Arc::from(
                crate::model::load_one_step(dir)?,
            ))),
            _ => Ok(LoadedModel::Lifted(Arc::from(crate::model::load_lifted(
                dir,
            )?))),
        }
    }

    /// The model's kind in words (`lifted-linear`, `bilinear`, `a one-step NNDM`).
    pub fn kind(&self) -> &'static str {
        match self {
            LoadedModel::Lifted(_) => "lifted-linear",
            LoadedModel::Bilinear(_) => "bilinear",
            LoadedModel::OneStep(_) => "a one-step NNDM",
        }
    }

    /// State dimension nx.
    pub fn nx(&self) -> usize {
        match self {
            LoadedModel::Lifted(m) => m.nx(),
            LoadedModel::Bilinear(m) => m.nx(),
            LoadedModel::OneStep(m) => m.nx(),
        }
    }

    /// Input dimension nu.
    pub fn nu(&self) -> usize {
        match self {
            LoadedModel::Lifted(m) => m.nu(),
            LoadedModel::Bilinear(m) => m.nu(),
            LoadedModel::OneStep(m) => m.nu(),
        }
    }

    /// The controller of this model with `cfg`; `offset_free` for a lifted-linear or a bilinear
    /// model (a one-step NNDM with one is refused: its planner has no such correction). A
    /// one-step model gets random-shooting MPC, which needs finite input bounds and honours the
    /// horizon and the weights `q` and `r` only (other settings it cannot honour are refused).
    pub fn controller(
        &self,
        cfg: &MpcConfig,
        offset_free: Option<&OffsetFreeConfig>,
    ) -> Result<ModelController> {
        if self.nu() == 0 {
            return Err(Error::InvalidArgument(format!(
                "no inputs to control: {AUTONOMOUS_MPC}"
            )));
        }
        if cfg.law == ControlLaw::Lqr {
            return match self {
                LoadedModel::Lifted(m) if offset_free.is_none() => {
                    Ok(ModelController::Lqr(Box::new(LqrLaw::new(m.clone(), cfg)?)))
                }
                LoadedModel::Lifted(_) => Err(Error::InvalidArgument(
                    "offset_free corrects the MPC; the LQR law has none".into(),
                )),
                other => Err(Error::InvalidArgument(format!(
                    "the LQR law needs a lifted-linear model; this one is {}",
                    other.kind()
                ))),
            };
        }
        match self {
            LoadedModel::Lifted(m) => {
                let mut c = MpcController::from_shared(m.clone(), cfg)?;
                c.set_offset_free(offset_free.cloned())?;
                Ok(ModelController::Lifted(Box::new(c)))
            }
            LoadedModel::Bilinear(m) => {
                let mut c = BilinearMpc::from_shared(m.clone(), cfg, ScpOptions::default())?;
                c.set_offset_free(offset_free.cloned())?;
                Ok(ModelController::Bilinear(Box::new(c)))
            }
            LoadedModel::OneStep(m) => {
                if offset_free.is_some() {
                    return Err(Error::InvalidArgument(
                        "offset_free needs a lifted-linear or bilinear model (this one is a \
                         one-step NNDM)"
                            .into(),
                    ));
                }
                Ok(ModelController::Shooting(Box::new(Shooting {
                    planner: shooting_planner(m.as_ref(), cfg)?,
                    model: m.clone(),
                })))
            }
        }
    }
}

/// One model's controller.
pub enum ModelController {
    /// Koopman MPC on a lifted model (stateless between solves but for its warm start; with
    /// an offset-free correction consecutive solves are one closed loop, as for the bilinear
    /// MPC).
    Lifted(Box<MpcController<'static>>),
    /// Sequential convex MPC on a bilinear model. With an offset-free correction, consecutive
    /// solves are one closed loop: each measured state updates the correction before the plan,
    /// and the plan's first input is recorded as applied.
    Bilinear(Box<BilinearMpc<'static>>),
    /// Random-shooting MPC on a one-step model (SHOOTING_SAMPLES sequences per solve, seeded
    /// once when the controller is built, so an episode is reproducible).
    Shooting(Box<Shooting>),
    /// The LQR law on a lifted model (`MpcConfig::law = lqr`; stateless between solves).
    Lqr(Box<LqrLaw>),
}

/// A random-shooting planner and the one-step model it plans on.
pub struct Shooting {
    planner: RandomShooting,
    model: Arc<dyn OneStepModel>,
}

impl ModelController {
    /// State dimension.
    pub fn nx(&self) -> usize {
        match self {
            ModelController::Lifted(c) => c.nx(),
            ModelController::Bilinear(c) => c.nx(),
            ModelController::Shooting(s) => s.model.nx(),
            ModelController::Lqr(l) => l.model().nx(),
        }
    }

    /// Input dimension.
    pub fn nu(&self) -> usize {
        match self {
            ModelController::Lifted(c) => c.nu(),
            ModelController::Bilinear(c) => c.nu(),
            ModelController::Shooting(s) => s.model.nu(),
            ModelController::Lqr(l) => l.model().nu(),
        }
    }

    /// Horizon H.
    pub fn horizon(&self) -> usize {
        match self {
            ModelController::Lifted(c) => c.horizon(),
            ModelController::Bilinear(c) => c.horizon(),
            ModelController::Shooting(s) => s.planner.horizon,
            ModelController::Lqr(l) => l.horizon(),
        }
    }

    /// The kind of model it plans on, in words (`lifted-linear`, `bilinear`, `a one-step NNDM`).
    pub fn kind(&self) -> &'static str {
        match self {
            ModelController::Lifted(_) => "lifted-linear",
            ModelController::Bilinear(_) => "bilinear",
            ModelController::Shooting(_) => "a one-step NNDM",
            ModelController::Lqr(_) => "lifted-linear (LQR law)",
        }
    }

    /// True if the controller can plan about a feed-forward ([`ModelController::solve_about_plan`]):
    /// the Koopman MPC on a lifted-linear model and random shooting on a one-step NNDM.
    pub fn takes_feedforward(&self) -> bool {
        matches!(
            self,
            ModelController::Lifted(_) | ModelController::Shooting(_) | ModelController::Lqr(_)
        )
    }

    /// Plans from `x` towards `reference` (nx values, or the stacked H·nx).
    ///
    /// Errors: wrong lengths, non-finite values, a failed QP without fallback.
    pub fn solve(&mut self, x: &[f64], reference: &[f64]) -> Result<ModelPlan> {
        match self {
            ModelController::Lqr(l) => l.solve(x, reference),
            ModelController::Lifted(c) => {
                let nx = c.nx();
                if c.offset_free().is_some() {
                    if reference.len() < nx {
                        return Err(Error::dimension("reference", nx, reference.len()));
                    }
                    c.observe(x, &reference[..nx])?;
                }
                let s = c.solve(x, reference)?;
                c.record(x, s.first(c.nu()));
                Ok(lifted_plan(s))
            }
            ModelController::Shooting(s) => {
                let (nx, h) = (s.model.nx(), s.planner.horizon);
                // One state is held over the horizon; the stacked x_1..x_H is used as it is.
                let stacked = if reference.len() == nx {
                    reference.repeat(h)
                } else if reference.len() == h * nx {
                    reference.to_vec()
                } else {
                    return Err(Error::dimension(
                        "reference (nx or horizon·nx)",
                        h * nx,
                        reference.len(),
                    ));
                };
                ensure_finite("reference", &stacked)?;
                let t = Instant::now();
                let (u, _) = s.planner.plan_sequence(s.model.as_ref(), x, &stacked)?;
                Ok(ModelPlan {
                    status: PlanStatus::Solved,
                    iterations: s.planner.samples,
                    solve_time: t.elapsed(),
                    u,
                })
            }
            ModelController::Bilinear(c) => {
                let nx = c.nx();
                if reference.len() < nx {
                    return Err(Error::dimension("reference", nx, reference.len()));
                }
                c.observe(x, &reference[..nx])?;
                let s = c.solve(x, reference)?;
                c.record(x, &s.u[..c.nu()]);
                Ok(ModelPlan {
                    status: match s.status {
                        ScpStatus::Converged => PlanStatus::Solved,
                        ScpStatus::NotConverged => PlanStatus::Suboptimal,
                        ScpStatus::Fallback(_) => PlanStatus::Fallback,
                    },
                    iterations: s.qp_iterations,
                    solve_time: s.solve_time,
                    u: s.u,
                })
            }
        }
    }

    /// The error-state MPC about the plan whose state at this step is `reference` (nx values)
    /// with feed-forward `feedforward` (H·nu values): on a lifted-linear model
    /// [`MpcController::solve_about_plan`]; on a one-step NNDM random shooting about the
    /// feed-forward ([`RandomShooting::plan_sequence_about`]) towards the model's own rollout
    /// of the plan from `reference` (so that the model's bias along the plan cancels, as in the
    /// lifted error-state MPC).
    ///
    /// Errors: as [`ModelController::solve`]; a bilinear model's controller
    /// ([`ModelController::takes_feedforward`]) refuses with [`Error::InvalidArgument`].
    pub fn solve_about_plan(
        &mut self,
        x: &[f64],
        reference: &[f64],
        feedforward: &[f64],
    ) -> Result<ModelPlan> {
        match self {
            ModelController::Lqr(l) => l.solve_about_plan(x, reference, feedforward),
            ModelController::Lifted(c) => Ok(lifted_plan(c.solve_about_plan(
                x,
                reference,
                feedforward,
            )?)),
            ModelController::Shooting(s) => {
                let (nx, nu, h) = (s.model.nx(), s.model.nu(), s.planner.horizon);
                if reference.len() != nx {
                    return Err(Error::dimension("plan state", nx, reference.len()));
                }
                if feedforward.len() != h * nu {
                    return Err(Error::dimension("feed-forward", h * nu, feedforward.len()));
                }
                ensure_finite("plan state", reference)?;
                let t = Instant::now();
                let target = rollout(s.model.as_ref(), reference, feedforward);
                let (u, _) =
                    s.planner
                        .plan_sequence_about(s.model.as_ref(), x, &target, feedforward)?;
                Ok(ModelPlan {
                    status: PlanStatus::Solved,
                    iterations: s.planner.samples,
                    solve_time: t.elapsed(),
                    u,
                })
            }
            other => Err(Error::InvalidArgument(format!(
                "a feed-forward (error-state MPC) needs a lifted-linear model or an NNDM; this \
                 one is {}",
                other.kind()
            ))),
        }
    }
}

fn lifted_plan(s: super::MpcSolution) -> ModelPlan {
    ModelPlan {
        status: match s.status {
            SolveStatus::Solved => PlanStatus::Solved,
            SolveStatus::Inaccurate => PlanStatus::Inaccurate,
            SolveStatus::Suboptimal => PlanStatus::Suboptimal,
            SolveStatus::Fallback(_) => PlanStatus::Fallback,
        },
        iterations: s.iterations,
        solve_time: s.solve_time,
        u: s.u,
    }
}

/// The states `x_1 .. x_H` of `model` from `x0` under the inputs `us` (H·nu values), stacked.
fn rollout(model: &dyn OneStepModel, x0: &[f64], us: &[f64]) -> Vec<f64> {
    let (nx, nu) = (model.nx(), model.nu());
    let mut out = Vec::with_capacity(us.len() / nu.max(1) * nx);
    let mut x = x0.to_vec();
    let mut next = vec![0.0; nx];
    for u in us.chunks_exact(nu.max(1)) {
        model.predict(&x, u, &mut next);
        out.extend_from_slice(&next);
        std::mem::swap(&mut x, &mut next);
    }
    out
}

/// The random-shooting planner for `model` with `cfg` (horizon, `q`, `r`, the input bounds); the
/// settings it cannot honour (terminal weight, rate and state bounds) are refused rather than
/// ignored.
fn shooting_planner(model: &dyn OneStepModel, cfg: &MpcConfig) -> Result<RandomShooting> {
    let (nx, nu) = (model.nx(), model.nu());
    let refuse = |what: &str| {
        Err(Error::InvalidArgument(format!(
            "random-shooting MPC on a one-step NNDM: {what}"
        )))
    };
    if cfg.terminal.is_some() || cfg.terminal_riccati || cfg.has_general_constraints() {
        return refuse(
            "no terminal weight or terminal_riccati, rate or state bounds (input bounds only)",
        );
    }
    let q = cfg.q.clone().unwrap_or_else(|| vec![1.0; nx]);
    if q.len() != nx {
        return Err(Error::dimension("q", nx, q.len()));
    }
    let (Some(lo), Some(hi)) = (&cfg.u_min, &cfg.u_max) else {
        return refuse("it samples inputs within the bounds: set u_min and u_max");
    };
    if lo.len() != nu || hi.len() != nu {
        return Err(Error::dimension("input bounds", nu, lo.len().min(hi.len())));
    }
    let planner = RandomShooting::new(
        SHOOTING_SAMPLES,
        cfg.horizon,
        q,
        lo.clone(),
        hi.clone(),
        SHOOTING_SEED,
    )?;
    match &cfg.r {
        Some(r) => planner.with_input_weight(r.clone()),
        None => Ok(planner),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::arch::Arch;
    use crate::model::koopman::KoopmanModel;
    use std::path::PathBuf;

    fn scratch(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("koopman-served-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    fn cfg() -> MpcConfig {
        MpcConfig {
            horizon: 8,
            r: Some(vec![1e-3]),
            ..MpcConfig::with_bounds(vec![-1.0], vec![1.0])
        }
    }

    #[test]
    fn a_lifted_model_dir_gives_the_mpc_controller_with_or_without_offset_free() {
        let dir = scratch("lifted");
        KoopmanModel::init(Arch::new(2, 1, &[16, 16], 2).unwrap(), 5)
            .unwrap()
            .save(&dir)
            .unwrap();
        let loaded = LoadedModel::load(&dir).unwrap();
        assert_eq!(
            (loaded.kind(), loaded.nx(), loaded.nu()),
            ("lifted-linear", 2, 1)
        );
        let mut c = loaded.controller(&cfg(), None).unwrap();
        assert!(c.takes_feedforward());
        let model: Arc<dyn LiftedModel> = Arc::from(crate::model::load_lifted(&dir).unwrap());
        let mut direct = MpcController::from_shared(model, &cfg()).unwrap();
        for x in [[0.5, -0.2], [0.3, 0.1], [-0.4, 0.0]] {
            let (got, want) = (
                c.solve(&x, &[0.0, 0.0]).unwrap(),
                direct.solve(&x, &[0.0, 0.0]).unwrap(),
            );
            assert_eq!(got.u, want.u);
            assert_eq!(got.status, PlanStatus::Solved);
        }
        let of = OffsetFreeConfig::defaults(super::super::OffsetMode::Trajectory, 2, vec![0]);
        // The linear MPC takes the offset-free correction too (koopman/tests/linear_offset_free.rs).
        loaded.controller(&cfg(), Some(&of)).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_bilinear_model_dir_with_zero_n_plans_as_the_linear_mpc_and_refuses_a_feedforward() {
        let dir = scratch("bilinear");
        let linear = KoopmanModel::init(Arch::new(2, 1, &[16, 16], 2).unwrap(), 6).unwrap();
        let latent = linear.arch().latent_dim();
        let lin_dir = scratch("bilinear-linear");
        linear.save(&lin_dir).unwrap();
        BilinearModel::from_parts(linear, vec![0.0; latent * latent])
            .unwrap()
            .save(&dir)
            .unwrap();
        let loaded = LoadedModel::load(&dir).unwrap();
        assert_eq!(loaded.kind(), "bilinear");
        let mut c = loaded.controller(&cfg(), None).unwrap();
        let mut lin = LoadedModel::load(&lin_dir)
            .unwrap()
            .controller(&cfg(), None)
            .unwrap();
        // With every N_i = 0 the sequential convex MPC solves the linear MPC's QP.
        let x = [0.6, -0.3];
        let (b, l) = (
            c.solve(&x, &[0.0, 0.0]).unwrap(),
            lin.solve(&x, &[0.0, 0.0]).unwrap(),
        );
        for (ub, ul) in b.u.iter().zip(&l.u) {
            assert!((ub - ul).abs() < 1e-6, "{:?} vs {:?}", b.u, l.u);
        }
        assert!(!c.takes_feedforward());
        let Err(err) = c.solve_about_plan(&x, &[0.0, 0.0], &[0.0; 8]) else {
            panic!("a feed-forward to a bilinear controller must be refused");
        };
        assert!(err.to_string().contains("this one is bilinear"), "{err}");
        let _ = std::fs::remove_dir_all(&dir);
        let _ = std::fs::remove_dir_all(&lin_dir);
    }
}
