//! The error-state (deviation) MPC of [`MpcController::solve_about_plan`]: the plan's rollout
//! as the reference and the input weights pulled towards the feed-forward, folded into the
//! dedicated solver's precomputed map.

use std::time::Instant;

use super::{Backend, MpcController, MpcSolution};
use crate::error::{ensure_finite, Error, Result};
use crate::linalg::kernels::gemv_simd;
use crate::mpc::condensed::Condensed;
use crate::mpc::config::MpcConfig;
use crate::mpc::offset_free::OffsetMode;

impl MpcController<'_> {
    /// Error-state (deviation) tracking of a planned trajectory: plans the deviation
    /// `δu = u − u_ff` from the feed-forward `feedforward` (H·nu values, the plan's inputs at
    /// steps k..k+H−1) so that the lifted deviation `δz = Φ(x) − ž` from the model's own rollout
    /// `ž_0 = Φ(reference_now)`, `ž_{τ+1} = A ž_τ + B u_ff,τ` is driven to zero: the cost is
    /// `Σ ‖P δz_{τ+1}‖²_Q + δu_τᵀ R δu_τ` (the Tikhonov term also acts on `δu`), the input bounds
    /// stay on `u`. Whatever the model gets wrong along the plan appears in `ž` as well and
    /// cancels, so a biased model tracks with the feed-forward's accuracy while its feedback
    /// still corrects deviations. `reference_now` is the planned state at the current step k
    /// (nx values). Returns the absolute inputs `u`.
    ///
    /// With the offset-free correction [`crate::mpc::OffsetMode::Disturbance`] on, each call
    /// first updates its estimate `d` from `x` ([`crate::mpc::OffsetFree::update_about_plan`]:
    /// the error of the model's one-step prediction of the deviation from the plan) and the
    /// predictions from `Φ(x)` carry `d` (`z_{τ+1} = A z_τ + B u_τ + E d`) while the plan's
    /// rollout does not: the plan is what the plant should do, `d` what it does differently.
    /// Consecutive calls are consecutive steps of one episode (call
    /// [`MpcController::set_offset_free`] again to start another).
    ///
    /// Errors: as [`MpcController::solve`]; a feed-forward of another length than H·nu
    /// (`InvalidArgument`) or with a non-finite value (`NonFinite`); an offset-free correction
    /// other than `disturbance`, or the terminal cost is the Riccati one (`InvalidArgument`).
    pub fn solve_about_plan(
        &mut self,
        x: &[f64],
        reference_now: &[f64],
        feedforward: &[f64],
    ) -> Result<MpcSolution> {
        let start = Instant::now();
        if self.condensed.terminal_map.is_some() {
            return Err(Error::InvalidArgument(
                "the error-state MPC (a feed-forward) does not take terminal_riccati".into(),
            ));
        }
        if let Some(o) = self
            .offset
            .as_ref()
            .filter(|o| o.config().mode != OffsetMode::Disturbance)
        {
            return Err(Error::InvalidArgument(format!(
                "the error-state MPC (a feed-forward) takes the offset-free correction \
                 `disturbance` only, got {:?}",
                o.config().mode
            )));
        }
        let (nx, n) = (self.nx(), self.condensed.n_vars());
        for (what, v) in [("state", x), ("reference state", reference_now)] {
            if v.len() != nx {
                return Err(Error::dimension(what, nx, v.len()));
            }
            ensure_finite(what, v)?;
        }
        if feedforward.len() != n {
            return Err(Error::InvalidArgument(format!(
                "feed-forward has {} values; expected H·nu = {n}",
                feedforward.len()
            )));
        }
        ensure_finite("feed-forward", feedforward)?;
        let model = self.model.get();
        let (z0, z_plan) = (model.lift(x), model.lift(reference_now));
        self.check_lifted(&z0)?;
        self.check_lifted(&z_plan)?;
        if self.offset.is_some() {
            // The plan's rollout as the reference; `set_reference` moves it by −S d.
            self.observe_about_plan(x, reference_now)?;
            let rollout = self.condensed.predict(&z_plan, feedforward);
            let s = self.solve_lifted_from(start, &z0, &rollout, Some(feedforward))?;
            let nu = self.nu();
            self.record_about_plan(x, &s.u[..nu], reference_now, &feedforward[..nu]);
            return Ok(s);
        }
        if matches!(self.solver, Backend::Dedicated { .. }) {
            self.ustar_about_plan(&z0, &z_plan, feedforward);
            return self.solve_qp(start, &z0);
        }
        // P ž_1..H: tracking it from Φ(x) is the error-state cost up to the input weights.
        let rollout = self.condensed.predict(&z_plan, feedforward);
        self.solve_lifted_from(start, &z0, &rollout, Some(feedforward))
    }

    /// The dedicated solver's `u*` of the error-state problem, `G₁z_0 + G_plan [ž_0; u_ff]`:
    /// the same as forming the rollout `Φž_0 + Γu_ff` as the reference and pulling the input
    /// weights towards `u_ff`, in two products (`G_plan` is built at the first call).
    fn ustar_about_plan(&mut self, z0: &[f64], z_plan: &[f64], u_ff: &[f64]) {
        let (latent, n) = (self.condensed.latent, self.condensed.n_vars());
        let Backend::Dedicated { qp, g, g_plan } = &mut self.solver else {
            unreachable!("called for the dedicated solver only")
        };
        let g_plan = g_plan.get_or_insert_with(|| {
            let d: Vec<f64> = (0..n)
                .map(|i| input_weight(&self.cfg, &self.condensed, i))
                .collect();
            plan_map(&self.condensed, g, qp.hessian_inverse(), &d)
        });
        self.plan_in.clear();
        self.plan_in.extend_from_slice(z_plan);
        self.plan_in.extend_from_slice(u_ff);
        self.ustar.fill(0.0);
        gemv_simd(&g[..n * latent], z0, &mut self.ustar);
        gemv_simd(g_plan, &self.plan_in, &mut self.ustar);
        // What `linear_term` needs: z_0 now, the rollout on demand, the pull.
        self.zr[..latent].copy_from_slice(z0);
        self.rollout_pending = true;
        self.set_pull(u_ff);
        self.q_current = false;
    }

    /// Moves the input weights (R and the Tikhonov term, `d = diag(R̄ + δI)`) from `u` onto
    /// `u − u_ff`: the linear term gains `−d ⊙ u_ff`, so `u* = −H⁻¹q` gains `H⁻¹ (d ⊙ u_ff)`.
    pub(super) fn weigh_deviation_from(&mut self, u_ff: &[f64]) {
        self.set_pull(u_ff);
        match &self.solver {
            Backend::Dedicated { qp, .. } => {
                gemv_simd(qp.hessian_inverse(), &self.pull, &mut self.ustar)
            }
            Backend::Other(_) => self.q.iter_mut().zip(&self.pull).for_each(|(q, p)| *q -= p),
        }
    }

    /// Records the input weights' pull towards the feed-forward, `d ⊙ u_ff`, in place.
    fn set_pull(&mut self, u_ff: &[f64]) {
        let (cfg, condensed) = (&self.cfg, &self.condensed);
        self.pull.clear();
        self.pull.extend(
            u_ff.iter()
                .enumerate()
                .map(|(i, u)| input_weight(cfg, condensed, i) * u),
        );
    }
}

