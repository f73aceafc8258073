//! The receding-horizon Koopman MPC controller: lifts the state, forms `q = M1 z_0 + M2 r`,
//! solves the QP warm-started from the shifted previous plan (the dedicated solver: from its
//! previous working set), and falls back safely on failure; optionally with the offset-free
//! correction of the bilinear MPC ([`offset`]).

use std::sync::Arc;
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use super::boxqp::{BoxQp, WarmStart};
use super::clarabel_qp::ClarabelQp;
use super::closed_form::ClampedClosedForm;
use super::condensed::{Condensed, Weights};
use super::config::{MpcConfig, SolverKind};
use super::constraints::{input_box, LinearConstraints};
use super::qp::{QpSolver, QpStatus};
use crate::error::{ensure_finite, Error, Result};
use crate::linalg::kernels::gemv_simd;
use crate::model::LiftedModel;

mod error_state;
mod offset;

/// Why the controller returned its fallback plan instead of a solver's answer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FallbackReason {
    /// The constraints (rate or state bounds) admit no solution at this state.
    Infeasible,
    /// The solver hit its iteration limit without a usable point.
    MaxIterations,
    /// The solver hit its time limit without a usable point.
    TimeLimit,
    /// The solver failed numerically or produced non-finite inputs.
    Numerical,
}

/// How the plan of one [`MpcController::solve`] was obtained.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SolveStatus {
    /// Optimal within the solver's tolerances.
    Solved,
    /// Optimal to reduced accuracy (Clarabel's `AlmostSolved`).
    Inaccurate,
    /// The dedicated solver stopped at its iteration or time limit; its plan is feasible
    /// (within the input bounds) and better than the warm start, but not proven optimal.
    Suboptimal,
    /// The solver failed; the plan is the previous plan shifted by one step (last input
    /// repeated), clamped to the input bounds — or the input closest to zero within the bounds
    /// when there is no previous plan.
    Fallback(FallbackReason),
}

/// One solve's result.
#[derive(Clone, Debug, PartialEq)]
pub struct MpcSolution {
    /// The input plan, H·nu values, first input first (always finite).
    pub u: Vec<f64>,
    /// How it was obtained.
    pub status: SolveStatus,
    /// Wall time of the solve (lifting, linear term and QP).
    pub solve_time: Duration,
    /// Wall time of the QP alone (within `solve_time`). For the dedicated solver it starts from
    /// `u* = −H⁻¹q`, which the step forms in its one product in place of `q` (as DAQP's solve
    /// time starts from its transformed linear term).
    pub qp_time: Duration,
    /// Solver iterations.
    pub iterations: usize,
}

impl MpcSolution {
    /// The first input of the plan (what a receding-horizon loop applies).
    pub fn first(&self, nu: usize) -> &[f64] {
        &self.u[..nu]
    }
}

/// The lifting Φ, borrowed or shared.
enum ModelRef<'m> {
    Borrowed(&'m dyn LiftedModel),
    Shared(Arc<dyn LiftedModel>),
}

impl ModelRef<'_> {
    fn get(&self) -> &dyn LiftedModel {
        match self {
            ModelRef::Borrowed(m) => *m,
            ModelRef::Shared(m) => m.as_ref(),
        }
    }
}

/// The QP solver of a controller: the dedicated box solver is called from the unconstrained
/// optimum `u*`, which the controller forms in one product; the others from `q`.
enum Backend {
    Dedicated {
        qp: Box<BoxQp>,
        /// `G = −H⁻¹ [M1 M2]` (column-major, n × (N + H·nx)): `u* = G [z_0; r]`.
        g: Vec<f64>,
        /// The error-state map `[G₂Φ  G₂Γ + H⁻¹D]` (column-major, n × (N + n); G₂ = G's
        /// reference columns, D = diag(R̄ + δI)): `u* = G₁z_0 + G_plan [ž; u_ff]` without
        /// forming the plan's rollout. Built at the first [`MpcController::solve_about_plan`].
        g_plan: Option<Vec<f64>>,
    },
    Other(Box<dyn QpSolver>),
}

