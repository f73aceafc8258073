//! The NNDM baseline of the paper's ablation: an MLP one-step model `x⁺ = x + g([x, u])` with
//! f64 inference, save/load, and the random-shooting MPC's [`OneStepModel`] interface.
//!
//! `g` is an MLP on the concatenated state and input with ReLU hidden layers and a linear output
//! layer. It predicts the *increment* `x⁺ − x` rather than `x⁺` itself: a standard choice that
//! is better conditioned (at initialisation the model is close to the identity map, which one
//! step of a sampled system nearly is), and that costs no parameters. Its hidden widths are
//! chosen so that its parameter count matches the Koopman model of the same configuration
//! ([`NndmArch::matching_koopman`]).

pub mod arch;
pub mod mlp;

pub use arch::NndmArch;

use super::store::{self, Tensor};
use crate::mpc::OneStepModel;
use crate::rng::Rng;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Version of the on-disk format written by [`NndmModel::save`].
pub const FORMAT_VERSION: u32 = 1;

/// An NNDM with f64 weights.
#[derive(Clone, Debug, PartialEq)]
pub struct NndmModel {
    arch: NndmArch,
    params: Vec<f64>,
    /// Free-form metadata saved in `config.json` (training configuration, metrics, data).
    pub metadata: serde_json::Value,
}

/// The `config.json` of a saved NNDM.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct ConfigFile {
    kind: String,
    format_version: u32,
    nx: usize,
    nu: usize,
    hidden: Vec<usize>,
    widths: Vec<usize>,
    num_params: usize,
    /// Always `null`: states and inputs are in raw units.
    normalisation: Option<serde_json::Value>,
    model: String,
    #[serde(default)]
    metadata: serde_json::Value,
}

/// Fresh f64 parameters for `arch` ([`NndmArch::layout`] order): every weight and bias
/// `U(±1/√fan_in)`, torch's `nn.Linear` default, drawn layer by layer (weights, then bias).
pub fn init_params(arch: &NndmArch, rng: &mut Rng) -> Result<Vec<f64>> {
    arch.check()?;
    let mut p = vec![0.0; arch.num_params()];
    for lay in arch.layout() {
        let bound = 1.0 / (lay.fan_in as f64).sqrt();
        for v in &mut p[lay.w..lay.b + lay.out] {
            *v = rng.uniform(-bound, bound);
        }
    }
    Ok(p)
}

/// `Σ a_i b_i` with 8 independent partial sums (vectorises).
#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0f64; 8];
    let (ac, bc) = (a.chunks_exact(8), b.chunks_exact(8));
    let (ar, br) = (ac.remainder(), bc.remainder());
    for (x, y) in ac.zip(bc) {
        for i in 0..8 {
            acc[i] += x[i] * y[i];
        }
    }
    let tail: f64 = ar.iter().zip(br).map(|(x, y)| x * y).sum();
    acc.iter().sum::<f64>() + tail
}

impl NndmModel {
    /// A model from flat parameters in [`NndmArch::layout`] order.
    pub fn from_params(arch: NndmArch, params: Vec<f64>) -> Result<Self> {
        arch.check()?;
        let len = arch.num_params();
        if params.len() != len {
            return Err(Error::dimension("NNDM parameters", len, params.len()));
        }
        crate::error::ensure_finite("NNDM parameters", &params)?;
        Ok(NndmModel {
            arch,
            params,
            metadata: serde_json::Value::Null,
        })
    }

    /// A freshly initialised model from `seed`.
    pub fn init(arch: NndmArch, seed: u64) -> Result<Self> {
        let params = init_params(&arch, &mut Rng::new(seed))?;
        Self::from_params(arch, params)
    }

    /// The architecture.
    pub fn arch(&self) -> &NndmArch {
        &self.arch
    }

    /// The flat parameters.
    pub fn params(&self) -> &[f64] {
        &self.params
    }

    /// Number of parameters.
    pub fn num_params(&self) -> usize {
        self.params.len()
    }

    /// One step `x⁺ = x + g([x, u])`, checked: wrong lengths or non-finite values are errors.
    pub fn step(&self, x: &[f64], u: &[f64]) -> Result<Vec<f64>> {
        if x.len() != self.arch.nx {
            return Err(Error::dimension("NNDM state", self.arch.nx, x.len()));
        }
        if u.len() != self.arch.nu {
            return Err(Error::dimension("NNDM input", self.arch.nu, u.len()));
        }
        crate::error::ensure_finite("NNDM state", x)?;
        crate::error::ensure_finite("NNDM input", u)?;
        let mut next = vec![0.0; self.arch.nx];
        self.step_into(x, u, &mut next);
        Ok(next)
    }

    /// Unchecked [`NndmModel::step`] into `next` (lengths nx, nu, nx; panics otherwise).
    pub fn step_into(&self, x: &[f64], u: &[f64], next: &mut [f64]) {
        let layers = self.arch.layout();
        let last = layers.len() - 1;
        let mut h: Vec<f64> = x.iter().chain(u).copied().collect();
        let mut y = Vec::new();
        for (l, lay) in layers.iter().enumerate() {
            y.clear();
            y.extend((0..lay.out).map(|i| {
                let row = &self.params[lay.w + i * lay.fan_in..lay.w + (i + 1) * lay.fan_in];
                let v = dot(row, &h) + self.params[lay.b + i];
                if l < last {
                    v.max(0.0)
                } else {
                    v
                }
            }));
            std::mem::swap(&mut h, &mut y);
        }
        for ((n, xi), gi) in next.iter_mut().zip(x).zip(&h) {
            *n = xi + gi;
        }
    }

