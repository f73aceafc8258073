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
//! - [`OffsetMode::Trajectory`]: a correction per horizon step, the filtered error of the
//!   model's τ-step prediction, `e_τ ← (1 − α) e_τ + α (x_k − x̂_{k|k−τ})`, where `x̂_{k|k−τ}` is
//!   the model rolled out from the state measured τ steps ago with the inputs applied since
//!   (τ = 1..H); the MPC then sees `x̂_τ + e_τ` (its reference shifted by `−e_τ`). A model whose
//!   error is not a constant per-step drift (a learnt lifting's first step "snaps" by a nearly
//!   state-independent amount that later steps undo) is corrected where the constant
//!   disturbance over-corrects it: at a closed-loop equilibrium every τ-step prediction of the
//!   held plan is exact, so only the model's input sensitivity, not its bias, shapes the plan.

use std::collections::VecDeque;

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
    /// The filtered error of each τ-step prediction (τ = 1..H) added to the prediction of
    /// horizon step τ (`gain` = the filter constant α ∈ [0, 1]).
    Trajectory,
}

/// Settings of the offset-free correction.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OffsetFreeConfig {
    /// The correction.
    pub mode: OffsetMode,
    /// On while the wrapped error `‖x − r‖₂` is at most this (> 0; may be ∞).
    pub radius: f64,
    /// Per state component (nx values): α_i ∈ [0, 1] for [`OffsetMode::Disturbance`] and
    /// [`OffsetMode::Trajectory`], k_i ≥ 0 for [`OffsetMode::Integral`]; 0 leaves the component
    /// uncorrected.
    pub gain: Vec<f64>,
    /// State components that are angles (wrapped to (−π, π] in every error).
    #[serde(default)]
    pub angles: Vec<usize>,
}

impl OffsetFreeConfig {
    /// The settings that worked on the damped pendulum for `mode` (see docs/log/2026-12.md,
    /// "Session 6"): integral and disturbance: radius 0.3, gain 0.1 on the angles and 0 elsewhere;
    /// trajectory: radius 1.0, α = 0.5 on every component.
    pub fn defaults(mode: OffsetMode, nx: usize, angles: Vec<usize>) -> Self {
        let (radius, gain) = match mode {
            OffsetMode::Trajectory => (1.0, vec![0.5; nx]),
            OffsetMode::Integral | OffsetMode::Disturbance => (
                0.3,
                (0..nx)
                    .map(|i| if angles.contains(&i) { 0.1 } else { 0.0 })
                    .collect(),
            ),
        };
        OffsetFreeConfig {
            mode,
            radius,
            gain,
            angles,
        }
    }

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
            OffsetMode::Disturbance | OffsetMode::Trajectory => 1.0,
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

/// The correction's running state: the estimate, whether it is on, and the last decisions (for
/// the prediction errors).
#[derive(Clone, Debug, PartialEq)]
pub struct OffsetFree {
    cfg: OffsetFreeConfig,
    horizon: usize,
    /// `d` or `ξ` (nx values); for [`OffsetMode::Trajectory`] `e_1..e_H` (H·nx values).
    estimate: Vec<f64>,
    active: bool,
    /// The last decisions `(x, u)`, newest first: one kept, or H for [`OffsetMode::Trajectory`].
    history: VecDeque<(Vec<f64>, Vec<f64>)>,
    /// About a plan ([`OffsetFree::record_about_plan`]): the plan's state and first
    /// feed-forward input at the last decision.
    plan_prev: Option<(Vec<f64>, Vec<f64>)>,
}

impl OffsetFree {
    /// A correction for states of dimension `nx` and an MPC of horizon `horizon` (errors: see
    /// [`OffsetFreeConfig::check`]; a zero horizon).
    pub fn new(cfg: OffsetFreeConfig, nx: usize, horizon: usize) -> Result<Self> {
        cfg.check(nx)?;
        if horizon == 0 {
            return Err(Error::InvalidArgument(
                "the offset-free correction needs a horizon of at least 1".into(),
            ));
        }
        let len = match cfg.mode {
            OffsetMode::Trajectory => horizon * nx,
            _ => nx,
        };
        Ok(OffsetFree {
            estimate: vec![0.0; len],
            cfg,
            horizon,
            active: false,
            history: VecDeque::new(),
            plan_prev: None,
        })
    }

    /// The settings.
    pub fn config(&self) -> &OffsetFreeConfig {
        &self.cfg
    }

    /// The current estimate (`d` or `ξ`, nx values; `e_1..e_H`, H·nx values, for
    /// [`OffsetMode::Trajectory`]; zero while off).
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
        self.history.clear();
        self.plan_prev = None;
    }

    /// Updates the estimate from the measured state `x` and the current reference `r`;
    /// `predict(x_start, inputs)` is the model's prediction of the state after `inputs.len() / nu`
    /// steps from `x_start` (used by [`OffsetMode::Disturbance`], one step, and
    /// [`OffsetMode::Trajectory`], 1..H steps). Outside the radius the estimate is reset to zero.
    ///
    /// Errors: wrong lengths or non-finite values (the estimate is left unchanged).
    pub fn update(
        &mut self,
        x: &[f64],
        r: &[f64],
        predict: impl FnMut(&[f64], &[f64]) -> Vec<f64>,
    ) -> Result<()> {
        self.update_with(x, r, predict, false)
    }

