//! A lifted model given by its matrices and a fixed random-feature lifting: the stand-in model
//! of the MPC tests and benchmarks (random stable systems of any size), and its least-squares fit.

use faer::Mat;

use crate::error::{Error, Result};
use crate::model::LiftedModel;
use crate::rng::Rng;

mod fit;
pub use fit::fit_random_features;

/// The nonlinearity of the lifting features.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Activation {
    /// `tanh(F x + c)`.
    #[default]
    Tanh,
    /// `cos(F x + c)` (random Fourier features).
    Cos,
}

/// `z = [x, σ(F x + c)]`, `z⁺ = A z + B u`, with explicit A, B, F, c and σ = tanh or cos.
#[derive(Clone, Debug)]
pub struct MatrixModel {
    /// Latent transition matrix (N × N).
    pub a: Mat<f64>,
    /// Latent input matrix (N × nu).
    pub b: Mat<f64>,
    /// Feature weights F ((N − nx) × nx).
    pub features: Mat<f64>,
    /// Feature offsets c (N − nx).
    pub offsets: Vec<f64>,
    /// The feature nonlinearity σ.
    pub activation: Activation,
    nx: usize,
}

impl MatrixModel {
    /// A model from its matrices; `features` has N − nx rows and nx columns.
    pub fn new(a: Mat<f64>, b: Mat<f64>, features: Mat<f64>, offsets: Vec<f64>) -> Result<Self> {
        let latent = a.nrows();
        let nx = features.ncols();
        if a.ncols() != latent {
            return Err(Error::dimension("A columns", latent, a.ncols()));
        }
        if b.nrows() != latent {
            return Err(Error::dimension("B rows", latent, b.nrows()));
        }
        if nx == 0 || features.nrows() + nx != latent {
            return Err(Error::dimension(
                "feature rows (N − nx)",
                latent.saturating_sub(nx),
                features.nrows(),
            ));
        }
        if offsets.len() != features.nrows() {
            return Err(Error::dimension(
                "feature offsets",
                features.nrows(),
                offsets.len(),
            ));
        }
        Ok(MatrixModel {
            a,
            b,
            features,
            offsets,
            activation: Activation::Tanh,
            nx,
        })
    }

    /// A linear model `x⁺ = A x + B u` without lifting (N = nx).
    pub fn linear(a: Mat<f64>, b: Mat<f64>) -> Result<Self> {
        let nx = a.nrows();
        Self::new(a, b, Mat::zeros(0, nx), Vec::new())
    }

    /// A random stable model: A with spectral radius ≤ `radius` (a scaled random orthogonal
    /// matrix mixed with a contraction), B, F ~ N(0, 1/nx), deterministic from `seed`.
    pub fn random_stable(
        nx: usize,
        latent: usize,
        nu: usize,
        radius: f64,
        seed: u64,
    ) -> Result<Self> {
        if latent < nx {
            return Err(Error::InvalidArgument(format!("latent {latent} < nx {nx}")));
        }
        let mut rng = Rng::new(seed);
        let w = Mat::from_fn(latent, latent, |_, _| rng.normal());
        let qr = w.qr();
        let q = qr.compute_Q();
        // Orthogonal Q scaled by a diagonal in [0.5, 1]·radius keeps ‖A‖₂ ≤ radius.
        let scales: Vec<f64> = (0..latent)
            .map(|_| radius * rng.uniform(0.5, 1.0))
            .collect();
        let a = Mat::from_fn(latent, latent, |i, j| q[(i, j)] * scales[j]);
        let b = Mat::from_fn(latent, nu, |_, _| rng.normal() / (latent as f64).sqrt());
        let s = 1.0 / (nx as f64).sqrt();
        let f = Mat::from_fn(latent - nx, nx, |_, _| rng.normal() * s);
        let c = (0..latent - nx).map(|_| rng.uniform(-0.5, 0.5)).collect();
        Self::new(a, b, f, c)
    }
}

impl LiftedModel for MatrixModel {
    fn nx(&self) -> usize {
        self.nx
    }
    fn nu(&self) -> usize {
        self.b.ncols()
    }
    fn latent_dim(&self) -> usize {
        self.a.nrows()
    }
    fn a(&self) -> Mat<f64> {
        self.a.clone()
    }
    fn b(&self) -> Mat<f64> {
        self.b.clone()
    }
    fn lift(&self, x: &[f64]) -> Vec<f64> {
        let mut z = Vec::with_capacity(self.latent_dim());
        z.extend_from_slice(x);
        for i in 0..self.features.nrows() {
            let mut s = self.offsets[i];
            for (j, &xj) in x.iter().enumerate() {
                s += self.features[(i, j)] * xj;
            }
            z.push(match self.activation {
                Activation::Tanh => s.tanh(),
                Activation::Cos => s.cos(),
            });
        }
        z
    }
}