/// Linear MPC on a lifted model (SPEC.md, "Control"). Every matrix that depends on the model
/// alone is built once in [`MpcController::new`]; each [`MpcController::solve`] costs one lift,
/// one product (the dedicated solver's `u* = −H⁻¹q = G [z_0; r]`, the other solvers'
/// `q = M1 z_0 + M2 r`) and the QP.
pub struct MpcController<'m> {
    model: ModelRef<'m>,
    cfg: MpcConfig,
    condensed: Condensed,
    constraints: Option<LinearConstraints>,
    solver: Backend,
    lo: Vec<f64>,
    hi: Vec<f64>,
    plan: Option<Vec<f64>>,
    u_prev: Vec<f64>,
    // Workspace.
    r: Vec<f64>,
    q: Vec<f64>,
    /// False when `q` has not been formed for the last solve (the dedicated solver needs `u*`
    /// only); `linear_term` forms it from `zr`.
    q_current: bool,
    /// `[z_0; r]` of the last solve.
    zr: Vec<f64>,
    ustar: Vec<f64>,
    h: Vec<f64>,
    /// `d ⊙ u_ff` of the last [`MpcController::solve_about_plan`] (empty after a plain solve):
    /// the input weights' pull towards the feed-forward, part of that solve's linear term.
    pull: Vec<f64>,
    /// `[ž_0; u_ff]` of the last error-state solve with the dedicated solver, whose reference
    /// part of `zr` (the plan's rollout) is then formed only if `linear_term` asks for it.
    plan_in: Vec<f64>,
    /// True while `zr`'s reference part waits for the rollout of `plan_in`.
    rollout_pending: bool,
    /// The offset-free correction, if on ([`MpcController::set_offset_free`]).
    offset: Option<super::offset_free::OffsetFree>,
    /// `S = [S_0; …; S_{H−1}]` (row-major, H·nx × nx): the offset of the predicted `x_{τ+1}`
    /// per unit of the constant state disturbance, `S_τ = Σ_{j≤τ} P A^j E`.
    disturbance_map: Vec<f64>,
    /// The offset the correction adds to the predicted states `x_1..x_H` in the last solve
    /// (H·nx values; empty when none).
    pred_offset: Vec<f64>,
    /// With `terminal_riccati`: `Γ_zᵀ P Φ(r_H)` of the last solve, subtracted from its linear
    /// term (empty otherwise).
    terminal_pull: Vec<f64>,
}

impl<'m> MpcController<'m> {
    /// Builds the controller for `model` (borrowed for the controller's lifetime).
    pub fn new(model: &'m dyn LiftedModel, cfg: &MpcConfig) -> Result<Self> {
        Self::build(ModelRef::Borrowed(model), cfg)
    }
}

impl MpcController<'static> {
    /// Builds a controller that shares ownership of `model` (for services that keep it).
    pub fn from_shared(model: Arc<dyn LiftedModel>, cfg: &MpcConfig) -> Result<Self> {
        Self::build(ModelRef::Shared(model), cfg)
    }
}

