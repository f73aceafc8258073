//! A quick least-squares fit of a [`MatrixModel`] (EDMD with random tanh features and linear
//! inputs) from a dataset: the in-process stand-in model of the MPC tests and `control --fit`.

use faer::linalg::solvers::Solve;
use faer::{Mat, Side};

use super::{Activation, MatrixModel};
use crate::data::Dataset;
use crate::error::{Error, Result};
use crate::model::LiftedModel;
use crate::rng::Rng;

/// Fits `z⁺ ≈ A z + B u` with `z = [x, tanh(F x + c)]`, `n_features` random features scaled by
/// the data's per-component spread, by ridge-regularised least squares over every transition.
pub fn fit_random_features(
    data: &Dataset,
    n_features: usize,
    ridge: f64,
    seed: u64,
) -> Result<MatrixModel> {
    let (nx, nu) = (data.nx, data.nu);
    if data.n == 0 || data.steps == 0 {
        return Err(Error::InvalidArgument(
            "cannot fit a model to an empty dataset".into(),
        ));
    }
    if !(ridge.is_finite() && ridge >= 0.0) {
        return Err(Error::InvalidArgument(format!(
            "ridge must be finite and ≥ 0, got {ridge}"
        )));
    }
    if data.x.iter().chain(&data.u).any(|v| !v.is_finite()) {
        return Err(Error::NonFinite("dataset".into()));
    }
    // Per-component spread of the states sets the feature scale.
    let count = (data.n * (data.steps + 1)) as f64;
    let mut mean = vec![0.0; nx];
    let mut sq = vec![0.0; nx];
    for v in data.x.chunks(nx) {
        for i in 0..nx {
            mean[i] += v[i] / count;
            sq[i] += v[i] * v[i] / count;
        }
    }
    let std: Vec<f64> = (0..nx)
        .map(|i| (sq[i] - mean[i] * mean[i]).max(1e-12).sqrt())
        .collect();
    let mut rng = Rng::new(seed);
    let f = Mat::from_fn(n_features, nx, |_, j| {
        rng.normal() / (std[j] * (nx as f64).sqrt())
    });
    let c: Vec<f64> = (0..n_features)
        .map(|i| rng.uniform(-1.0, 1.0) - (0..nx).map(|j| f[(i, j)] * mean[j]).sum::<f64>())
        .collect();
    let latent = nx + n_features;
    let mut lifter = MatrixModel::new(
        Mat::identity(latent, latent),
        Mat::zeros(latent, nu),
        f.clone(),
        c.clone(),
    )?;
    lifter.activation = Activation::Tanh;
    // Normal equations G θ = C with regressors w = [z; u] and targets z⁺.
    let d = latent + nu;
    let mut g = Mat::<f64>::zeros(d, d);
    let mut cm = Mat::<f64>::zeros(d, latent);
    let mut w = vec![0.0; d];
    for i in 0..data.n {
        let mut z = lifter.lift(data.state(i, 0));
        for t in 0..data.steps {
            let zn = lifter.lift(data.state(i, t + 1));
            w[..latent].copy_from_slice(&z);
            w[latent..].copy_from_slice(data.input(i, t));
            for a in 0..d {
                let wa = w[a];
                for b in 0..=a {
                    g[(a, b)] += wa * w[b];
                }
                for b in 0..latent {
                    cm[(a, b)] += wa * zn[b];
                }
            }
            z = zn;
        }
    }
    let trace = (0..d).map(|a| g[(a, a)]).sum::<f64>() / d as f64;
    for a in 0..d {
        for b in 0..a {
            g[(b, a)] = g[(a, b)];
        }
        g[(a, a)] += ridge * trace.max(1e-300);
    }
    let llt = g.llt(Side::Lower).map_err(|_| {
        Error::Numerical("least-squares normal equations are singular; increase the ridge".into())
    })?;
    let theta = llt.solve(&cm); // d × latent: θᵀ = [A B]ᵀ
    let a = Mat::from_fn(latent, latent, |i, j| theta[(j, i)]);
    let b = Mat::from_fn(latent, nu, |i, j| theta[(latent + j, i)]);
    let mut model = MatrixModel::new(a, b, f, c)?;
    model.activation = Activation::Tanh;
    Ok(model)
}
