//! What `koopbridge control` checks before it runs a closed loop: can the target be held within
//! the input bounds at all, and does the model's input gain agree with the true system's there.

use koopman::analysis::{
    gain_agreement, holding_input, model_input_gain, system_input_gain, GainAgreement, HoldingInput,
};
use koopman::model::bilinear::{BilinearModel, Linearised};
use koopman::model::LiftedModel;
use koopman::systems::System;
use serde::Serialize;

use koopman::analysis::gain::WEAK_AUTHORITY;

/// The pre-flight checks of one control task (written as `diagnostics.json`).
#[derive(Debug, Serialize)]
pub struct ControlDiagnostics {
    /// The state the task ends at (regulation target, or the last tracking reference).
    pub target: Vec<f64>,
    /// The constant input that holds the target and whether the bounds allow it.
    pub holding: Option<HoldingInput>,
    /// The model's input gains over the horizon against the true system's at the target.
    pub authority: Option<GainAgreement>,
    /// Plain-language warnings (also printed).
    pub warnings: Vec<String>,
}

/// Runs the checks; failures of the checks themselves become warnings, never errors. `hold`
/// says whether the task must hold `target` (regulation) or only pass near it (tracking: the
/// holding check is skipped and the gains are compared at `target` with zero nominal input).
pub fn diagnose(
    system: &dyn System,
    model: Option<&dyn LiftedModel>,
    target: &[f64],
    hold: bool,
    bounds: (&[f64], &[f64]),
    horizon: usize,
) -> ControlDiagnostics {
    let (u_min, u_max) = bounds;
    let mut warnings = Vec::new();
    let holding = match hold.then(|| holding_input(system, target, u_min, u_max)) {
        None => None,
        Some(Ok(h)) => {
            if h.residual > 1e-6 {
                warnings.push(format!(
                    "the target {target:?} is not an equilibrium of {} for any constant input \
                     (residual {:.2e} per step): it can be passed through, not held",
                    system.name(),
                    h.residual
                ));
            } else if !h.within_bounds {
                warnings.push(format!(
                    "holding the target {target:?} needs u = {} — {:.1}× the input bounds \
                     [{}, {}]: no controller can hold it",
                    fmt_vec(&h.u),
                    h.bound_ratio,
                    fmt_vec(u_min),
                    fmt_vec(u_max)
                ));
            }
            Some(h)
        }
        Some(Err(e)) => {
            warnings.push(format!("could not compute the holding input: {e}"));
            None
        }
    };
    let authority = model.and_then(|m| {
        let nominal = holding
            .as_ref()
            .map(|h| clamp(&h.u, u_min, u_max))
            .unwrap_or_else(|| vec![0.0; system.nu()]);
        let truth = system_input_gain(system, target, &nominal, horizon, 1e-4);
        match truth.and_then(|t| gain_agreement(&model_input_gain(m, horizon), &t)) {
            Ok(a) => {
                if a.projection < WEAK_AUTHORITY {
                    warnings.push(format!(
                        "the model's input gain P·A^k·B over {horizon} steps is {:.2}× the true \
                         system's at the target along it (cosine {:.2}, norm ratio {:.2}): an MPC \
                         on this model has little or the wrong authority there. A linear-input \
                         model learns one gain for the whole data; if the true gain changes sign \
                         across the data (the damped pendulum's cos θ·u), collect data where the \
                         task happens",
                        a.projection, a.cosine, a.norm_ratio
                    ));
                }
                Some(a)
            }
            Err(e) => {
                warnings.push(format!("could not compare input gains: {e}"));
                None
            }
        }
    });
    ControlDiagnostics {
        target: target.to_vec(),
        holding,
        authority,
        warnings,
    }
}

impl ControlDiagnostics {
    /// Prints the figures and the warnings to stderr.
    pub fn print(&self) {
        if let Some(h) = &self.holding {
            eprintln!(
                "target {}: holding input {} ({})",
                fmt_vec(&self.target),
                fmt_vec(&h.u),
                if h.within_bounds {
                    "within bounds"
                } else {
                    "outside the bounds"
                }
            );
        }
        if let Some(a) = &self.authority {
            eprintln!(
                "control authority: model gain / true gain at the target = {:.3} (cosine {:.3}, \
                 norm ratio {:.3}; 1 = exact, 0 = none, < 0 = opposite)",
                a.projection, a.cosine, a.norm_ratio
            );
        }
        for w in &self.warnings {
            eprintln!("warning: {w}");
        }
    }
}

/// The bilinear model linearised at the target and the input that holds it (zero when the
/// target cannot be held), for the authority diagnostic.
pub fn linearised_at<'m>(
    system: &dyn System,
    model: &'m BilinearModel,
    target: &[f64],
    lo: &[f64],
    hi: &[f64],
) -> anyhow::Result<Linearised<'m>> {
    let u = koopman::analysis::holding_input(system, target, lo, hi)
        .map(|h| clamp(&h.u, lo, hi))
        .unwrap_or_else(|_| vec![0.0; system.nu()]);
    Ok(model.linearised(&model.try_lift(target)?, &u)?)
}

fn clamp(u: &[f64], lo: &[f64], hi: &[f64]) -> Vec<f64> {
    u.iter()
        .zip(lo.iter().zip(hi))
        .map(|(&v, (&l, &h))| v.clamp(l, h))
        .collect()
}

fn fmt_vec(v: &[f64]) -> String {
    let parts: Vec<String> = v.iter().map(|x| format!("{x:.3}")).collect();
    format!("[{}]", parts.join(", "))
}
