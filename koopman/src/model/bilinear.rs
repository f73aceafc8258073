//! The bilinear Koopman model `z = [x, ψ(x)]`, `z⁺ = A z + B u + Σ_i u_i N_i z`: SPEC's encoder,
//! A and B (a [`KoopmanModel`]) plus one N × N matrix per input; save, load, one-step prediction.

use super::arch::Arch;
use super::koopman::KoopmanModel;
use super::store::{self, Tensor};
use super::LiftedModel;
use crate::mpc::OneStepModel;
use crate::{Error, Result};
use faer::{Mat, MatRef};
use std::path::Path;

/// A bilinear Koopman model with f64 weights. With every N_i = 0 it is SPEC's linear model.
#[derive(Clone, Debug, PartialEq)]
pub struct BilinearModel {
    linear: KoopmanModel,
    /// N_1..N_nu, row-major N × N each.
    n: Vec<f64>,
    /// Free-form metadata saved in `config.json` (training configuration, metrics, data).
    pub metadata: serde_json::Value,
}

impl BilinearModel {
    /// The model from its linear part and the N_i (`nu·N²` values, row-major N × N each).
    ///
    /// Errors: no inputs (`nu = 0`), a wrong number of N values, or a non-finite one.
    pub fn from_parts(linear: KoopmanModel, n: Vec<f64>) -> Result<Self> {
        let arch = linear.arch();
        if arch.nu == 0 {
            return Err(Error::InvalidArgument(
                "a bilinear model needs at least one input (nu = 0)".into(),
            ));
        }
        let want = crate::train::bilinear::bilinear_len(arch);
        if n.len() != want {
            return Err(Error::dimension("bilinear matrices N_i", want, n.len()));
        }
        crate::error::ensure_finite("bilinear matrices N_i", &n)?;
        Ok(BilinearModel {
            linear,
            n,
            metadata: serde_json::Value::Null,
        })
    }

    /// The model from one flat vector: the linear model's parameters ([`Arch::layout`] order)
    /// followed by N_1..N_nu (the trainer's layout).
    pub fn from_params(arch: Arch, mut params: Vec<f64>) -> Result<Self> {
        let lin = arch.num_params();
        if params.len() < lin {
            return Err(Error::dimension(
                "bilinear model parameters",
                lin + crate::train::bilinear::bilinear_len(&arch),
                params.len(),
            ));
        }
        let n = params.split_off(lin);
        Self::from_parts(KoopmanModel::from_params(arch, params)?, n)
    }

    /// A freshly initialised model: SPEC's initialisation from `seed` (the same encoder, A and B
    /// as [`KoopmanModel::init`]) and every N_i = 0.
    pub fn init(arch: Arch, seed: u64) -> Result<Self> {
        let len = crate::train::bilinear::bilinear_len(&arch);
        Self::from_parts(KoopmanModel::init(arch, seed)?, vec![0.0; len])
    }

    /// The linear part (encoder, A, B).
    pub fn linear(&self) -> &KoopmanModel {
        &self.linear
    }

    /// The architecture.
    pub fn arch(&self) -> &Arch {
        self.linear.arch()
    }

    /// State dimension nx.
    pub fn nx(&self) -> usize {
        self.arch().nx
    }

    /// Input dimension nu.
    pub fn nu(&self) -> usize {
        self.arch().nu
    }

    /// Latent dimension N.
    pub fn latent_dim(&self) -> usize {
        self.arch().latent_dim()
    }

