//! The input authority at a control goal: the model's one-step input gain `∂x⁺/∂u` (through its
//! lift, `A`, `B` and the projection on the state: `koopman::analysis::model_input_gain`) against
//! the simulator's own, measured through its adapter by central differences (`reset(x0 = goal)`,
//! one `step` with `u0 ± δ` per input), compared as `koopbridge control`'s pre-flight check does
//! (`koopman::analysis::gain_agreement`).

use faer::Mat;
use koopman::analysis::{gain_agreement, model_input_gain, InputGain};
use serde::{Deserialize, Serialize};

use super::closed_loop::ControlReport;
use crate::client::SimClient;
use crate::error::{Error, Result};
use crate::messages::ResetRequest;

/// The model's and the simulator's one-step input gains at the goal (`report.json`'s
/// `diagnoses[].input_authority`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InputAuthority {
    /// The state both gains are taken at (the control goal).
    pub at: Vec<f64>,
    /// The nominal input `u0` of the differences (the loop's last command).
    pub nominal: Vec<f64>,
    /// The difference step per input.
    pub delta: Vec<f64>,
    /// The model's `∂x⁺/∂u`, `nx` rows of `nu` values.
    pub model_gain: Vec<Vec<f64>>,
    /// The simulator's `∂x⁺/∂u`, measured.
    pub sim_gain: Vec<Vec<f64>>,
    /// `⟨G_model, G_sim⟩ / ‖G_sim‖²`: 1 = the same gain, ≤ 0 = none or the wrong sign.
    pub projection: f64,
    /// Cosine between the two gains (the sign agreement, whatever the scale).
    pub cosine: f64,
    /// `‖G_model‖ / ‖G_sim‖`.
    pub norm_ratio: f64,
}

/// The simulator's one-step input gain at `x` and nominal input `u0`: for each input `i`,
/// `(step(u0 + δ_i e_i) − step(u0 − δ_i e_i)) / 2δ_i`, each step from `reset(x0 = x)`.
pub fn measure_sim_gain(
    sim: &mut SimClient,
    x: &[f64],
    u0: &[f64],
    delta: &[f64],
) -> Result<InputGain> {
    let nx = x.len();
    let mut next = |u: Vec<f64>| -> Result<Vec<f64>> {
        sim.reset(&ResetRequest {
            seed: None,
            x0: Some(x.to_vec()),
            perturbation: None,
        })?;
        Ok(sim.step(&u, None)?.x)
    };
    let mut cols = Vec::with_capacity(u0.len());
    for (i, &d) in delta.iter().enumerate() {
        let mut up = u0.to_vec();
        up[i] += d;
        let mut down = u0.to_vec();
        down[i] -= d;
        let (p, m) = (next(up)?, next(down)?);
        cols.push(
            p.iter()
                .zip(&m)
                .map(|(p, m)| (p - m) / (2.0 * d))
                .collect::<Vec<_>>(),
        );
    }
    Ok(InputGain {
        gains: vec![Mat::from_fn(nx, u0.len(), |r, c| cols[c][r])],
    })
}

fn rows(g: &InputGain) -> Vec<Vec<f64>> {
    g.gains.first().map_or_else(Vec::new, |m| {
        (0..m.nrows())
            .map(|r| (0..m.ncols()).map(|c| m[(r, c)]).collect())
            .collect()
    })
}

/// The input authority of control run `c` with its lifted `model`, measured on `sim` at the goal
/// (the reference's first state). `None` for a trajectory reference or a simulator without
/// inputs (a model without a lifted form, whose gain depends on the state, is not measured).
/// Afterwards the simulator is at the goal (the next `step` needs a `reset` as ever).
pub fn input_authority(
    c: &ControlReport,
    model: &dyn koopman::model::LiftedModel,
    sim: &mut SimClient,
) -> Result<Option<InputAuthority>> {
    let info = sim.info.sim.clone();
    let (nx, nu) = (info.nx(), info.nu());
    if nu == 0 || c.reference_trajectory.is_some() || c.reference.len() < nx {
        return Ok(None);
    }
    let at = c.reference[..nx].to_vec();
    let bounds = |i: usize| (info.u_min[i], info.u_max[i]);
    let delta: Vec<f64> = (0..nu)
        .map(|i| match bounds(i) {
            (l, h) if l.is_finite() && h.is_finite() && h > l => 1e-3 * (h - l),
            _ => 1e-3,
        })
        .collect();
    // The loop's last command, kept δ inside the bounds so both sides are feasible.
    let nominal: Vec<f64> = (0..nu)
        .map(|i| {
            let u = c.u.last().and_then(|u| u.get(i).copied()).unwrap_or(0.0);
            let (l, h) = bounds(i);
            u.min(h - delta[i]).max(l + delta[i])
        })
        .collect();
    let truth = measure_sim_gain(sim, &at, &nominal, &delta)?;
    let m = model_input_gain(model, 1);
    let a = gain_agreement(&m, &truth)
        .map_err(|e| Error::Config(format!("input authority of '{}': {e}", c.model)))?;
    Ok(Some(InputAuthority {
        at,
        nominal,
        delta,
        model_gain: rows(&m),
        sim_gain: rows(&truth),
        projection: a.projection,
        cosine: a.cosine,
        norm_ratio: a.norm_ratio,
    }))
}
