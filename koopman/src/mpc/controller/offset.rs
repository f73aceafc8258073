//! The offset-free correction of the linear Koopman MPC: the bilinear MPC's estimates
//! ([`crate::mpc::offset_free`]: a constant state disturbance, integral action, or the filtered
//! τ-step prediction errors) on a lifted-linear model.
//!
//! On a linear model each correction is an offset of the predictions or of the reference, so
//! the condensed QP keeps its Hessian and only the reference moves: a constant disturbance `d`
//! added to the state part of every predicted step (`z_{τ+1} = A z_τ + B u_τ + E d`, `E = [I; 0]`)
//! moves the predicted `x_{τ+1}` by `S_τ d`, `S_τ = Σ_{j=0}^{τ} P A^j E`, which is the tracking
//! cost of the reference `r_τ − S_τ d`; the trajectory correction moves `x_{τ+1}` by `e_{τ+1}`;
//! integral action plans towards `r − ξ`. State bounds apply to the moved predictions.

use super::MpcController;
use crate::error::{Error, Result};
use crate::mpc::offset_free::{OffsetFree, OffsetFreeConfig, OffsetMode};

impl MpcController<'_> {
    /// Switches the offset-free correction on (`Some`) or off (`None`). While it is on, a closed
    /// loop calls [`MpcController::observe`] with each measured state before
    /// [`MpcController::solve`] and [`MpcController::record`] with the input applied after it
    /// (as [`crate::mpc::Policy::act`] does); the error-state MPC refuses it.
    ///
    /// Errors: settings that do not fit the model's state (see [`OffsetFreeConfig::check`]); a
    /// correction with `terminal_riccati` (`InvalidArgument`).
    pub fn set_offset_free(&mut self, cfg: Option<OffsetFreeConfig>) -> Result<()> {
        if cfg.is_some() && self.condensed.terminal_map.is_some() {
            return Err(Error::InvalidArgument(
                "the offset-free correction does not take terminal_riccati".into(),
            ));
        }
        let (nx, hz) = (self.nx(), self.horizon());
        self.offset = cfg.map(|c| OffsetFree::new(c, nx, hz)).transpose()?;
        self.pred_offset.clear();
        if self.disturbance_map.is_empty()
            && self
                .offset
                .as_ref()
                .is_some_and(|o| o.config().mode == OffsetMode::Disturbance)
        {
            // S_0 = I; S_τ = S_{τ−1} + P A^τ E, and P A^τ is row block τ−1 of Φ.
            let phi = &self.condensed.phi;
            let mut s = vec![0.0; hz * nx * nx];
            for tau in 0..hz {
                for i in 0..nx {
                    for k in 0..nx {
                        let row = tau * nx + i;
                        s[row * nx + k] = if tau == 0 {
                            f64::from(u8::from(i == k))
                        } else {
                            s[(row - nx) * nx + k] + phi[((tau - 1) * nx + i, k)]
                        };
                    }
                }
            }
            self.disturbance_map = s;
        }
        Ok(())
    }

    /// The offset-free correction, if on.
    pub fn offset_free(&self) -> Option<&OffsetFree> {
        self.offset.as_ref()
    }

    /// Updates the offset-free correction (if on) from the measured state `x` and the current
    /// reference `r` (nx values each); the τ-step predictions it needs are the model's own
    /// (`P(Φ(x_start) rolled out)`, from the condensed matrices).
    ///
    /// Errors: wrong lengths or non-finite values.
    pub fn observe(&mut self, x: &[f64], r: &[f64]) -> Result<()> {
        self.observe_with(x, r, false)
    }

    /// [`MpcController::observe`] about a plan whose state now is `r`
    /// ([`OffsetFree::update_about_plan`]; [`MpcController::solve_about_plan`] calls it).
    pub(super) fn observe_about_plan(&mut self, x: &[f64], r: &[f64]) -> Result<()> {
        self.observe_with(x, r, true)
    }

    fn observe_with(&mut self, x: &[f64], r: &[f64], about_plan: bool) -> Result<()> {
        let Some(o) = &mut self.offset else {
            return Ok(());
        };
        let (model, c) = (self.model.get(), &self.condensed);
        let (nx, nu, hz) = (c.nx, c.nu, c.horizon);
        let predict = |start: &[f64], inputs: &[f64]| {
            let k = inputs.len() / nu;
            let Ok(z) = model.try_lift(start) else {
                return Vec::new();
            };
            if k == 0 || k > hz || z.len() != c.latent {
                return Vec::new();
            }
            // x_k depends on u_0..u_{k−1} only: the rest of the horizon is padded with zeros.
            let mut u = inputs.to_vec();
            u.resize(hz * nu, 0.0);
            c.predict(&z, &u)[(k - 1) * nx..k * nx].to_vec()
        };
        if about_plan {
            o.update_about_plan(x, r, predict)
        } else {
            o.update(x, r, predict)
        }
    }

    /// Records the input `u` applied at state `x` (for the correction's prediction errors).
    pub fn record(&mut self, x: &[f64], u: &[f64]) {
        if let Some(o) = &mut self.offset {
            o.record(x, u);
        }
    }

    /// Records the input `u` applied at state `x` about the plan's state `r` with first
    /// feed-forward input `u_ff`.
    pub(super) fn record_about_plan(&mut self, x: &[f64], u: &[f64], r: &[f64], u_ff: &[f64]) {
        if let Some(o) = &mut self.offset {
            o.record_about_plan(x, u, r, u_ff);
        }
    }

    /// Moves the expanded reference of the next solve by the correction (and keeps the offset it
    /// adds to the predictions, for the state bounds).
    pub(super) fn shift_for_offset(&mut self) {
        self.pred_offset.clear();
        let Some(o) = &self.offset else {
            return;
        };
        let nx = self.condensed.nx;
        match o.config().mode {
            OffsetMode::Disturbance => {
                if let Some(d) = o.disturbance() {
                    self.pred_offset = self
                        .disturbance_map
                        .chunks_exact(nx)
                        .map(|row| row.iter().zip(d).map(|(s, d)| s * d).sum())
                        .collect();
                }
            }
            OffsetMode::Trajectory => {
                if o.active() {
                    self.pred_offset = o.estimate().to_vec();
                }
            }
            OffsetMode::Integral => o.shift_reference(&mut self.r),
        }
        for (r, p) in self.r.iter_mut().zip(&self.pred_offset) {
            *r -= p;
        }
    }
}