impl<'m> MpcController<'m> {
    fn build(model: ModelRef<'m>, cfg: &MpcConfig) -> Result<Self> {
        if cfg.law != super::config::ControlLaw::Mpc {
            return Err(Error::InvalidArgument(
                "law = \"lqr\" is not this MPC: the LQR law is built by \
                 LoadedModel::controller (the MPC service, the exported FMU)"
                    .into(),
            ));
        }
        let m = model.get();
        let (nx, nu, latent) = (m.nx(), m.nu(), m.latent_dim());
        let a = m.a();
        let b = m.b();
        if a.nrows() != latent || a.ncols() != latent {
            return Err(Error::dimension(
                "A rows (latent dimension)",
                latent,
                a.nrows(),
            ));
        }
        if b.nrows() != latent || b.ncols() != nu {
            return Err(Error::dimension("B columns (inputs)", nu, b.ncols()));
        }
        let q = cfg.q.clone().unwrap_or_else(|| vec![1.0; nx]);
        if cfg.terminal_riccati && cfg.terminal.is_some() {
            return Err(Error::InvalidArgument(
                "terminal_riccati replaces the terminal weight: give one of terminal and \
                 terminal_riccati"
                    .into(),
            ));
        }
        let terminal = match (&cfg.terminal, cfg.terminal_riccati) {
            (_, true) => vec![0.0; nx], // the cost-to-go P holds x_H's stage cost
            (Some(t), false) => t.clone(),
            (None, false) => q.clone(),
        };
        let r = cfg.r.clone().unwrap_or_else(|| vec![0.0; nu]);
        let w = Weights {
            q: &q,
            terminal: &terminal,
            r: &r,
            regularization: cfg.regularization,
        };
        let mut condensed = Condensed::build(a.as_ref(), b.as_ref(), nx, cfg.horizon, &w)?;
        if cfg.terminal_riccati {
            let lqr = super::lqr::Lqr::new(m, &q, &r, 100_000, 1e-12)?;
            if !lqr.converged {
                return Err(Error::Numerical(format!(
                    "terminal_riccati: the Riccati iteration of the model did not converge in {} \
                     iterations (is (A, B) stabilisable under these weights?)",
                    lqr.iterations
                )));
            }
            condensed = condensed.with_lifted_terminal(a.as_ref(), b.as_ref(), lqr.p.as_ref())?;
        }
        let (lo, hi) = input_box(cfg, nu, cfg.horizon)?;
        if let Some(t) = cfg.time_limit {
            if t.is_nan() || t <= 0.0 {
                return Err(Error::InvalidArgument(format!(
                    "time_limit must be > 0 s, got {t}"
                )));
            }
        }
        let (solver, constraints): (Backend, Option<LinearConstraints>) = match cfg.solver {
            SolverKind::Dedicated => {
                if cfg.has_general_constraints() {
                    return Err(Error::InvalidArgument(
                        "the dedicated solver handles input bounds only; use the clarabel solver for input-rate or state bounds".into(),
                    ));
                }
                let mut s = BoxQp::new(
                    condensed.hessian.as_ref(),
                    &lo,
                    &hi,
                    cfg.max_iterations,
                    cfg.time_limit,
                )?;
                // The previous solve's working set is a far better first guess than the bounds
                // the shifted plan touches on chattering loops (docs/decisions/0001-box-qp-solver.md).
                s.set_warm_start(WarmStart::Previous);
                let g = ustar_map(&condensed, s.hessian_inverse());
                (
                    Backend::Dedicated {
                        qp: Box::new(s),
                        g,
                        g_plan: None,
                    },
                    None,
                )
            }
            SolverKind::Clarabel => {
                let c = LinearConstraints::build(cfg, &condensed)?;
                let s = ClarabelQp::new(
                    condensed.hessian.as_ref(),
                    c.g.as_ref(),
                    cfg.max_iterations,
                    cfg.time_limit,
                )?;
                (Backend::Other(Box::new(s)), Some(c))
            }
            SolverKind::ClosedForm => {
                let s = ClampedClosedForm::new(condensed.hessian.as_ref(), &lo, &hi)?;
                (Backend::Other(Box::new(s)), None)
            }
        };
        let n = condensed.n_vars();
        Ok(MpcController {
            model,
            cfg: cfg.clone(),
            constraints,
            solver,
            lo,
            hi,
            plan: None,
            u_prev: vec![0.0; nu],
            r: vec![0.0; cfg.horizon * nx],
            q: vec![0.0; n],
            q_current: true,
            zr: vec![0.0; condensed.latent + cfg.horizon * nx],
            ustar: vec![0.0; n],
            h: Vec::new(),
            pull: Vec::new(),
            plan_in: Vec::new(),
            rollout_pending: false,
            offset: None,
            disturbance_map: Vec::new(),
            pred_offset: Vec::new(),
            terminal_pull: Vec::new(),
            condensed,
        })
    }

