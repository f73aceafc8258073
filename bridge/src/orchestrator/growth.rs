//! How fast deviations grow at a control goal, in the simulator and in the model: the spectral
//! radius of the simulator's one-step state Jacobian `∂x⁺/∂x` (central differences through its
//! adapter: `reset(x0 = goal ± δ e_i)`, one `step` with the input the model holds the goal with)
//! against that of the
//! model's lifted `A`, and what their ratio becomes over the MPC's horizon. A model that grows
//! slower than an unstable plant plans as if the plant fell slowly.

use faer::Mat;
use serde::{Deserialize, Serialize};

use super::closed_loop::ControlReport;
use crate::client::SimClient;
use crate::error::{Error, Result};
use crate::messages::ResetRequest;

/// The simulator's growth rate at least this (per step) makes the goal an unstable equilibrium.
pub const UNSTABLE_RADIUS: f64 = 1.02;
/// A model whose predicted departure over the horizon is this many times too slow cannot hold an
/// unstable goal.
pub const TOO_SLOW_OVER_HORIZON: f64 = 10.0;

/// `report.json`'s `diagnoses[].growth`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Growth {
    /// The state both are taken at (the control goal).
    pub at: Vec<f64>,
    /// The input the simulator's Jacobian is taken with: the model's holding input at the goal.
    pub input: Vec<f64>,
    /// Largest |eigenvalue| of the simulator's `∂x⁺/∂x` at the goal (per step).
    pub sim_spectral_radius: f64,
    /// Largest |eigenvalue| of the model's lifted `A` (per step).
    pub model_spectral_radius: f64,
    /// The MPC's horizon H.
    pub horizon: usize,
    /// `(sim / model)^H`: how many times faster the plant departs over the horizon than the model
    /// predicts (< 1: the model grows faster).
    pub too_slow_over_horizon: f64,
}

impl Growth {
    /// True when the goal is unstable and the model predicts the departure over the horizon at
    /// least [`TOO_SLOW_OVER_HORIZON`] times too slow.
    pub fn model_too_slow(&self) -> bool {
        self.sim_spectral_radius >= UNSTABLE_RADIUS
            && self.too_slow_over_horizon >= TOO_SLOW_OVER_HORIZON
    }
}

/// The largest |eigenvalue| of a square matrix.
fn spectral_radius(a: faer::MatRef<'_, f64>) -> Result<f64> {
    let ev = koopman::analysis::conditioning::eigenvalues(a)
        .map_err(|e| Error::Config(format!("eigenvalues: {e}")))?;
    Ok(ev.iter().map(|z| z.norm()).fold(0.0, f64::max))
}

/// The simulator's `∂x⁺/∂x` at `x` under input `u0`: column `i` is
/// `(step from x + δ_i e_i − step from x − δ_i e_i) / 2δ_i`, `δ_i = 1e-5·max(1, |x_i|)`.
pub fn measure_state_jacobian(sim: &mut SimClient, x: &[f64], u0: &[f64]) -> Result<Mat<f64>> {
    let nx = x.len();
    let mut next = |x0: Vec<f64>| -> Result<Vec<f64>> {
        sim.reset(&ResetRequest {
            seed: None,
            x0: Some(x0),
            perturbation: None,
        })?;
        Ok(sim.step(u0, None)?.x)
    };
    let mut j = Mat::zeros(nx, nx);
    for i in 0..nx {
        let d = 1e-5 * x[i].abs().max(1.0);
        let (mut up, mut down) = (x.to_vec(), x.to_vec());
        up[i] += d;
        down[i] -= d;
        let (p, m) = (next(up)?, next(down)?);
        for r in 0..nx.min(p.len()).min(m.len()) {
            j[(r, i)] = (p[r] - m[r]) / (2.0 * d);
        }
    }
    Ok(j)
}

/// The input with which `model` predicts that `x` stays put, `argmin_u ‖P(A φ(x) + B u) − x‖`
/// (least squares), clamped to `[lo, hi]`.
pub fn model_holding_input(
    model: &dyn koopman::model::LiftedModel,
    x: &[f64],
    lo: &[f64],
    hi: &[f64],
) -> Vec<f64> {
    use faer::linalg::solvers::SolveLstsq;
    let (nx, nu) = (model.nx(), model.nu());
    let (a, b) = (model.a(), model.b());
    let z = model.lift(x);
    let rhs = Mat::from_fn(nx, 1, |i, _| {
        x[i] - (0..z.len()).map(|k| a[(i, k)] * z[k]).sum::<f64>()
    });
    let pb = Mat::from_fn(nx, nu, |i, j| b[(i, j)]);
    let u = pb.qr().solve_lstsq(&rhs);
    (0..nu)
        .map(|j| {
            let v = if u[(j, 0)].is_finite() {
                u[(j, 0)]
            } else {
                0.0
            };
            v.min(hi.get(j).copied().unwrap_or(f64::INFINITY))
                .max(lo.get(j).copied().unwrap_or(f64::NEG_INFINITY))
        })
        .collect()
}

