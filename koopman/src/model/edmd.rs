//! EDMD with control: a polynomial dictionary of the state, the input kept linear, and
//! `[A B] = argmin (1/P) Σ ‖z⁺ − A z − B u‖² + λ ‖[A B]‖²_F` over all P transitions of a dataset.
//!
//! The dictionary ([`dictionary`]) starts with x itself, so `x = P z`; [`fit`] uses the degree it is
//! given or the largest with at most 250 features (degree 20 and N = 231 for the damped pendulum,
//! degree 6 and N = 210 for the double pendulum); [`select::fit_by_validation`], what the trainer
//! uses unless a degree is given, tries every degree up to that and keeps the one with the lowest
//! validation error. The normal equations are accumulated in chunks ([`gram`]),
//! so memory does not depend on the number of pairs, and solved by Cholesky with an SVD fallback.

pub mod dictionary;
pub mod gram;
mod io;
pub mod select;

pub use dictionary::{Basis, Dictionary};
pub use gram::Solver;
pub use select::{fit_by_validation, DegreeSelection, DegreeTrial};

use crate::data::Dataset;
use crate::model::LiftedModel;
use crate::{Error, Result};
use faer::Mat;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Settings of an EDMD fit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct EdmdConfig {
    /// Total polynomial degree d; `None` = the largest with at most `max_features` features.
    pub degree: Option<usize>,
    /// Feature budget used when `degree` is `None`.
    pub max_features: usize,
    /// Per-variable polynomial family (same span either way; Chebyshev is better conditioned).
    pub basis: Basis,
    /// Ridge weight λ on the mean squared residual (default 1e-10).
    pub ridge: f64,
    /// Pairs per accumulation chunk (memory ∝ chunk · N).
    pub chunk: usize,
}

impl Default for EdmdConfig {
    fn default() -> Self {
        EdmdConfig {
            degree: None,
            max_features: 250,
            basis: Basis::Chebyshev,
            ridge: 1e-10,
            chunk: 2048,
        }
    }
}

/// What happened during a fit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FitInfo {
    /// Number of (x, u, x⁺) pairs.
    pub pairs: usize,
    /// Factorisation used.
    pub solver: Solver,
    /// Seconds spent accumulating the normal equations.
    pub accumulate_seconds: f64,
    /// Seconds spent solving them.
    pub solve_seconds: f64,
    /// Mean squared one-step residual of the lifted state (per latent coordinate) over all
    /// training pairs, evaluated from the normal equations.
    pub train_residual: f64,
    /// Environment of the training data.
    pub env: String,
}

/// A fitted EDMD-with-control model.
#[derive(Clone, Debug)]
pub struct EdmdModel {
    /// The lifting.
    pub dict: Dictionary,
    /// Input dimension.
    pub nu: usize,
    /// A (N × N).
    pub a: Mat<f64>,
    /// B (N × nu).
    pub b: Mat<f64>,
    /// The settings it was fitted with.
    pub config: EdmdConfig,
    /// Fit diagnostics.
    pub info: FitInfo,
}

/// Fits EDMD with control on every transition of `data` (validated first).
pub fn fit(data: &Dataset, cfg: &EdmdConfig) -> Result<EdmdModel> {
    data.validate()?;
    if !(cfg.ridge >= 0.0 && cfg.ridge.is_finite()) {
        return Err(Error::InvalidArgument(format!(
            "ridge must be finite and ≥ 0 (got {})",
            cfg.ridge
        )));
    }
    let nx = data.nx;
    let degree = cfg
        .degree
        .unwrap_or_else(|| dictionary::auto_degree(nx, cfg.max_features));
    if degree == 0 {
        return Err(Error::InvalidArgument(
            "EDMD degree must be at least 1".into(),
        ));
    }
    let n_feat = dictionary::feature_count(nx, degree);
    if n_feat > 20_000 {
        return Err(Error::InvalidArgument(format!(
            "degree {degree} on {nx} variables gives {n_feat} features (at most 20,000)"
        )));
    }
    // Scale every state component to [−1, 1] over the training states.
    let mut lo = vec![f64::INFINITY; nx];
    let mut hi = vec![f64::NEG_INFINITY; nx];
    for s in data.x.chunks_exact(nx) {
        for k in 0..nx {
            lo[k] = lo[k].min(s[k]);
            hi[k] = hi[k].max(s[k]);
        }
    }
    let dict = Dictionary::new(degree, cfg.basis, &lo, &hi);
    let n_lat = dict.len();
    let t0 = Instant::now();
    let normal = gram::accumulate(&dict, data, cfg.chunk);
    let accumulate_seconds = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let (k, solver) = gram::solve(&normal, cfg.ridge)?;
    let solve_seconds = t1.elapsed().as_secs_f64();
    // K is (N+nu) × N with z⁺ ≈ Kᵀ w: A = K[:N]ᵀ, B = K[N:]ᵀ.
    let a = Mat::from_fn(n_lat, n_lat, |i, j| k[(j, i)]);
    let b = Mat::from_fn(n_lat, data.nu, |i, j| k[(n_lat + j, i)]);
    let train_residual = gram::residual(&normal, &k);
    let model = EdmdModel {
        dict,
        nu: data.nu,
        a,
        b,
        config: cfg.clone(),
        info: FitInfo {
            pairs: normal.pairs,
            solver,
            accumulate_seconds,
            solve_seconds,
            train_residual,
            env: data.meta.env.clone(),
        },
    };
    Ok(model)
}

impl EdmdModel {
    /// The SPEC metric on `data`: discounted multi-step prediction error `L_pred` with discount
    /// `gamma` (0.8 in SPEC), rolling out from `Φ(x_0)` with the stored inputs.
    pub fn prediction_error(&self, data: &Dataset, gamma: f64) -> Result<f64> {
        crate::analysis::prediction_error(self, data, gamma)
    }
}

impl LiftedModel for EdmdModel {
    fn nx(&self) -> usize {
        self.dict.nx
    }
    fn nu(&self) -> usize {
        self.nu
    }
    fn latent_dim(&self) -> usize {
        self.dict.len()
    }
    fn a(&self) -> Mat<f64> {
        self.a.clone()
    }
    fn b(&self) -> Mat<f64> {
        self.b.clone()
    }
    fn lift(&self, x: &[f64]) -> Vec<f64> {
        self.dict.lift(x)
    }
}

#[cfg(test)]
mod tests;