    /// State dimension nx.
    pub fn nx(&self) -> usize {
        self.condensed.nx
    }

    /// Input dimension nu.
    pub fn nu(&self) -> usize {
        self.condensed.nu
    }

    /// Horizon H.
    pub fn horizon(&self) -> usize {
        self.condensed.horizon
    }

    /// The configuration the controller was built with.
    pub fn config(&self) -> &MpcConfig {
        &self.cfg
    }

    /// The condensed matrices (Hessian, M1, M2, Φ, Γ).
    pub fn condensed(&self) -> &Condensed {
        &self.condensed
    }

    /// The linear term `q` of the last solve's QP (`min ½UᵀHU + qᵀU`, H·nu values; zeros
    /// before the first solve), e.g. to record the QP sequence of a closed loop. With the
    /// dedicated solver a solve forms `u* = −H⁻¹q` instead, and `q` is formed here.
    pub fn linear_term(&mut self) -> &[f64] {
        if !self.q_current {
            let latent = self.condensed.latent;
            if self.rollout_pending {
                let (z_plan, u_ff) = self.plan_in.split_at(latent);
                let rollout = self.condensed.predict(z_plan, u_ff);
                self.zr[latent..].copy_from_slice(&rollout);
                self.rollout_pending = false;
            }
            let (z0, r) = self.zr.split_at(latent);
            self.condensed.linear_term(z0, r, &mut self.q);
            self.q.iter_mut().zip(&self.pull).for_each(|(q, p)| *q -= p);
            self.q
                .iter_mut()
                .zip(&self.terminal_pull)
                .for_each(|(q, p)| *q -= p);
            self.q_current = true;
        }
        &self.q
    }

    /// Forgets the warm start and the previous input (e.g. at the start of an episode).
    pub fn reset(&mut self) {
        self.plan = None;
        self.u_prev.fill(0.0);
        match &mut self.solver {
            Backend::Dedicated { qp, .. } => qp.reset(),
            Backend::Other(s) => s.reset(),
        }
    }

    /// Sets the input applied at the previous step (`u_{−1}` of the rate bounds). `solve` sets
    /// it to the first input of its plan; call this if something else was applied.
    pub fn set_previous_input(&mut self, u: &[f64]) -> Result<()> {
        if u.len() != self.nu() {
            return Err(Error::dimension("previous input", self.nu(), u.len()));
        }
        ensure_finite("previous input", u)?;
        self.u_prev.copy_from_slice(u);
        Ok(())
    }

    /// Expands a reference of nx values (held over the horizon) or H·nx values (stacked).
    fn set_reference(&mut self, reference: &[f64]) -> Result<()> {
        let (nx, hz) = (self.nx(), self.horizon());
        expand_reference(&mut self.r, reference, nx, hz)?;
        self.shift_for_offset();
        Ok(())
    }

    /// Plans from state `x` (nx values) towards `reference` (nx values held over the horizon,
    /// or the stacked H·nx values of `x_1..x_H`).
    ///
    /// Errors: wrong lengths or non-finite state/reference (`Dimension`, `InvalidArgument`,
    /// `NonFinite`); a solver failure is an error only when `fallback` is off.
    pub fn solve(&mut self, x: &[f64], reference: &[f64]) -> Result<MpcSolution> {
        let start = Instant::now();
        if x.len() != self.nx() {
            return Err(Error::dimension("state", self.nx(), x.len()));
        }
        ensure_finite("state", x)?;
        let z0 = self.model.get().lift(x);
        self.check_lifted(&z0)?;
        self.solve_lifted_from(start, &z0, reference, None)
    }

