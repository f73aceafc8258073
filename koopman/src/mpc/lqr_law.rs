//! The MPC service's LQR law (`MpcConfig::law = lqr`): the infinite-horizon LQR gain of a lifted
//! model under the MPC's Q and R, applied about a plan — `u = u_ff,k − K (Φ(x_k) − Φ(r_k))` — or
//! about a reference window with [`Lqr`]'s model-based feed-forward, clamped to the input bounds.

use std::sync::Arc;
use std::time::Instant;

use super::config::MpcConfig;
use super::lqr::Lqr;
use super::model_plan::{ModelPlan, PlanStatus};
use crate::error::{ensure_finite, Error, Result};
use crate::model::LiftedModel;

/// Riccati iterations the gain may take (a 1 kHz arm's lifted model needs thousands).
pub const LQR_MAX_ITERATIONS: usize = 20_000;
/// Relative change of the Riccati matrix (or of the gain) at which it has converged.
pub const LQR_TOLERANCE: f64 = 1e-10;

/// The LQR law of one lifted model: its gain, computed once, and the input bounds.
pub struct LqrLaw {
    lqr: Lqr,
    model: Arc<dyn LiftedModel>,
    u_min: Vec<f64>,
    u_max: Vec<f64>,
    horizon: usize,
}

impl LqrLaw {
    /// Computes the gain of `model` under `cfg`'s Q (default I on x) and R (default 0, then a
    /// `1e-9` multiple of `BᵀPB`'s largest diagonal entry); the plans it returns have
    /// `cfg.horizon` inputs. Errors: weights of the wrong length, a Riccati iteration that does
    /// not converge in [`LQR_MAX_ITERATIONS`] (the model's (A, B) not stabilisable under them).
    pub fn new(model: Arc<dyn LiftedModel>, cfg: &MpcConfig) -> Result<Self> {
        let (nx, nu) = (model.nx(), model.nu());
        let q = cfg.q.clone().unwrap_or_else(|| vec![1.0; nx]);
        let r = cfg.r.clone().unwrap_or_else(|| vec![0.0; nu]);
        let lqr = Lqr::new(model.as_ref(), &q, &r, LQR_MAX_ITERATIONS, LQR_TOLERANCE)?;
        if !lqr.converged {
            return Err(Error::Numerical(format!(
                "LQR law: the Riccati iteration did not converge in {LQR_MAX_ITERATIONS} \
                 iterations (is the model's (A, B) stabilisable under these Q and R?)"
            )));
        }
        let bound = |b: &Option<Vec<f64>>, inf: f64| b.clone().unwrap_or_else(|| vec![inf; nu]);
        Ok(LqrLaw {
            lqr,
            u_min: bound(&cfg.u_min, f64::NEG_INFINITY),
            u_max: bound(&cfg.u_max, f64::INFINITY),
            model,
            horizon: cfg.horizon.max(1),
        })
    }

    /// The model it controls.
    pub fn model(&self) -> &dyn LiftedModel {
        self.model.as_ref()
    }

    /// Planned inputs (H·nu values).
    pub fn horizon(&self) -> usize {
        self.horizon
    }

    /// About the reference window `reference` (nx values held, or the stacked H·nx): LQR's
    /// `u_ff − K(Φ(x) − Φ(r_1))` with `u_ff = pinv(B)(Φ(r_2) − AΦ(r_1))`, held over the horizon.
    pub fn solve(&self, x: &[f64], reference: &[f64]) -> Result<ModelPlan> {
        let nx = self.model.nx();
        if reference.len() != nx && reference.len() != self.horizon * nx {
            return Err(Error::dimension(
                "reference (nx or horizon·nx)",
                self.horizon * nx,
                reference.len(),
            ));
        }
        self.check(x, reference)?;
        let t = Instant::now();
        let r1 = &reference[..nx];
        let r2 = reference.get(nx..2 * nx).unwrap_or(r1);
        let u = self.lqr.control(
            &self.model.lift(x),
            &self.model.lift(r1),
            &self.model.lift(r2),
        )?;
        Ok(self.plan(self.clamped(u).repeat(self.horizon), t))
    }

    /// About the plan whose state at this step is `reference` (nx values) with feed-forward
    /// `feedforward` (H·nu values): `u = u_ff,0 − K(Φ(x) − Φ(r))`; the plan's further inputs are
    /// the feed-forward's.
    pub fn solve_about_plan(
        &self,
        x: &[f64],
        reference: &[f64],
        feedforward: &[f64],
    ) -> Result<ModelPlan> {
        let (nx, nu) = (self.model.nx(), self.model.nu());
        if reference.len() != nx {
            return Err(Error::dimension("plan state", nx, reference.len()));
        }
        if feedforward.len() != self.horizon * nu {
            return Err(Error::dimension(
                "feed-forward",
                self.horizon * nu,
                feedforward.len(),
            ));
        }
        self.check(x, reference)?;
        ensure_finite("feed-forward", feedforward)?;
        let t = Instant::now();
        let (z, zr) = (self.model.lift(x), self.model.lift(reference));
        let k = &self.lqr.k;
        let u: Vec<f64> = (0..nu)
            .map(|i| {
                feedforward[i]
                    - (0..z.len())
                        .map(|j| k[(i, j)] * (z[j] - zr[j]))
                        .sum::<f64>()
            })
            .collect();
        let mut plan = self.clamped(u);
        plan.extend(
            feedforward[nu..]
                .chunks(nu)
                .flat_map(|f| self.clamped(f.to_vec())),
        );
        Ok(self.plan(plan, t))
    }

    fn check(&self, x: &[f64], reference: &[f64]) -> Result<()> {
        if x.len() != self.model.nx() {
            return Err(Error::dimension("state", self.model.nx(), x.len()));
        }
        ensure_finite("state", x)?;
        ensure_finite("reference", reference)
    }

    fn clamped(&self, mut u: Vec<f64>) -> Vec<f64> {
        for (i, v) in u.iter_mut().enumerate() {
            *v = v.clamp(self.u_min[i], self.u_max[i]);
        }
        u
    }

    fn plan(&self, u: Vec<f64>, t: Instant) -> ModelPlan {
        ModelPlan {
            u,
            status: PlanStatus::Solved,
            iterations: 0,
            solve_time: t.elapsed(),
        }
    }
}
