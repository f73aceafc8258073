//! Sequential convex MPC on a bilinear Koopman model: linearise `z⁺ = A z + B u + Σ u_i N_i z`
//! along a nominal plan, solve the time-varying condensed box QP with the dedicated solver,
//! re-linearise along the new plan, until the plan stops moving or a cap is reached.
//!
//! Along a nominal `(z̄_τ, ū_τ)` the model is `δz_{τ+1} = A_τ δz_τ + B_τ δu_τ` with
//! `A_τ = A + Σ_i ū_{τ,i} N_i` and `B_τ = B + [N_1 z̄_τ … N_nu z̄_τ]`, so the predicted states are
//! `X ≈ X̄ + Γ (U − Ū)` and the QP in U is `min ½UᵀHU + qᵀU`, `H = ΓᵀQ̄Γ + R̄ + δI`,
//! `q = ΓᵀQ̄ (X̄ − ΓŪ − r)`, `lo ≤ U ≤ hi`. With every N_i = 0 this is the linear MPC's QP.
//! A fixed point of the iteration satisfies the KKT conditions of the bilinear problem.
//!
//! An optional offset-free correction ([`BilinearMpc::set_offset_free`], [`super::offset_free`])
//! removes the steady offset a model bias leaves near the target: [`Policy::act`] updates it
//! from each measured state; it adds a constant disturbance to the predictions or shifts the
//! reference.

use std::sync::Arc;
use std::time::{Duration, Instant};

use faer::Mat;
use serde::{Deserialize, Serialize};

use super::boxqp::BoxQp;
use super::config::MpcConfig;
use super::constraints::input_box;
use super::controller::{expand_reference, FallbackReason};
use super::offset_free::{OffsetFree, OffsetFreeConfig};
use super::policy::{Action, Policy};
use super::qp::{QpOutcome, QpSolver, QpStatus};
use crate::error::{ensure_finite, Error, Result};
use crate::model::bilinear::BilinearModel;

mod linearise;

/// How a [`BilinearMpc::solve`] ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ScpStatus {
    /// The plan moved less than the tolerance between two linearisations.
    Converged,
    /// The cap on linearisations was reached first; the plan is the one of lowest cost on the
    /// bilinear model among those evaluated (finite, within the bounds).
    NotConverged,
    /// The QP solver failed on the first linearisation; the plan is the shifted previous plan
    /// clamped to the bounds (or the input closest to zero without one).
    Fallback(FallbackReason),
}

/// One solve's result.
#[derive(Clone, Debug, PartialEq)]
pub struct BilinearSolution {
    /// The input plan, H·nu values, first input first (always finite, within the bounds).
    pub u: Vec<f64>,
    /// How it was obtained.
    pub status: ScpStatus,
    /// QPs solved (linearisations).
    pub linearisations: usize,
    /// QP iterations, summed over the linearisations.
    pub qp_iterations: usize,
    /// The plan's MPC cost on the bilinear model (exact rollout).
    pub cost: f64,
    /// Wall time (lifting, linearisations, QPs, rollouts).
    pub solve_time: Duration,
}

/// Options of the sequential convex iteration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScpOptions {
    /// Most linearisations (QPs) per solve.
    pub max_linearisations: usize,
    /// Converged when `max |U_new − U_old| ≤ tol · (1 + max |U_old|)`.
    pub tol: f64,
}

impl Default for ScpOptions {
    fn default() -> Self {
        ScpOptions {
            max_linearisations: 3,
            tol: 1e-6,
        }
    }
}

/// The model a [`BilinearMpc`] plans with: borrowed, or shared with other owners (a service that
/// keeps controllers beyond any borrow).
enum ModelRef<'m> {
    Borrowed(&'m BilinearModel),
    Shared(Arc<BilinearModel>),
}

impl ModelRef<'_> {
    fn get(&self) -> &BilinearModel {
        match self {
            ModelRef::Borrowed(m) => m,
            ModelRef::Shared(m) => m,
        }
    }
}

