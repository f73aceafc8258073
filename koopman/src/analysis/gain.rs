//! Control authority: how an input moves the state k steps later, in a lifted model
//! (`∂x_{k+1}/∂u_0 = P A^k B`, the same at every state) and in the true system (central finite
//! differences at a given state), and a one-number comparison of the two.
//!
//! A linear-input Koopman model `z⁺ = A z + B u` has a state-independent input gain. When the true
//! gain changes sign across the data (the damped pendulum's `cos θ · u`), the best constant gain
//! is close to zero and an MPC on that model has no usable authority; this module measures that
//! before a closed loop is run.

use faer::Mat;

use crate::error::{ensure_finite, Error, Result};
use crate::model::LiftedModel;
use crate::systems::System;

/// Below this projection of a model's gain on the true one ([`GainAgreement::projection`]),
/// the model has too little control authority for an MPC on it to be expected to regulate
/// (`koopbridge control`'s pre-flight check and `koopbridge run`'s control diagnosis).
pub const WEAK_AUTHORITY: f64 = 0.25;

/// The input-to-state gains `G_k = ∂x_{k+1}/∂u_0` for `k = 0..steps` (each nx × nu), with every
/// later input held at zero.
#[derive(Clone, Debug)]
pub struct InputGain {
    /// `G_0 … G_{steps−1}`.
    pub gains: Vec<Mat<f64>>,
}

impl InputGain {
    /// Stacks the gains into one (steps·nx) × nu matrix, rows ordered step by step.
    pub fn stacked(&self) -> Mat<f64> {
        let (nx, nu) = self
            .gains
            .first()
            .map(|g| (g.nrows(), g.ncols()))
            .unwrap_or((0, 0));
        Mat::from_fn(self.gains.len() * nx, nu, |i, j| {
            self.gains[i / nx][(i % nx, j)]
        })
    }
}

/// `G_k = P A^k B` of a lifted model (P selects the first nx latent coordinates).
pub fn model_input_gain(model: &dyn LiftedModel, steps: usize) -> InputGain {
    let (nx, nu) = (model.nx(), model.nu());
    let a = model.a();
    let mut ak_b = model.b();
    let mut gains = Vec::with_capacity(steps);
    for k in 0..steps {
        if k > 0 {
            ak_b = &a * &ak_b;
        }
        gains.push(Mat::from_fn(nx, nu, |i, j| ak_b[(i, j)]));
    }
    InputGain { gains }
}

/// `G_k` of the true system at state `x` and nominal input `u0`, by central differences with
/// step `h` on `u_0` (later inputs equal `u0`).
pub fn system_input_gain(
    system: &dyn System,
    x: &[f64],
    u0: &[f64],
    steps: usize,
    h: f64,
) -> Result<InputGain> {
    let (nx, nu) = (system.nx(), system.nu());
    if x.len() != nx {
        return Err(Error::dimension("state", nx, x.len()));
    }
    if u0.len() != nu {
        return Err(Error::dimension("input", nu, u0.len()));
    }
    ensure_finite("state", x)?;
    ensure_finite("input", u0)?;
    if !(h > 0.0 && h.is_finite()) {
        return Err(Error::InvalidArgument(format!(
            "finite-difference step must be positive, got {h}"
        )));
    }
    let rollout = |first: &[f64]| {
        let mut states = Vec::with_capacity(steps);
        let mut cur = x.to_vec();
        let mut next = vec![0.0; nx];
        for k in 0..steps {
            system.step(&cur, if k == 0 { first } else { u0 }, &mut next);
            std::mem::swap(&mut cur, &mut next);
            states.push(cur.clone());
        }
        states
    };
    let mut gains = vec![Mat::zeros(nx, nu); steps];
    for j in 0..nu {
        let mut plus = u0.to_vec();
        let mut minus = u0.to_vec();
        plus[j] += h;
        minus[j] -= h;
        let (sp, sm) = (rollout(&plus), rollout(&minus));
        for (k, g) in gains.iter_mut().enumerate() {
            for i in 0..nx {
                g[(i, j)] = (sp[k][i] - sm[k][i]) / (2.0 * h);
            }
        }
    }
    Ok(InputGain { gains })
}

/// How well a model's input gain matches a reference gain over the horizon.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct GainAgreement {
    /// `⟨G_model, G_true⟩ / ‖G_true‖²`: 1 when the model's gain equals the true one, 0 when it
    /// has no authority along it, negative when it points the other way.
    pub projection: f64,
    /// Cosine of the angle between the stacked gains (sign agreement regardless of scale).
    pub cosine: f64,
    /// `‖G_model‖ / ‖G_true‖` (Frobenius norms of the stacked gains).
    pub norm_ratio: f64,
}

