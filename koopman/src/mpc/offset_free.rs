//! Offset-free correction of the bilinear MPC near its target: a constant disturbance estimate
//! or integral action, switched on only within a radius of the reference.
//!
//! A model trained over a whole state region is biased somewhere; near the target a bias leaves a
//! steady offset (the MPC believes its input holds the target, the plant settles beside it).
//! Far from the target the bias changes with the state, so a correction estimated there is
//! wrong, which is why it is switched on only while `‖x − r‖ ≤ radius` (angles wrapped) and
//! reset to zero whenever the state leaves that ball.
//!
//! - [`OffsetMode::Disturbance`]: the standard offset-free MPC estimate (Muske & Badgwell 2002;
//!   Pannocchia & Rawlings 2003) of a constant disturbance `d` added to the state part of every
//!   predicted step, `z_{τ+1} = f(z_τ, u_τ) + [d; 0]`, low-pass filtered from the one-step
//!   prediction error: `d ← (1 − α) d + α (x_k − P f(Φ(x_{k−1}), u_{k−1}))`. Exact for a plant
//!   that is the model plus a constant state disturbance.
//! - [`OffsetMode::Integral`]: integral action on the tracking error, `ξ ← ξ + k ⊙ (x_k − r_k)`,
//!   and the MPC plans towards `r − ξ` (|ξ_i| ≤ radius, anti-windup). Any closed-loop
//!   equilibrium with the correction on has `x_i = r_i` for every component with `k_i > 0`,
//!   whatever the model's bias there.

use serde::{Deserialize, Serialize};

use super::metrics::wrapped_error;
use crate::error::{ensure_finite, Error, Result};

/// Which correction [`OffsetFree`] applies.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum OffsetMode {
    /// A constant state disturbance in the prediction model, estimated from the one-step
    /// prediction error with a low-pass filter (`gain` = the filter constant α ∈ [0, 1]).
    Disturbance,
    /// Integral action: the reference is shifted by the integrated error (`gain` = k ≥ 0 per step).
    Integral,
}

/// Settings of the offset-free correction.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OffsetFreeConfig {
    /// The correction.
    pub mode: OffsetMode,
    /// On while the wrapped error `‖x − r‖₂` is at most this (> 0; may be ∞).
    pub radius: f64,
    /// Per state component (nx values): α_i ∈ [0, 1] for [`OffsetMode::Disturbance`], k_i ≥ 0
    /// for [`OffsetMode::Integral`]; 0 leaves the component uncorrected.
    pub gain: Vec<f64>,
    /// State components that are angles (wrapped to (−π, π] in every error).
    #[serde(default)]
    pub angles: Vec<usize>,
}

impl OffsetFreeConfig {
    /// Checks the settings against the state dimension.
    pub fn check(&self, nx: usize) -> Result<()> {
        if self.gain.len() != nx {
            return Err(Error::dimension("offset-free gains", nx, self.gain.len()));
        }
        if self.radius.is_nan() || self.radius <= 0.0 {
            return Err(Error::InvalidArgument(format!(
                "the offset-free radius must be > 0, got {}",
                self.radius
            )));
        }
        let max = match self.mode {
            OffsetMode::Disturbance => 1.0,
            OffsetMode::Integral => f64::INFINITY,
        };
        if self
            .gain
            .iter()
            .any(|g| !(g.is_finite() && *g >= 0.0 && *g <= max))
        {
            return Err(Error::InvalidArgument(format!(
                "offset-free gains must be finite and in [0, {max}] for {:?}, got {:?}",
                self.mode, self.gain
            )));
        }
        if let Some(&i) = self.angles.iter().find(|&&i| i >= nx) {
            return Err(Error::InvalidArgument(format!(
                "offset-free angle index {i} is not a state component (nx = {nx})"
            )));
        }
        Ok(())
    }
}

/// The correction's running state: the estimate, whether it is on, and the last decision (for
/// the one-step prediction error).
#[derive(Clone, Debug, PartialEq)]
pub struct OffsetFree {
    cfg: OffsetFreeConfig,
    estimate: Vec<f64>,
    active: bool,
    last: Option<(Vec<f64>, Vec<f64>)>,
}

