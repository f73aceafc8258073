//! Controllers seen from the closed loop: one trait, [`Policy`], implemented by the Koopman MPC
//! (any solver), LQR on the lifted model and random-shooting MPC.

use std::time::{Duration, Instant};

use super::controller::{MpcController, SolveStatus};
use super::lqr::Lqr;
use super::shooting::{OneStepModel, RandomShooting, SystemAsModel};
use crate::error::{Error, Result};
use crate::model::LiftedModel;
use crate::systems::System;

/// One control decision.
#[derive(Clone, Debug, PartialEq)]
pub struct Action {
    /// The input to apply (nu values, finite).
    pub u: Vec<f64>,
    /// Time spent deciding.
    pub solve_time: Duration,
    /// True if the controller used its fallback.
    pub fallback: bool,
}

/// A feedback controller: state and reference window in, input out.
pub trait Policy {
    /// Name for reports (`koopman-mpc/dedicated`, `lqr`, …).
    fn name(&self) -> String;
    /// How many future reference states it wants (`r_{k+1}..r_{k+H}`).
    fn horizon(&self) -> usize;
    /// Decides `u_k` from `x_k`, the current reference `r_k` and `future` = `r_{k+1}..r_{k+H}`.
    fn act(&mut self, x: &[f64], current: &[f64], future: &[f64]) -> Result<Action>;
}

impl Policy for MpcController<'_> {
    fn name(&self) -> String {
        let offset = self.offset_free().map_or("", |o| match o.config().mode {
            super::OffsetMode::Disturbance => "+disturbance",
            super::OffsetMode::Integral => "+integral",
            super::OffsetMode::Trajectory => "+trajectory",
        });
        format!("koopman-mpc/{}{offset}", self.config().solver.name())
    }
    fn horizon(&self) -> usize {
        MpcController::horizon(self)
    }
    /// With an offset-free correction on, the state `x` and the current reference update it
    /// before the solve, and the applied input is recorded after it.
    fn act(&mut self, x: &[f64], current: &[f64], future: &[f64]) -> Result<Action> {
        self.observe(x, current)?;
        let s = self.solve(x, future)?;
        self.record(x, s.first(self.nu()));
        Ok(Action {
            u: s.first(self.nu()).to_vec(),
            solve_time: s.solve_time,
            fallback: matches!(s.status, SolveStatus::Fallback(_)),
        })
    }
}

/// LQR with feed-forward on a lifted model, clamped to the input bounds.
pub struct LqrPolicy<'m> {
    /// The gain and feed-forward.
    pub lqr: Lqr,
    model: &'m dyn LiftedModel,
    u_min: Vec<f64>,
    u_max: Vec<f64>,
}

impl<'m> LqrPolicy<'m> {
    /// Wraps a computed LQR with the model (for lifting) and clamping bounds (nu each).
    pub fn new(
        lqr: Lqr,
        model: &'m dyn LiftedModel,
        u_min: Vec<f64>,
        u_max: Vec<f64>,
    ) -> Result<Self> {
        if u_min.len() != model.nu() || u_max.len() != model.nu() {
            return Err(Error::dimension(
                "LQR input bounds",
                model.nu(),
                u_min.len(),
            ));
        }
        Ok(LqrPolicy {
            lqr,
            model,
            u_min,
            u_max,
        })
    }
}

impl Policy for LqrPolicy<'_> {
    fn name(&self) -> String {
        "lqr".into()
    }
    fn horizon(&self) -> usize {
        1
    }
    fn act(&mut self, x: &[f64], current: &[f64], future: &[f64]) -> Result<Action> {
        let t = Instant::now();
        let z = self.model.lift(x);
        let zr = self.model.lift(current);
        let zn = self.model.lift(&future[..self.model.nx()]);
        let mut u = self.lqr.control(&z, &zr, &zn)?;
        for (i, v) in u.iter_mut().enumerate() {
            *v = v.clamp(self.u_min[i], self.u_max[i]);
        }
        Ok(Action {
            u,
            solve_time: t.elapsed(),
            fallback: false,
        })
    }
}

/// Random-shooting MPC on a one-step model.
pub struct ShootingPolicy<'m> {
    /// The planner.
    pub planner: RandomShooting,
    model: PlanningModel<'m>,
    label: String,
}

/// The one-step model a [`ShootingPolicy`] plans on: borrowed, or a reference system wrapped
/// by the policy itself (so that no caller has to keep the wrapper alive).
enum PlanningModel<'m> {
    Borrowed(&'m dyn OneStepModel),
    System(SystemAsModel<'m>),
}

impl<'m> ShootingPolicy<'m> {
    /// `label` names the model in reports (e.g. `oracle`, `nndm`).
    pub fn new(planner: RandomShooting, model: &'m dyn OneStepModel, label: &str) -> Self {
        ShootingPolicy {
            planner,
            model: PlanningModel::Borrowed(model),
            label: label.to_string(),
        }
    }

    /// Plans on the true system as its own one-step model (the oracle baseline).
    pub fn on_system(planner: RandomShooting, system: &'m dyn System, label: &str) -> Self {
        ShootingPolicy {
            planner,
            model: PlanningModel::System(SystemAsModel(system)),
            label: label.to_string(),
        }
    }
}

impl PlanningModel<'_> {
    fn get(&self) -> &dyn OneStepModel {
        match self {
            PlanningModel::Borrowed(m) => *m,
            PlanningModel::System(m) => m,
        }
    }
}

impl Policy for ShootingPolicy<'_> {
    fn name(&self) -> String {
        format!("random-shooting/{}", self.label)
    }
    fn horizon(&self) -> usize {
        self.planner.horizon
    }
    fn act(&mut self, x: &[f64], _current: &[f64], future: &[f64]) -> Result<Action> {
        let t = Instant::now();
        let (u, _) = self.planner.plan(self.model.get(), x, future)?;
        Ok(Action {
            u,
            solve_time: t.elapsed(),
            fallback: false,
        })
    }
}

/// Applies a constant input (zero by default): the "do nothing" baseline every controller must
/// beat — on the damped pendulum gravity and damping alone bring the state towards rest.
pub struct ConstantPolicy {
    u: Vec<f64>,
}

impl ConstantPolicy {
    /// A policy that always applies `u`; errors on a non-finite value.
    pub fn new(u: Vec<f64>) -> Result<Self> {
        crate::error::ensure_finite("constant input", &u)?;
        Ok(ConstantPolicy { u })
    }

    /// The zero input of dimension `nu`.
    pub fn zero(nu: usize) -> Self {
        ConstantPolicy { u: vec![0.0; nu] }
    }
}

impl Policy for ConstantPolicy {
    fn name(&self) -> String {
        if self.u.iter().all(|&v| v == 0.0) {
            "zero-input".into()
        } else {
            "constant-input".into()
        }
    }
    fn horizon(&self) -> usize {
        1
    }
    fn act(&mut self, x: &[f64], _current: &[f64], _future: &[f64]) -> Result<Action> {
        crate::error::ensure_finite("state", x)?;
        Ok(Action {
            u: self.u.clone(),
            solve_time: Duration::ZERO,
            fallback: false,
        })
    }
}