    /// N_i (N × N) as a view, `i < nu`.
    pub fn n_mat(&self, i: usize) -> MatRef<'_, f64> {
        let nn = self.latent_dim();
        MatRef::from_row_major_slice(&self.n[i * nn * nn..(i + 1) * nn * nn], nn, nn)
    }

    /// N_1..N_nu as one slice (row-major N × N each).
    pub fn n_flat(&self) -> &[f64] {
        &self.n
    }

    /// The flat parameter vector (linear parameters, then the N_i), as the trainer uses it.
    pub fn params(&self) -> Vec<f64> {
        let mut p = self.linear.params().to_vec();
        p.extend_from_slice(&self.n);
        p
    }

    /// Lifts a state: `z = Φ(x)` (panics on a state of the wrong length, like
    /// [`LiftedModel::lift`]).
    pub fn lift(&self, x: &[f64]) -> Vec<f64> {
        self.linear.lift(x)
    }

    /// Checked [`BilinearModel::lift`] (typed errors for a wrong length or non-finite values).
    pub fn try_lift(&self, x: &[f64]) -> Result<Vec<f64>> {
        self.linear.try_lift(x)
    }

    /// One latent step `out = A z + B u + Σ_i u_i N_i z` (`z`, `out`: N values; `u`: nu).
    pub fn step(&self, z: &[f64], u: &[f64], out: &mut [f64]) {
        let nn = self.latent_dim();
        let (a, b) = (self.linear.a_ref(), self.linear.b_ref());
        for (r, o) in out.iter_mut().enumerate().take(nn) {
            let mut s = 0.0;
            for (c, &zc) in z.iter().enumerate() {
                s += a[(r, c)] * zc;
            }
            for (i, &ui) in u.iter().enumerate() {
                s += b[(r, i)] * ui;
                if ui != 0.0 {
                    let row = &self.n[i * nn * nn + r * nn..i * nn * nn + (r + 1) * nn];
                    s += ui * row.iter().zip(z).map(|(n, z)| n * z).sum::<f64>();
                }
            }
            *o = s;
        }
    }

    /// The input matrix at `z`: `B(z) = B + [N_1 z … N_nu z]` (N × nu).
    pub fn input_matrix(&self, z: &[f64]) -> Mat<f64> {
        let nn = self.latent_dim();
        let b = self.linear.b_ref();
        Mat::from_fn(nn, self.nu(), |r, i| {
            let row = &self.n[i * nn * nn + r * nn..i * nn * nn + (r + 1) * nn];
            b[(r, i)] + row.iter().zip(z).map(|(n, z)| n * z).sum::<f64>()
        })
    }

    /// The model linearised at `(z, u)`: `A(u) = A + Σ_i u_i N_i`, `B(z) = B + [N_i z]`, with the
    /// same lifting — a [`LiftedModel`], so gain diagnostics and LQR apply at an operating point.
    pub fn linearised(&self, z: &[f64], u: &[f64]) -> Result<Linearised<'_>> {
        let nn = self.latent_dim();
        if z.len() != nn {
            return Err(Error::dimension("lifted state", nn, z.len()));
        }
        if u.len() != self.nu() {
            return Err(Error::dimension("input", self.nu(), u.len()));
        }
        crate::error::ensure_finite("operating point", z)?;
        crate::error::ensure_finite("operating point", u)?;
        let a0 = self.linear.a_ref();
        let a = Mat::from_fn(nn, nn, |r, c| {
            a0[(r, c)]
                + u.iter()
                    .enumerate()
                    .map(|(i, ui)| ui * self.n[i * nn * nn + r * nn + c])
                    .sum::<f64>()
        });
        Ok(Linearised {
            model: self,
            a,
            b: self.input_matrix(z),
        })
    }

    /// Saves `model.safetensors` (the linear model's tensors and `N`, shape `[nu, N, N]`) and
    /// `config.json` (`"kind": "bilinear"`) into `dir`; each file is written atomically.
    pub fn save(&self, dir: &Path) -> Result<()> {
        let nn = self.latent_dim();
        let n = Tensor {
            name: "N".into(),
            shape: vec![self.nu(), nn, nn],
            data: self.n.clone(),
        };
        self.linear
            .save_kind(dir, "bilinear", vec![n], &self.metadata)
    }

    /// Loads a model saved by [`BilinearModel::save`] (F32 or F64 tensors).
    ///
    /// Errors: `Format` for a wrong kind or an `N` of the wrong shape, `NonFinite` for NaN or
    /// infinite values, besides the errors of [`KoopmanModel::load`].
    pub fn load(dir: &Path) -> Result<Self> {
        let (mut linear, n) = KoopmanModel::load_kind(
            dir,
            "bilinear",
            "a bilinear Koopman model",
            |st, path, arch| {
                let nn = arch.latent_dim();
                store::read_tensor(st, path, "N", &[arch.nu, nn, nn])
            },
        )?;
        let meta = std::mem::take(&mut linear.metadata);
        let mut model = Self::from_parts(linear, n)?;
        model.metadata = meta;
        Ok(model)
    }
}

/// One-step prediction through the latent space: `x⁺ = P (A Φ(x) + B u + Σ u_i N_i Φ(x))`, so
/// random shooting and the closed-loop machinery can use the model.
impl OneStepModel for BilinearModel {
    fn nx(&self) -> usize {
        self.arch().nx
    }
    fn nu(&self) -> usize {
        self.arch().nu
    }
    fn predict(&self, x: &[f64], u: &[f64], next: &mut [f64]) {
        let z = self.lift(x);
        let mut zn = vec![0.0; z.len()];
        self.step(&z, u, &mut zn);
        let nx = next.len();
        next.copy_from_slice(&zn[..nx]);
    }
}

/// A [`BilinearModel`] linearised at an operating point (see [`BilinearModel::linearised`]).
pub struct Linearised<'m> {
    model: &'m BilinearModel,
    a: Mat<f64>,
    b: Mat<f64>,
}

impl LiftedModel for Linearised<'_> {
    fn nx(&self) -> usize {
        self.model.nx()
    }
    fn nu(&self) -> usize {
        self.model.nu()
    }
    fn latent_dim(&self) -> usize {
        self.model.latent_dim()
    }
    fn a(&self) -> Mat<f64> {
        self.a.clone()
    }
    fn b(&self) -> Mat<f64> {
        self.b.clone()
    }
    fn lift(&self, x: &[f64]) -> Vec<f64> {
        self.model.lift(x)
    }
}