/// Receding-horizon MPC on a [`BilinearModel`] by sequential convex programming. Every buffer
/// is allocated in [`BilinearMpc::new`]; a solve costs `O(H²·N²·nu)` per linearisation.
pub struct BilinearMpc<'m> {
    model: ModelRef<'m>,
    opts: ScpOptions,
    cfg: MpcConfig,
    nx: usize,
    nu: usize,
    nn: usize,
    hz: usize,
    /// A, B and the N_i, column-major.
    a: Vec<f64>,
    b: Vec<f64>,
    n: Vec<f64>,
    /// Diagonal of Q̄ (H·nx) and R̄ (H·nu).
    qbar: Vec<f64>,
    rbar: Vec<f64>,
    lo: Vec<f64>,
    hi: Vec<f64>,
    solver: BoxQp,
    plan: Option<Vec<f64>>,
    offset: Option<OffsetFree>,
    // Workspace.
    r: Vec<f64>,
    zbar: Vec<f64>,
    at: Vec<f64>,
    bt: Vec<f64>,
    s: Vec<f64>,
    s2: Vec<f64>,
    gamma: Mat<f64>,
    wq: Mat<f64>,
    hess: Mat<f64>,
    xfree: Vec<f64>,
    q: Vec<f64>,
}

impl<'m> BilinearMpc<'m> {
    /// A controller for `model` with `cfg`'s horizon, weights, input bounds, regularisation and
    /// iteration limit (the dedicated box solver; `cfg.solver` is not used).
    ///
    /// Errors: rate or state bounds (not supported here), bad weights or bounds.
    pub fn new(model: &'m BilinearModel, cfg: &MpcConfig, opts: ScpOptions) -> Result<Self> {
        Self::with_model(ModelRef::Borrowed(model), cfg, opts)
    }