/// The growth check of control run `c` with its lifted `model`, measured on `sim` at the goal
/// with the input the model holds it with ([`model_holding_input`], within the simulator's
/// bounds). `None` for a trajectory reference or a run without an MPC horizon.
pub fn growth(
    c: &ControlReport,
    model: &dyn koopman::model::LiftedModel,
    sim: &mut SimClient,
) -> Result<Option<Growth>> {
    let nx = sim.info.sim.nx();
    let Some(horizon) = c.mpc.as_ref().map(|m| m.horizon) else {
        return Ok(None);
    };
    if c.reference_trajectory.is_some() || c.reference.len() < nx {
        return Ok(None);
    }
    let at = c.reference[..nx].to_vec();
    let info = sim.info.sim.clone();
    let hold = model_holding_input(model, &at, &info.u_min, &info.u_max);
    let jac = measure_state_jacobian(sim, &at, &hold)?;
    let sim_spectral_radius = spectral_radius(jac.as_ref())?;
    let model_spectral_radius = spectral_radius(model.a().as_ref())?;
    let ratio = sim_spectral_radius / model_spectral_radius.max(f64::MIN_POSITIVE);
    Ok(Some(Growth {
        at,
        input: hold,
        sim_spectral_radius,
        model_spectral_radius,
        horizon,
        too_slow_over_horizon: ratio.powi(horizon as i32),
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use koopman::model::LiftedModel;

    /// `z = [x; 1]`, `z⁺ = A z + B u` with a known A and B.
    struct Affine;

    impl LiftedModel for Affine {
        fn nx(&self) -> usize {
            2
        }
        fn nu(&self) -> usize {
            1
        }
        fn latent_dim(&self) -> usize {
            3
        }
        fn a(&self) -> Mat<f64> {
            let rows = [[1.1, 0.2, 0.05], [-0.3, 0.9, -0.1], [0.0, 0.0, 1.0]];
            Mat::from_fn(3, 3, |i, j| rows[i][j])
        }
        fn b(&self) -> Mat<f64> {
            let col = [0.5, 2.0, 0.0];
            Mat::from_fn(3, 1, |i, _| col[i])
        }
        fn lift(&self, x: &[f64]) -> Vec<f64> {
            vec![x[0], x[1], 1.0]
        }
    }

    #[test]
    fn the_holding_input_is_the_least_squares_fixed_point_clamped() {
        let x = [0.4, -0.2];
        // r = x − (A z)[..2]; u = (bᵀr)/(bᵀb) with b = [0.5, 2].
        let az = [1.1 * 0.4 + 0.2 * -0.2 + 0.05, -0.3 * 0.4 + 0.9 * -0.2 - 0.1];
        let r = [x[0] - az[0], x[1] - az[1]];
        let want = (0.5 * r[0] + 2.0 * r[1]) / (0.25 + 4.0);
        let u = model_holding_input(&Affine, &x, &[-10.0], &[10.0]);
        assert!((u[0] - want).abs() < 1e-12, "{u:?} vs {want}");
        let clamped = model_holding_input(&Affine, &x, &[-0.01], &[0.01]);
        assert_eq!(clamped, vec![0.01f64.copysign(want)]);
        // The lifted A's spectral radius: its 2×2 block's eigenvalues and the constant's 1.
        let tr: f64 = 1.1 + 0.9;
        let det: f64 = 1.1 * 0.9 + 0.2 * 0.3;
        let disc: f64 = tr * tr - 4.0 * det;
        let rho = if disc >= 0.0 {
            (tr.abs() + disc.sqrt()) / 2.0
        } else {
            det.sqrt()
        };
        let got = spectral_radius(Affine.a().as_ref()).unwrap();
        assert!((got - rho.max(1.0)).abs() < 1e-12, "{got} vs {rho}");
    }

    #[test]
    fn too_slow_needs_an_unstable_goal_and_a_slow_model() {
        let g = |sim: f64, model: f64, h: usize| Growth {
            at: vec![0.0],
            input: vec![0.0],
            sim_spectral_radius: sim,
            model_spectral_radius: model,
            horizon: h,
            too_slow_over_horizon: (sim / model).powi(h as i32),
        };
        assert!(g(1.56, 1.29, 30).model_too_slow());
        assert!(!g(1.56, 1.29, 5).model_too_slow()); // 2.6× over 5 steps
        assert!(!g(1.56, 1.6, 30).model_too_slow());
        assert!(!g(1.0, 0.5, 30).model_too_slow()); // a stable goal
    }
}