    /// Like [`MpcController::solve`] but from an already lifted state `z_0` (N values).
    pub fn solve_lifted(&mut self, z0: &[f64], reference: &[f64]) -> Result<MpcSolution> {
        let start = Instant::now();
        self.check_lifted(z0)?;
        self.solve_lifted_from(start, z0, reference, None)
    }

    /// A lifted state must have N finite values (a model's lifting is checked, not trusted).
    fn check_lifted(&self, z: &[f64]) -> Result<()> {
        if z.len() != self.condensed.latent {
            return Err(Error::dimension(
                "lifted state",
                self.condensed.latent,
                z.len(),
            ));
        }
        ensure_finite("lifted state", z)
    }

    fn solve_lifted_from(
        &mut self,
        start: Instant,
        z0: &[f64],
        reference: &[f64],
        feedforward: Option<&[f64]>,
    ) -> Result<MpcSolution> {
        self.set_reference(reference)?;
        let latent = self.condensed.latent;
        self.rollout_pending = false;
        self.zr[..latent].copy_from_slice(z0);
        self.zr[latent..].copy_from_slice(&self.r);
        self.q_current = matches!(self.solver, Backend::Other(_));
        match &self.solver {
            Backend::Dedicated { g, .. } => {
                // u* = −H⁻¹q = G [z_0; r]: one product, and the QP skips its own.
                self.ustar.fill(0.0);
                gemv_simd(g, &self.zr, &mut self.ustar);
            }
            Backend::Other(_) => self.condensed.linear_term(z0, &self.r, &mut self.q),
        }
        self.pull_to_terminal_reference()?;
        match feedforward {
            Some(u_ff) => self.weigh_deviation_from(u_ff),
            None => self.pull.clear(),
        }
        self.solve_qp(start, z0)
    }

    /// With a lifted terminal cost, the linear term's `−Γ_zᵀ P Φ(r_H)` (`r_H`: the reference's
    /// last step), applied as the input weights' pull is: subtracted from `q`, or `H⁻¹` of it
    /// added to the dedicated solver's `u*`.
    fn pull_to_terminal_reference(&mut self) -> Result<()> {
        let Some(tm) = &self.condensed.terminal_map else {
            return Ok(());
        };
        let nx = self.condensed.nx;
        let r_h = &self.r[self.r.len() - nx..];
        let z_ref = self.model.get().lift(r_h);
        if z_ref.len() != self.condensed.latent || z_ref.iter().any(|v| !v.is_finite()) {
            return Err(Error::NonFinite("the lifted terminal reference".into()));
        }
        self.terminal_pull.clear();
        self.terminal_pull.resize(tm.nrows(), 0.0);
        super::condensed::gemv_acc(tm.as_ref(), &z_ref, &mut self.terminal_pull);
        match &self.solver {
            Backend::Dedicated { qp, .. } => {
                gemv_simd(qp.hessian_inverse(), &self.terminal_pull, &mut self.ustar)
            }
            Backend::Other(_) => self
                .q
                .iter_mut()
                .zip(&self.terminal_pull)
                .for_each(|(q, p)| *q -= p),
        }
        Ok(())
    }