    /// Saves `model.safetensors` (`mlp.{l}.weight` `[out, in]`, `mlp.{l}.bias` `[out]`) and
    /// `config.json` (with `"kind": "nndm"`) into `dir`, creating it if needed; each file is
    /// written atomically.
    pub fn save(&self, dir: &Path) -> Result<()> {
        store::ensure_dir(dir)?;
        let mut tensors = Vec::new();
        for (l, lay) in self.arch.layout().iter().enumerate() {
            tensors.push(Tensor {
                name: format!("mlp.{l}.weight"),
                shape: vec![lay.out, lay.fan_in],
                data: self.params[lay.w..lay.b].to_vec(),
            });
            tensors.push(Tensor {
                name: format!("mlp.{l}.bias"),
                shape: vec![lay.out],
                data: self.params[lay.b..lay.b + lay.out].to_vec(),
            });
        }
        crate::fsutil::write_atomic(
            &dir.join("model.safetensors"),
            &store::to_safetensors(&tensors)?,
        )?;
        let cfg = ConfigFile {
            kind: "nndm".into(),
            format_version: FORMAT_VERSION,
            nx: self.arch.nx,
            nu: self.arch.nu,
            hidden: self.arch.hidden.clone(),
            widths: self.arch.widths(),
            num_params: self.num_params(),
            normalisation: None,
            model:
                "x+ = x + g([x, u]); g = MLP with ReLU after every hidden layer, linear output; \
                    layer l: y = W_l h + b_l, tensors row-major [out, in]"
                    .into(),
            metadata: self.metadata.clone(),
        };
        let json =
            serde_json::to_vec_pretty(&cfg).map_err(|e| Error::InvalidArgument(e.to_string()))?;
        crate::fsutil::write_atomic(&dir.join("config.json"), &json)
    }

    /// Loads a model saved by [`NndmModel::save`] (F32 or F64 tensors).
    pub fn load(dir: &Path) -> Result<Self> {
        let (value, cfg_path) = store::read_config_checked(dir, "nndm", FORMAT_VERSION, "an NNDM")?;
        store::refuse_normalisation(&value, &cfg_path, "an NNDM")?;
        let cfg: ConfigFile = serde_json::from_value(value)
            .map_err(|e| Error::format(&cfg_path, format!("not an NNDM config: {e}")))?;
        let arch = NndmArch::new(cfg.nx, cfg.nu, &cfg.hidden)
            .map_err(|e| Error::format(&cfg_path, e.to_string()))?;
        if arch.widths() != cfg.widths || arch.num_params() != cfg.num_params {
            return Err(Error::format(
                &cfg_path,
                "widths/num_params disagree with nx, nu and hidden",
            ));
        }
        let st_path = dir.join("model.safetensors");
        let bytes = store::read_file(&st_path)?;
        let st = safetensors::SafeTensors::deserialize(&bytes)
            .map_err(|e| Error::format(&st_path, format!("not a safetensors file: {e}")))?;
        let mut params = vec![0.0; arch.num_params()];
        for (l, lay) in arch.layout().iter().enumerate() {
            let w = store::read_tensor(
                &st,
                &st_path,
                &format!("mlp.{l}.weight"),
                &[lay.out, lay.fan_in],
            )?;
            params[lay.w..lay.b].copy_from_slice(&w);
            let b = store::read_tensor(&st, &st_path, &format!("mlp.{l}.bias"), &[lay.out])?;
            params[lay.b..lay.b + lay.out].copy_from_slice(&b);
        }
        let mut model = Self::from_params(arch, params)?;
        model.metadata = cfg.metadata;
        Ok(model)
    }
}

impl OneStepModel for NndmModel {
    fn nx(&self) -> usize {
        self.arch.nx
    }
    fn nu(&self) -> usize {
        self.arch.nu
    }
    /// Panics on wrong lengths (use [`NndmModel::step`] for a checked version).
    fn predict(&self, x: &[f64], u: &[f64], next: &mut [f64]) {
        self.step_into(x, u, next);
    }

    /// All rows through the MLP at once (one GEMM per layer, sequential: callers parallelise
    /// over chunks); allocates the activation buffers of `rows` rows per call.
    fn predict_rows(&self, xs: &[f64], us: &[f64], next: &mut [f64]) {
        let (nx, nu) = (self.arch.nx, self.arch.nu);
        let rows = next.len() / nx.max(1);
        if rows == 0 {
            return;
        }
        let mut bufs = mlp::MlpBufs::<f64>::new(&self.arch, rows, rows);
        let input = bufs.input_mut(); // column-major rows × (nx + nu)
        for i in 0..rows {
            for j in 0..nx {
                input[j * rows + i] = xs[i * nx + j];
            }
            for j in 0..nu {
                input[(nx + j) * rows + i] = us[i * nu + j];
            }
        }
        bufs.forward_block(&self.params, 0, rows);
        let out = bufs.output(); // column-major rows × nx: the increment g
        for i in 0..rows {
            for j in 0..nx {
                next[i * nx + j] = xs[i * nx + j] + out[j * rows + i];
            }
        }
    }
}