impl OffsetFree {
    /// A correction for states of dimension `nx` (errors: see [`OffsetFreeConfig::check`]).
    pub fn new(cfg: OffsetFreeConfig, nx: usize) -> Result<Self> {
        cfg.check(nx)?;
        Ok(OffsetFree {
            estimate: vec![0.0; nx],
            cfg,
            active: false,
            last: None,
        })
    }

    /// The settings.
    pub fn config(&self) -> &OffsetFreeConfig {
        &self.cfg
    }

    /// The current estimate (`d` or `ξ`, nx values; zero while off).
    pub fn estimate(&self) -> &[f64] {
        &self.estimate
    }

    /// True if the state was within the radius at the last [`OffsetFree::update`].
    pub fn active(&self) -> bool {
        self.active
    }

    /// Forgets the estimate and the last decision (e.g. at the start of an episode).
    pub fn reset(&mut self) {
        self.estimate.fill(0.0);
        self.active = false;
        self.last = None;
    }

    /// Updates the estimate from the measured state `x` and the current reference `r`;
    /// `predict(x_prev, u_prev)` is the model's one-step prediction of the state (used by
    /// [`OffsetMode::Disturbance`]). Outside the radius the estimate is reset to zero.
    ///
    /// Errors: wrong lengths or non-finite values (the estimate is left unchanged).
    pub fn update(
        &mut self,
        x: &[f64],
        r: &[f64],
        predict: impl FnOnce(&[f64], &[f64]) -> Vec<f64>,
    ) -> Result<()> {
        let nx = self.estimate.len();
        if x.len() != nx || r.len() != nx {
            return Err(Error::dimension(
                "offset-free state / reference",
                nx,
                x.len(),
            ));
        }
        ensure_finite("state", x)?;
        ensure_finite("reference", r)?;
        let err = wrapped_error(x, r, &self.cfg.angles);
        let dist = err.iter().map(|e| e * e).sum::<f64>().sqrt();
        if dist > self.cfg.radius {
            self.estimate.fill(0.0);
            self.active = false;
            return Ok(());
        }
        match self.cfg.mode {
            OffsetMode::Disturbance => {
                if let (true, Some((xp, up))) = (self.active, &self.last) {
                    let pred = predict(xp, up);
                    if pred.len() == nx && pred.iter().all(|v| v.is_finite()) {
                        let innov = wrapped_error(x, &pred, &self.cfg.angles);
                        for ((d, g), e) in self.estimate.iter_mut().zip(&self.cfg.gain).zip(innov) {
                            *d = (1.0 - g) * *d + g * e;
                        }
                    }
                }
            }
            OffsetMode::Integral => {
                let cap = self.cfg.radius;
                for ((s, g), e) in self.estimate.iter_mut().zip(&self.cfg.gain).zip(err) {
                    *s = (*s + g * e).clamp(-cap, cap);
                }
            }
        }
        self.active = true;
        Ok(())
    }

    /// Records the decision taken at `x` (its first input `u`), for the next one-step error.
    pub fn record(&mut self, x: &[f64], u: &[f64]) {
        self.last = Some((x.to_vec(), u.to_vec()));
    }

    /// The state disturbance to add to every predicted step (zero unless
    /// [`OffsetMode::Disturbance`] is on).
    pub fn disturbance(&self) -> Option<&[f64]> {
        (self.cfg.mode == OffsetMode::Disturbance && self.active).then_some(&self.estimate[..])
    }

    /// Shifts the stacked reference (`H·nx` or `nx` values) by `−ξ` when
    /// [`OffsetMode::Integral`] is on.
    pub fn shift_reference(&self, reference: &mut [f64]) {
        if self.cfg.mode == OffsetMode::Integral && self.active {
            let nx = self.estimate.len();
            for (k, v) in reference.iter_mut().enumerate() {
                *v -= self.estimate[k % nx];
            }
        }
    }
}