/// Compares a model's gains with a reference (e.g. the true system's at the control target).
pub fn gain_agreement(model: &InputGain, reference: &InputGain) -> Result<GainAgreement> {
    let (m, r) = (model.stacked(), reference.stacked());
    if m.nrows() != r.nrows() || m.ncols() != r.ncols() {
        return Err(Error::dimension("stacked gain rows", r.nrows(), m.nrows()));
    }
    let (mut dot, mut mm, mut rr) = (0.0, 0.0, 0.0);
    for j in 0..m.ncols() {
        for i in 0..m.nrows() {
            dot += m[(i, j)] * r[(i, j)];
            mm += m[(i, j)] * m[(i, j)];
            rr += r[(i, j)] * r[(i, j)];
        }
    }
    if rr == 0.0 {
        return Err(Error::InvalidArgument(
            "the reference gain is zero: the input does not move the state".into(),
        ));
    }
    let cosine = if mm == 0.0 {
        0.0
    } else {
        dot / (mm * rr).sqrt()
    };
    Ok(GainAgreement {
        projection: dot / rr,
        cosine,
        norm_ratio: (mm / rr).sqrt(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::matrix::MatrixModel;

    /// A linear system `x⁺ = F x + G u` as a `System`, to compare both gain routes exactly.
    struct Linear {
        f: Mat<f64>,
        g: Mat<f64>,
    }
    impl System for Linear {
        fn name(&self) -> &str {
            "linear"
        }
        fn nx(&self) -> usize {
            self.f.nrows()
        }
        fn nu(&self) -> usize {
            self.g.ncols()
        }
        fn dt(&self) -> f64 {
            1.0
        }
        fn state_names(&self) -> Vec<String> {
            (0..self.nx()).map(|i| format!("x{i}")).collect()
        }
        fn input_names(&self) -> Vec<String> {
            (0..self.nu()).map(|i| format!("u{i}")).collect()
        }
        fn input_bounds(&self) -> (Vec<f64>, Vec<f64>) {
            (vec![-1.0; self.nu()], vec![1.0; self.nu()])
        }
        fn angle_indices(&self) -> Vec<usize> {
            vec![]
        }
        fn window_steps(&self) -> usize {
            1
        }
        fn sample_initial_state(&self, _rng: &mut crate::rng::Rng) -> Vec<f64> {
            vec![0.0; self.nx()]
        }
        fn step(&self, x: &[f64], u: &[f64], x_next: &mut [f64]) {
            for (i, out) in x_next.iter_mut().enumerate() {
                *out = (0..x.len()).map(|j| self.f[(i, j)] * x[j]).sum::<f64>()
                    + (0..u.len()).map(|j| self.g[(i, j)] * u[j]).sum::<f64>();
            }
        }
    }

    fn linear_pair() -> (Linear, MatrixModel) {
        let f = Mat::from_fn(2, 2, |i, j| [[0.9, 0.1], [-0.2, 0.95]][i][j]);
        let g = Mat::from_fn(2, 1, |i, _| [0.05, 0.3][i]);
        // The lifted model with no extra features is the linear system itself (P = I).
        let model = MatrixModel::new(f.clone(), g.clone(), Mat::zeros(0, 2), vec![]).unwrap();
        (Linear { f, g }, model)
    }

    #[test]
    fn model_gain_is_p_a_to_the_k_b_and_matches_finite_differences_of_the_same_linear_system() {
        let (sys, model) = linear_pair();
        let mg = model_input_gain(&model, 6);
        let sg = system_input_gain(&sys, &[0.4, -0.3], &[0.0], 6, 1e-3).unwrap();
        // Independent closed form: G_k = F^k G.
        let mut fk_g = sys.g.clone();
        for k in 0..6 {
            if k > 0 {
                fk_g = &sys.f * &fk_g;
            }
            for i in 0..2 {
                assert!((mg.gains[k][(i, 0)] - fk_g[(i, 0)]).abs() < 1e-14);
                assert!((sg.gains[k][(i, 0)] - fk_g[(i, 0)]).abs() < 1e-10);
            }
        }
        let agree = gain_agreement(&mg, &sg).unwrap();
        assert!((agree.projection - 1.0).abs() < 1e-9, "{agree:?}");
        assert!((agree.cosine - 1.0).abs() < 1e-9);
        // A model whose B has the opposite sign disagrees completely.
        let flipped = MatrixModel::new(sys.f.clone(), -&sys.g, Mat::zeros(0, 2), vec![]).unwrap();
        let bad = gain_agreement(&model_input_gain(&flipped, 6), &sg).unwrap();
        assert!((bad.projection + 1.0).abs() < 1e-9 && (bad.cosine + 1.0).abs() < 1e-9);
    }

    #[test]
    fn the_damped_pendulum_gain_flips_sign_with_cos_theta() {
        let sys = crate::systems::by_name("damped-pendulum").unwrap();
        let at = |theta: f64| system_input_gain(sys.as_ref(), &[theta, 0.0], &[0.0], 5, 1e-4);
        let down = at(0.0).unwrap();
        let over = at(-2.5).unwrap();
        // θ̇ one step after u: ≈ dt·cos θ (dt = 0.02).
        assert!(
            (down.gains[0][(1, 0)] - 0.02).abs() < 2e-3,
            "{:?}",
            down.gains[0]
        );
        assert!(over.gains[0][(1, 0)] < 0.0 && down.gains[0][(1, 0)] > 0.0);
        let agree = gain_agreement(&over, &down).unwrap();
        assert!(agree.cosine < -0.5, "{agree:?}");
    }

    #[test]
    fn bad_arguments_are_typed_errors() {
        let sys = crate::systems::by_name("damped-pendulum").unwrap();
        assert!(system_input_gain(sys.as_ref(), &[0.0], &[0.0], 3, 1e-4).is_err());
        assert!(system_input_gain(sys.as_ref(), &[0.0, f64::NAN], &[0.0], 3, 1e-4).is_err());
        assert!(system_input_gain(sys.as_ref(), &[0.0, 0.0], &[0.0], 3, 0.0).is_err());
        let zero = InputGain {
            gains: vec![Mat::zeros(2, 1)],
        };
        assert!(gain_agreement(&zero, &zero).is_err());
    }
}