/// `d_i = (R̄ + δI)_ii`: the input weight of planned input `i` (of H·nu), R cycling over the
/// horizon.
fn input_weight(cfg: &MpcConfig, c: &Condensed, i: usize) -> f64 {
    cfg.r.as_deref().map_or(0.0, |r| r[i % c.nu]) + c.tikhonov
}

/// `G_plan = [G₂Φ  G₂Γ + H⁻¹D]` (column-major, n × (N + n)) from `G = [G₁ G₂]` (column-major,
/// n × (N + H·nx)), H⁻¹ (column-major) and `d = diag(D)`.
fn plan_map(c: &Condensed, g: &[f64], hinv: &[f64], d: &[f64]) -> Vec<f64> {
    let (n, latent, hx) = (c.n_vars(), c.latent, c.horizon * c.nx);
    let g2 = faer::MatRef::from_column_major_slice(&g[n * latent..], n, hx);
    let hinv = faer::MatRef::from_column_major_slice(hinv, n, n);
    let left = g2 * &c.phi;
    let right = g2 * &c.gamma;
    let mut out = Vec::with_capacity(n * (latent + n));
    for j in 0..latent {
        out.extend((0..n).map(|i| left[(i, j)]));
    }
    for j in 0..n {
        out.extend((0..n).map(|i| right[(i, j)] + hinv[(i, j)] * d[j]));
    }
    out
}
