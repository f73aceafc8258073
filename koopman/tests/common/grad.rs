//! Pieces shared by the loss-gradient tests: random windows, filling the fast workspace, the
//! reference decorrelation term and the central finite-difference check per parameter group.

use koopman::rng::Rng;
use koopman::train::loss::LossWs;

/// A batch of windows: x[i][t] (nx values), u[i][t] (nu values).
pub struct Windows {
    /// States, `steps + 1` per window.
    pub x: Vec<Vec<Vec<f64>>>,
    /// Inputs, `steps` per window.
    pub u: Vec<Vec<Vec<f64>>>,
}

/// `b` windows of `steps` steps: states uniform in [-2, 2], inputs uniform in [-1.5, 1.5].
pub fn random_windows(b: usize, steps: usize, nx: usize, nu: usize, rng: &mut Rng) -> Windows {
    let draw = |n: usize, s: f64, rng: &mut Rng| (0..n).map(|_| rng.uniform(-s, s)).collect();
    let x = (0..b)
        .map(|_| (0..=steps).map(|_| draw(nx, 2.0, rng)).collect())
        .collect();
    let u = (0..b)
        .map(|_| (0..steps).map(|_| draw(nu, 1.5, rng)).collect())
        .collect();
    Windows { x, u }
}

/// Fills the fast workspace with the windows (time-major, column-major).
pub fn fill<T: koopman::model::scalar::Real>(
    ws: &mut LossWs<T>,
    w: &Windows,
    nx: usize,
    nu: usize,
) {
    let b = w.x.len();
    let steps = w.u[0].len();
    let n = (steps + 1) * b;
    let xs = ws.states_mut();
    for i in 0..b {
        for t in 0..=steps {
            for j in 0..nx {
                xs[j * n + t * b + i] = T::from_f64(w.x[i][t][j]);
            }
        }
    }
    let us = ws.inputs_mut();
    for i in 0..b {
        for t in 0..steps {
            for j in 0..nu {
                us[j * steps * b + t * b + i] = T::from_f64(w.u[i][t][j]);
            }
        }
    }
}

/// Reference decorrelation term with plain loops: the mean squared off-diagonal sample
/// covariance of the `d` encoder features `z[i][0][nx..]` over the batch (0 when `d < 2`).
pub fn ref_cov(z: &[Vec<Vec<f64>>], nx: usize, d: usize) -> f64 {
    if d < 2 {
        return 0.0;
    }
    let b = z.len();
    let psi: Vec<&[f64]> = (0..b).map(|i| &z[i][0][nx..]).collect();
    let mean: Vec<f64> = (0..d)
        .map(|j| psi.iter().map(|v| v[j]).sum::<f64>() / b as f64)
        .collect();
    let mut off = 0.0;
    for j in 0..d {
        for k in 0..d {
            if j != k {
                let c: f64 = psi
                    .iter()
                    .map(|v| (v[j] - mean[j]) * (v[k] - mean[k]))
                    .sum::<f64>()
                    / (b - 1) as f64;
                off += c * c;
            }
        }
    }
    off / (d * (d - 1)) as f64
}

/// Asserts that `grad` matches central differences (step 1e-6) of `loss` at `p` within a
/// relative error of 1e-6 in every named group `(name, start, end)`, and that no group's
/// gradient is zero; `label` heads the failure message.
pub fn assert_groups_match_fd(
    groups: &[(String, usize, usize)],
    p: &[f64],
    grad: &[f64],
    loss: impl Fn(&[f64]) -> f64,
    label: &str,
) {
    let h = 1e-6;
    for (name, s, e) in groups {
        let (mut num, mut den) = (0.0, 0.0);
        for k in *s..*e {
            let mut pp = p.to_vec();
            pp[k] += h;
            let lp = loss(&pp);
            pp[k] -= 2.0 * h;
            let lm = loss(&pp);
            let fd = (lp - lm) / (2.0 * h);
            num += (grad[k] - fd).powi(2);
            den += fd * fd;
        }
        let rel = num.sqrt() / den.sqrt().max(1e-300);
        assert!(
            rel <= 1e-6,
            "{label}: group {name} relative error {rel:e} (‖fd‖ = {:e})",
            den.sqrt()
        );
        assert!(
            den > 0.0,
            "group {name} has a zero gradient: the test would not see an error"
        );
    }
}

/// Relative 2-norm difference ‖a − b‖ / ‖a‖ of gradient `b` (f32 or f64) from gradient `a`.
pub fn rel_diff<T: Copy + Into<f64>>(a: &[f64], b: &[T]) -> f64 {
    let num: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - (*y).into()).powi(2))
        .sum();
    let den: f64 = a.iter().map(|x| x * x).sum();
    (num / den).sqrt()
}
