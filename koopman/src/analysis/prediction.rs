//! The SPEC metric for any lifted model: the discounted multi-step prediction error
//! `L_pred = (1/W) Σ_i γ^i · mean((P ẑ_{i+1} − x_{i+1})²)`, `ẑ_0 = Φ(x_0)`, `ẑ_{i+1} = A ẑ_i + B u_i`,
//! and the same rollout's error state by state.

use crate::data::Dataset;
use crate::model::LiftedModel;
use crate::{Error, Result};
use faer::Mat;
use rayon::prelude::*;

/// `L_pred` of `model` over every window of `data` with discount `gamma` (SPEC: 0.8), the mean
/// over windows and state dimensions. Uses the closed form
/// `P ẑ_{i+1} = P A^{i+1} Φ(x_0) + Σ_{j≤i} P A^{i−j} B u_j`, which equals the step-by-step rollout.
pub fn prediction_error(model: &dyn LiftedModel, data: &Dataset, gamma: f64) -> Result<f64> {
    if !(gamma > 0.0 && gamma.is_finite()) {
        return Err(Error::InvalidArgument(format!(
            "gamma must be positive (got {gamma})"
        )));
    }
    let (a, b) = checked_matrices(model, data)?;
    let (nx, steps) = (data.nx, data.steps);
    let n_lat = model.latent_dim();
    // m[k] = P A^k (nx × N), h[k] = P A^k B (nx × nu), k = 0..=T.
    let mut m: Vec<Mat<f64>> = Vec::with_capacity(steps + 1);
    m.push(Mat::from_fn(
        nx,
        n_lat,
        |i, j| if i == j { 1.0 } else { 0.0 },
    ));
    for k in 0..steps {
        let next = &m[k] * &a;
        m.push(next);
    }
    let h: Vec<Mat<f64>> = m.iter().map(|mk| mk * &b).collect();
    let weights: Vec<f64> = (0..steps).map(|i| gamma.powi(i as i32)).collect();
    let wsum: f64 = weights.iter().sum();
    const CHUNK: usize = 256;
    let partial: Vec<f64> = (0..data.n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let mut total = 0.0;
            let mut pred = vec![0.0; nx];
            for w in c * CHUNK..((c + 1) * CHUNK).min(data.n) {
                let z0 = model.lift(data.state(w, 0));
                for i in 0..steps {
                    let mk = &m[i + 1];
                    for (r, p) in pred.iter_mut().enumerate() {
                        let mut s = 0.0;
                        for (col, zc) in z0.iter().enumerate() {
                            s += mk[(r, col)] * zc;
                        }
                        for j in 0..=i {
                            let hk = &h[i - j];
                            for (q, uq) in data.input(w, j).iter().enumerate() {
                                s += hk[(r, q)] * uq;
                            }
                        }
                        *p = s;
                    }
                    let truth = data.state(w, i + 1);
                    let se: f64 = pred.iter().zip(truth).map(|(p, t)| (p - t) * (p - t)).sum();
                    total += weights[i] * se;
                }
            }
            total
        })
        .collect();
    let total: f64 = partial.iter().sum();
    let value = total / (wsum * (data.n * nx) as f64);
    if value.is_finite() {
        Ok(value)
    } else {
        Err(Error::NonFinite(
            "prediction error (the rollout diverged)".into(),
        ))
    }
}

/// Checks `data` and that its states have the model's dimension.
pub(super) fn check_states(model: &dyn LiftedModel, data: &Dataset) -> Result<()> {
    data.validate()?;
    if model.nx() != data.nx {
        return Err(Error::dimension(
            "state dimension (model vs data)",
            model.nx(),
            data.nx,
        ));
    }
    Ok(())
}

/// The model's `A` and `B` after checking `data` and the dimensions of model, data and matrices.
fn checked_matrices(model: &dyn LiftedModel, data: &Dataset) -> Result<(Mat<f64>, Mat<f64>)> {
    check_states(model, data)?;
    if model.nu() != data.nu {
        return Err(Error::dimension(
            "input dimension (model vs data)",
            model.nu(),
            data.nu,
        ));
    }
    let (a, b) = (model.a(), model.b());
    let n_lat = model.latent_dim();
    if a.nrows() != n_lat || a.ncols() != n_lat || b.nrows() != n_lat || b.ncols() != data.nu {
        return Err(Error::dimension(
            "model matrices A, B (latent dimension)",
            n_lat,
            a.nrows(),
        ));
    }
    Ok((a, b))
}

/// The root-mean-square error of each state over every window and step of the rollout that
/// [`prediction_error`] scores (`ẑ_0 = Φ(x_0)`, `ẑ_{i+1} = A ẑ_i + B u_i`, `x̂ = P ẑ`), in the
/// data's units: `rms_s = sqrt(Σ_w Σ_i (x̂_{i+1,s} − x_{i+1,s})² / (W·T))`, nx values. Their mean
/// square is `prediction_error(model, data, 1.0)`. Rolled out step by step, windows in parallel.
pub fn state_rms_errors(model: &dyn LiftedModel, data: &Dataset) -> Result<Vec<f64>> {
    let (a, b) = checked_matrices(model, data)?;
    let (nx, nu, steps) = (data.nx, data.nu, data.steps);
    let n_lat = model.latent_dim();
    const CHUNK: usize = 256;
    let partial: Vec<Vec<f64>> = (0..data.n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let mut sq = vec![0.0; nx];
            let mut next = vec![0.0; n_lat];
            for w in c * CHUNK..((c + 1) * CHUNK).min(data.n) {
                let mut z = model.lift(data.state(w, 0));
                for i in 0..steps {
                    let u = data.input(w, i);
                    for (r, zr) in next.iter_mut().enumerate() {
                        let mut s: f64 = (0..n_lat).map(|col| a[(r, col)] * z[col]).sum();
                        s += (0..nu).map(|q| b[(r, q)] * u[q]).sum::<f64>();
                        *zr = s;
                    }
                    std::mem::swap(&mut z, &mut next);
                    for ((acc, p), t) in sq.iter_mut().zip(&z[..nx]).zip(data.state(w, i + 1)) {
                        *acc += (p - t) * (p - t);
                    }
                }
            }
            sq
        })
        .collect();
    let count = (data.n * steps) as f64;
    let rms: Vec<f64> = (0..nx)
        .map(|s| (partial.iter().map(|p| p[s]).sum::<f64>() / count).sqrt())
        .collect();
    if rms.iter().all(|v| v.is_finite()) {
        Ok(rms)
    } else {
        Err(Error::NonFinite(
            "state errors (the rollout diverged)".into(),
        ))
    }
}