    /// [`BilinearMpc::new`] on a shared model: the controller owns a handle and borrows nothing.
    pub fn from_shared(
        model: Arc<BilinearModel>,
        cfg: &MpcConfig,
        opts: ScpOptions,
    ) -> Result<BilinearMpc<'static>> {
        BilinearMpc::with_model(ModelRef::Shared(model), cfg, opts)
    }

    fn with_model(handle: ModelRef<'m>, cfg: &MpcConfig, opts: ScpOptions) -> Result<Self> {
        let model = handle.get();
        if cfg.has_general_constraints() {
            return Err(Error::InvalidArgument(
                "bilinear MPC handles input bounds only (no rate or state bounds)".into(),
            ));
        }
        if cfg.horizon == 0 {
            return Err(Error::InvalidArgument(
                "MPC horizon must be at least 1".into(),
            ));
        }
        if opts.max_linearisations == 0 || !(opts.tol >= 0.0 && opts.tol.is_finite()) {
            return Err(Error::InvalidArgument(
                "the sequential convex MPC needs max_linearisations ≥ 1 and a finite tol ≥ 0"
                    .into(),
            ));
        }
        if !(cfg.regularization.is_finite() && cfg.regularization >= 0.0) {
            return Err(Error::InvalidArgument(format!(
                "regularization must be finite and ≥ 0, got {}",
                cfg.regularization
            )));
        }
        let (nx, nu, nn, hz) = (model.nx(), model.nu(), model.latent_dim(), cfg.horizon);
        let weights = |what: &str, v: &Option<Vec<f64>>, n: usize, d: f64| -> Result<Vec<f64>> {
            let v = v.clone().unwrap_or_else(|| vec![d; n]);
            if v.len() != n {
                return Err(Error::dimension(what, n, v.len()));
            }
            if v.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
                return Err(Error::InvalidArgument(format!(
                    "{what} must be finite and ≥ 0"
                )));
            }
            Ok(v)
        };
        if cfg.terminal_riccati {
            return Err(Error::InvalidArgument(
                "terminal_riccati needs a lifted-linear model (koopman or edmd); the bilinear \
                 MPC takes a terminal weight"
                    .into(),
            ));
        }
        let q = weights("Q", &cfg.q, nx, 1.0)?;
        let terminal = weights("terminal weight", &cfg.terminal, nx, 1.0)?;
        let terminal = if cfg.terminal.is_some() {
            terminal
        } else {
            q.clone()
        };
        let rw = weights("R", &cfg.r, nu, 0.0)?;
        let qbar = (0..hz * nx)
            .map(|k| {
                if k / nx + 1 == hz {
                    terminal[k % nx]
                } else {
                    q[k % nx]
                }
            })
            .collect();
        let rbar = (0..hz * nu).map(|k| rw[k % nu]).collect();
        let (lo, hi) = input_box(cfg, nu, hz)?;
        let (am, bm) = (model.linear().a_ref(), model.linear().b_ref());
        let a = (0..nn * nn).map(|k| am[(k % nn, k / nn)]).collect();
        let b = (0..nn * nu).map(|k| bm[(k % nn, k / nn)]).collect();
        let mut n = vec![0.0; nu * nn * nn];
        for i in 0..nu {
            let ni = model.n_mat(i);
            for k in 0..nn * nn {
                n[i * nn * nn + k] = ni[(k % nn, k / nn)];
            }
        }
        let nv = hz * nu;
        let eye = Mat::<f64>::identity(nv, nv);
        let solver = BoxQp::new(eye.as_ref(), &lo, &hi, cfg.max_iterations, cfg.time_limit)?;
        Ok(BilinearMpc {
            model: handle,
            opts,
            cfg: cfg.clone(),
            nx,
            nu,
            nn,
            hz,
            a,
            b,
            n,
            qbar,
            rbar,
            lo,
            hi,
            solver,
            plan: None,
            offset: None,
            r: vec![0.0; hz * nx],
            zbar: vec![0.0; (hz + 1) * nn],
            at: vec![0.0; hz * nn * nn],
            bt: vec![0.0; hz * nn * nu],
            s: vec![0.0; nn * nu],
            s2: vec![0.0; nn * nu],
            gamma: Mat::zeros(hz * nx, nv),
            wq: Mat::zeros(hz * nx, nv),
            hess: Mat::zeros(nv, nv),
            xfree: vec![0.0; hz * nx],
            q: vec![0.0; nv],
        })
    }

    /// State dimension nx.
    pub fn nx(&self) -> usize {
        self.nx
    }

    /// Input dimension nu.
    pub fn nu(&self) -> usize {
        self.nu
    }

    /// Horizon H.
    pub fn horizon(&self) -> usize {
        self.hz
    }

    /// Forgets the warm start and the offset-free estimate (e.g. at the start of an episode).
    pub fn reset(&mut self) {
        self.plan = None;
        if let Some(o) = &mut self.offset {
            o.reset();
        }
    }

    /// Switches the offset-free correction on (`Some`) or off (`None`).
    ///
    /// Errors: settings that do not fit the model's state (see [`OffsetFreeConfig::check`]).
    pub fn set_offset_free(&mut self, cfg: Option<OffsetFreeConfig>) -> Result<()> {
        let (nx, hz) = (self.nx, self.hz);
        self.offset = cfg.map(|c| OffsetFree::new(c, nx, hz)).transpose()?;
        Ok(())
    }

    /// The offset-free correction, if on.
    pub fn offset_free(&self) -> Option<&OffsetFree> {
        self.offset.as_ref()
    }

    /// Updates the offset-free correction (if on) from the measured state `x` and the current
    /// reference `r` (nx values each): the next [`BilinearMpc::solve`] plans with it, and
    /// [`BilinearMpc::record`] must then be told the input applied.
    ///
    /// Errors: wrong lengths or non-finite values.
    pub fn observe(&mut self, x: &[f64], r: &[f64]) -> Result<()> {
        let model = self.model.get();
        if let Some(o) = &mut self.offset {
            o.update(x, r, |start, inputs| {
                // The state after inputs.len() / nu steps of the bilinear model from `start`.
                let Ok(mut z) = model.try_lift(start) else {
                    return Vec::new();
                };
                let mut next = vec![0.0; z.len()];
                for u in inputs.chunks_exact(model.nu()) {
                    model.step(&z, u, &mut next);
                    std::mem::swap(&mut z, &mut next);
                }
                z.truncate(model.nx());
                z
            })?;
        }
        Ok(())
    }

    /// Records the input `u` applied at state `x` (for the offset-free disturbance estimate).
    pub fn record(&mut self, x: &[f64], u: &[f64]) {
        if let Some(o) = &mut self.offset {
            o.record(x, u);
        }
    }

    /// Plans from state `x` towards `reference` (nx values held, or the stacked H·nx values of
    /// `x_1..x_H`).
    ///
    /// Errors: wrong lengths or non-finite state/reference; a QP failure is an error only when
    /// `cfg.fallback` is off.
    pub fn solve(&mut self, x: &[f64], reference: &[f64]) -> Result<BilinearSolution> {
        let start = Instant::now();
        let z0 = self.model.get().try_lift(x)?;
        ensure_finite("lifted state", &z0)?;
        self.set_reference(reference)?;
        let mut ubar = self.shifted_plan();
        let mut best = ubar.clone();
        let mut best_cost = self.rollout(&z0, &ubar);
        let (mut its, mut lins) = (0, 0);
        let mut status = ScpStatus::NotConverged;
        while lins < self.opts.max_linearisations {
            let mut u = ubar.clone();
            // A rollout that overflowed gives a non-finite QP: never handed to the solver.
            let out = if self.build_qp(&ubar) {
                self.solver.solve(&self.q, &[], &mut u)
            } else {
                QpOutcome {
                    status: QpStatus::Numerical,
                    iterations: 0,
                    feasible_iterate: false,
                }
            };
            lins += 1;
            its += out.iterations;
            let usable = u.iter().all(|v| v.is_finite())
                && match out.status {
                    QpStatus::Solved | QpStatus::Inaccurate => true,
                    QpStatus::MaxIterations | QpStatus::TimeLimit => out.feasible_iterate,
                    _ => false,
                };
            if !usable {
                if lins == 1 {
                    let reason = match out.status {
                        QpStatus::MaxIterations => FallbackReason::MaxIterations,
                        QpStatus::TimeLimit => FallbackReason::TimeLimit,
                        QpStatus::Infeasible => FallbackReason::Infeasible,
                        _ => FallbackReason::Numerical,
                    };
                    if !self.cfg.fallback {
                        return Err(Error::Numerical(format!(
                            "bilinear MPC: the QP solver failed ({reason:?}) and fallback is off"
                        )));
                    }
                    status = ScpStatus::Fallback(reason);
                }
                break;
            }
            let scale = 1.0 + ubar.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let moved = u
                .iter()
                .zip(&ubar)
                .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
            let cost = self.rollout(&z0, &u);
            ubar.copy_from_slice(&u);
            if moved <= self.opts.tol * scale {
                // The fixed point: take it even if rounding left its cost a hair higher.
                best.copy_from_slice(&u);
                best_cost = cost;
                status = ScpStatus::Converged;
                break;
            }
            if cost < best_cost || !best_cost.is_finite() {
                best.copy_from_slice(&u);
                best_cost = cost;
            }
        }
        self.plan = Some(best.clone());
        Ok(BilinearSolution {
            u: best,
            status,
            linearisations: lins,
            qp_iterations: its,
            cost: best_cost,
            solve_time: start.elapsed(),
        })
    }

    /// The QP `(H, q)` of one linearisation along the plan `ubar` from the lifted state `z0`
    /// towards `reference` (for checks against other solvers).
    pub fn linearised_qp(
        &mut self,
        z0: &[f64],
        ubar: &[f64],
        reference: &[f64],
    ) -> Result<(Mat<f64>, Vec<f64>)> {
        if z0.len() != self.nn {
            return Err(Error::dimension("lifted state", self.nn, z0.len()));
        }
        if ubar.len() != self.hz * self.nu {
            return Err(Error::dimension("plan", self.hz * self.nu, ubar.len()));
        }
        ensure_finite("lifted state", z0)?;
        ensure_finite("plan", ubar)?;
        self.set_reference(reference)?;
        self.rollout(z0, ubar);
        if !self.build_qp(ubar) {
            return Err(Error::NonFinite(
                "the linearised QP (the rollout overflowed)".into(),
            ));
        }
        Ok((self.hess.clone(), self.q.clone()))
    }

    /// The MPC cost of `u` on the bilinear model from `z0` (exact rollout) towards `reference`.
    pub fn cost(&mut self, z0: &[f64], u: &[f64], reference: &[f64]) -> Result<f64> {
        if z0.len() != self.nn || u.len() != self.hz * self.nu {
            return Err(Error::dimension("lifted state / plan", self.nn, z0.len()));
        }
        self.set_reference(reference)?;
        Ok(self.rollout(z0, u))
    }

    fn set_reference(&mut self, reference: &[f64]) -> Result<()> {
        expand_reference(&mut self.r, reference, self.nx, self.hz)?;
        if let Some(o) = &self.offset {
            o.shift_reference(&mut self.r);
        }
        Ok(())
    }

    fn shifted_plan(&self) -> Vec<f64> {
        let (nu, n) = (self.nu, self.hz * self.nu);
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

impl Policy for BilinearMpc<'_> {
    fn name(&self) -> String {
        match &self.offset {
            None => "bilinear-mpc".into(),
            Some(o) => match o.config().mode {
                super::offset_free::OffsetMode::Disturbance => "bilinear-mpc+disturbance".into(),
                super::offset_free::OffsetMode::Integral => "bilinear-mpc+integral".into(),
                super::offset_free::OffsetMode::Trajectory => "bilinear-mpc+trajectory".into(),
            },
        }
    }
    fn horizon(&self) -> usize {
        self.hz
    }
    fn act(&mut self, x: &[f64], current: &[f64], future: &[f64]) -> Result<Action> {
        let start = Instant::now();
        self.observe(x, current)?;
        let s = self.solve(x, future)?;
        let u = s.u[..self.nu].to_vec();
        self.record(x, &u);
        Ok(Action {
            u,
            solve_time: start.elapsed(),
            fallback: matches!(s.status, ScpStatus::Fallback(_)),
        })
    }
}