    /// The QP of a solve whose `u*` (dedicated solver) or `q` (the others) is formed, then the
    /// status, the fallback and the warm start of the next solve.
    fn solve_qp(&mut self, start: Instant, z0: &[f64]) -> Result<MpcSolution> {
        if let Some(c) = &self.constraints {
            let mut free = vec![0.0; self.condensed.horizon * self.condensed.nx];
            super::condensed::gemv_acc(self.condensed.phi.as_ref(), z0, &mut free);
            // The correction's offset moves the predictions the state bounds apply to.
            free.iter_mut()
                .zip(&self.pred_offset)
                .for_each(|(f, p)| *f += p);
            c.rhs(&free, &self.u_prev, &mut self.h);
        }
        let mut u = self.shifted_plan();
        let qp_start = Instant::now();
        let outcome = match &mut self.solver {
            Backend::Dedicated { qp, .. } => qp.solve_unconstrained(&self.ustar, &mut u),
            Backend::Other(s) => s.solve(&self.q, &self.h, &mut u),
        };
        let qp_time = qp_start.elapsed();
        let finite = u.iter().all(|v| v.is_finite());
        let status = match outcome.status {
            QpStatus::Solved if finite => SolveStatus::Solved,
            QpStatus::Inaccurate if finite => SolveStatus::Inaccurate,
            QpStatus::MaxIterations | QpStatus::TimeLimit if finite && outcome.feasible_iterate => {
                SolveStatus::Suboptimal
            }
            QpStatus::Infeasible => SolveStatus::Fallback(FallbackReason::Infeasible),
            QpStatus::MaxIterations => SolveStatus::Fallback(FallbackReason::MaxIterations),
            QpStatus::TimeLimit => SolveStatus::Fallback(FallbackReason::TimeLimit),
            _ => SolveStatus::Fallback(FallbackReason::Numerical),
        };
        if let SolveStatus::Fallback(reason) = status {
            if !self.cfg.fallback {
                return Err(Error::Numerical(format!(
                    "{} solver failed ({reason:?}) and fallback is off",
                    match &self.solver {
                        Backend::Dedicated { qp, .. } => qp.name(),
                        Backend::Other(s) => s.name(),
                    }
                )));
            }
            u = self.shifted_plan();
        }
        let nu = self.nu();
        self.u_prev.copy_from_slice(&u[..nu]);
        self.plan = Some(u.clone());
        Ok(MpcSolution {
            u,
            status,
            solve_time: start.elapsed(),
            qp_time,
            iterations: outcome.iterations,
        })
    }

    /// The previous plan shifted by one step (last input repeated) and clamped to the input
    /// bounds; without a previous plan, the input closest to zero within the bounds.
    fn shifted_plan(&self) -> Vec<f64> {
        let (nu, n) = (self.nu(), self.condensed.n_vars());
        let mut u = vec![0.0; n];
        if let Some(p) = &self.plan {
            u[..n - nu].copy_from_slice(&p[nu..]);
            u[n - nu..].copy_from_slice(&p[n - nu..]);
        }
        for (i, v) in u.iter_mut().enumerate() {
            *v = v.clamp(self.lo[i], self.hi[i]);
        }
        u
    }
}

/// `G = −H⁻¹ [M1 M2]` (column-major, n × (N + H·nx)) from H⁻¹ (column-major, symmetric).
fn ustar_map(c: &Condensed, hinv: &[f64]) -> Vec<f64> {
    let n = c.n_vars();
    let hinv = faer::MatRef::from_column_major_slice(hinv, n, n);
    let m = faer::Mat::from_fn(n, c.m1.ncols() + c.m2.ncols(), |i, j| {
        if j < c.m1.ncols() {
            c.m1[(i, j)]
        } else {
            c.m2[(i, j - c.m1.ncols())]
        }
    });
    let g = -(hinv * m);
    let mut out = Vec::with_capacity(g.nrows() * g.ncols());
    for j in 0..g.ncols() {
        out.extend((0..n).map(|i| g[(i, j)]));
    }
    out
}

/// Writes into `r` (H·nx values) a reference of nx values held over the horizon `hz`, or of
/// H·nx stacked values; any other length is `InvalidArgument`, a non-finite one `NonFinite`.
pub(crate) fn expand_reference(
    r: &mut [f64],
    reference: &[f64],
    nx: usize,
    hz: usize,
) -> Result<()> {
    if reference.len() == nx {
        for t in 0..hz {
            r[t * nx..(t + 1) * nx].copy_from_slice(reference);
        }
    } else if reference.len() == hz * nx {
        r.copy_from_slice(reference);
    } else {
        return Err(Error::InvalidArgument(format!(
            "reference has {} values; expected nx = {nx} (held) or H·nx = {} (stacked)",
            reference.len(),
            hz * nx
        )));
    }
    ensure_finite("reference", r)
}