    /// [`OffsetMode::Disturbance`] about a plan (the error-state MPC): updates `d` from the
    /// error of the model's one-step prediction of the *deviation* from the plan,
    /// `(x_k − P f(Φ(x_{k−1}), u_{k−1})) − (r_k − P f(Φ(r_{k−1}), u_ff,k−1))`, where `r` is the
    /// plan's state now and the previous decision and plan point are those of
    /// [`OffsetFree::record_about_plan`]. The model's own error along the plan — which the
    /// error-state MPC cancels already — drops out; what is left is what the plant does
    /// differently about the plan (a heavier body, another floor). Exact for a plant that is
    /// the model plus a constant state disturbance, along a plan the model reproduces.
    ///
    /// Errors: another mode (`InvalidArgument`); as [`OffsetFree::update`].
    pub fn update_about_plan(
        &mut self,
        x: &[f64],
        r: &[f64],
        predict: impl FnMut(&[f64], &[f64]) -> Vec<f64>,
    ) -> Result<()> {
        if self.cfg.mode != OffsetMode::Disturbance {
            return Err(Error::InvalidArgument(format!(
                "about a plan (the error-state MPC) the offset-free correction is `disturbance` \
                 only, got {:?}",
                self.cfg.mode
            )));
        }
        self.update_with(x, r, predict, true)
    }

    fn update_with(
        &mut self,
        x: &[f64],
        r: &[f64],
        mut predict: impl FnMut(&[f64], &[f64]) -> Vec<f64>,
        about_plan: bool,
    ) -> Result<()> {
        let nx = self.cfg.gain.len();
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
                if let Some(innov) = self.one_step_innovation(x, r, &mut predict, about_plan) {
                    for ((d, g), e) in self.estimate.iter_mut().zip(&self.cfg.gain).zip(innov) {
                        *d = (1.0 - g) * *d + g * e;
                    }
                }
            }
            OffsetMode::Integral => {
                let cap = self.cfg.radius;
                for ((s, g), e) in self.estimate.iter_mut().zip(&self.cfg.gain).zip(err) {
                    *s = (*s + g * e).clamp(-cap, cap);
                }
            }
            OffsetMode::Trajectory => {
                // Step τ: from the state τ decisions ago with the inputs applied since.
                let mut inputs: Vec<f64> = Vec::new();
                for (tau, (xs, us)) in self.history.iter().enumerate() {
                    inputs.splice(0..0, us.iter().copied());
                    let pred = predict(xs, &inputs);
                    if pred.len() != nx || !pred.iter().all(|v| v.is_finite()) {
                        continue;
                    }
                    let innov = wrapped_error(x, &pred, &self.cfg.angles);
                    let e = &mut self.estimate[tau * nx..(tau + 1) * nx];
                    for ((d, g), v) in e.iter_mut().zip(&self.cfg.gain).zip(innov) {
                        *d = (1.0 - g) * *d + g * v;
                    }
                }
            }
        }
        self.active = true;
        Ok(())
    }

    /// The error of the model's one-step prediction of `x` from the last decision (about a plan:
    /// less its error on the plan's step to `r`); `None` while off, without a last decision, or
    /// when a prediction is not finite.
    fn one_step_innovation(
        &self,
        x: &[f64],
        r: &[f64],
        predict: &mut impl FnMut(&[f64], &[f64]) -> Vec<f64>,
        about_plan: bool,
    ) -> Option<Vec<f64>> {
        if !self.active {
            return None;
        }
        let fits = |p: &Vec<f64>| p.len() == x.len() && p.iter().all(|v| v.is_finite());
        let (xp, up) = self.history.front()?;
        let pred = Some(predict(xp, up)).filter(fits)?;
        let mut innov = wrapped_error(x, &pred, &self.cfg.angles);
        if about_plan {
            let (rp, ufp) = self.plan_prev.as_ref()?;
            let along = Some(predict(rp, ufp)).filter(fits)?;
            let along = wrapped_error(r, &along, &self.cfg.angles);
            innov.iter_mut().zip(along).for_each(|(e, a)| *e -= a);
        }
        Some(innov)
    }

    /// Records the decision taken at `x` (its first input `u`) about the plan's state `r` with
    /// first feed-forward input `u_ff` ([`OffsetFree::update_about_plan`]).
    pub fn record_about_plan(&mut self, x: &[f64], u: &[f64], r: &[f64], u_ff: &[f64]) {
        self.record(x, u);
        self.plan_prev = Some((r.to_vec(), u_ff.to_vec()));
    }

    /// Records the decision taken at `x` (its first input `u`), for the next prediction errors.
    pub fn record(&mut self, x: &[f64], u: &[f64]) {
        let keep = match self.cfg.mode {
            OffsetMode::Trajectory => self.horizon,
            _ => 1,
        };
        if self.history.len() == keep {
            self.history.pop_back();
        }
        self.history.push_front((x.to_vec(), u.to_vec()));
    }

    /// The state disturbance to add to every predicted step (zero unless
    /// [`OffsetMode::Disturbance`] is on).
    pub fn disturbance(&self) -> Option<&[f64]> {
        (self.cfg.mode == OffsetMode::Disturbance && self.active).then_some(&self.estimate[..])
    }

    /// Shifts the stacked reference (`H·nx` values, or `nx` for [`OffsetMode::Integral`]) by
    /// `−ξ` when [`OffsetMode::Integral`] is on, by `−e_τ` at step τ when
    /// [`OffsetMode::Trajectory`] is.
    pub fn shift_reference(&self, reference: &mut [f64]) {
        if !self.active {
            return;
        }
        let n = self.estimate.len();
        match self.cfg.mode {
            OffsetMode::Integral => {
                for (k, v) in reference.iter_mut().enumerate() {
                    *v -= self.estimate[k % n];
                }
            }
            OffsetMode::Trajectory => {
                for (v, e) in reference.iter_mut().zip(&self.estimate) {
                    *v -= e;
                }
            }
            OffsetMode::Disturbance => {}
        }
    }
}
