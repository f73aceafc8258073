//! The neural Koopman model for inference: f64 weights, lifting, A and B, save and load.

use super::arch::Arch;
use super::encoder::EncoderWs;
use super::init::init_params;
use super::store::{self, Tensor};
use super::LiftedModel;
use crate::data::Normalisation;
use crate::rng::Rng;
use crate::{Error, Result};
use faer::{Mat, MatRef, Par};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Version of the on-disk format written by [`KoopmanModel::save`].
pub const FORMAT_VERSION: u32 = 1;

/// A neural Koopman model `z = [x, ψ(x)]`, `z⁺ = A z + B u`, with f64 weights.
///
/// A model trained on z-scored data carries its [`Normalisation`]: its own coordinates (A, B,
/// [`LiftedModel::lift`]) are then the normalised ones, and
/// [`super::normalised::RawUnits`] presents it in raw units.
#[derive(Clone, Debug, PartialEq)]
pub struct KoopmanModel {
    arch: Arch,
    params: Vec<f64>,
    normalisation: Option<Normalisation>,
    /// Free-form metadata saved in `config.json` (training configuration, metrics, data).
    pub metadata: serde_json::Value,
}

/// The `config.json` of a saved Koopman model.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct ConfigFile {
    kind: String,
    format_version: u32,
    nx: usize,
    nu: usize,
    n_enc: usize,
    latent_dim: usize,
    widths: Vec<usize>,
    /// `null` for a model in raw units; the z-scoring of states and inputs it was trained with
    /// otherwise.
    #[serde(default)]
    normalisation: Option<Normalisation>,
    block: String,
    #[serde(default)]
    metadata: serde_json::Value,
}

impl KoopmanModel {
    /// A model from flat parameters in [`Arch::layout`] order.
    pub fn from_params(arch: Arch, params: Vec<f64>) -> Result<Self> {
        arch.check()?;
        let len = arch.num_params();
        if params.len() != len {
            return Err(Error::dimension(
                "Koopman model parameters",
                len,
                params.len(),
            ));
        }
        crate::error::ensure_finite("Koopman model parameters", &params)?;
        Ok(KoopmanModel {
            arch,
            params,
            normalisation: None,
            metadata: serde_json::Value::Null,
        })
    }

    /// The same model declared to work in the normalised coordinates of `norm` (checked against
    /// nx and nu).
    pub fn with_normalisation(mut self, norm: Normalisation) -> Result<Self> {
        norm.check(self.arch.nx, self.arch.nu)?;
        self.normalisation = Some(norm);
        Ok(self)
    }

    /// The z-scoring the model was trained with (`None`: raw units).
    pub fn normalisation(&self) -> Option<&Normalisation> {
        self.normalisation.as_ref()
    }

    /// A freshly initialised model (SPEC initialisation) from `seed`.
    pub fn init(arch: Arch, seed: u64) -> Result<Self> {
        let params = init_params(&arch, &mut Rng::new(seed))?;
        Self::from_params(arch, params)
    }

    /// The architecture.
    pub fn arch(&self) -> &Arch {
        &self.arch
    }

    /// The flat parameters.
    pub fn params(&self) -> &[f64] {
        &self.params
    }

    /// A as a view (N × N).
    pub fn a_ref(&self) -> MatRef<'_, f64> {
        let lay = self.arch.layout();
        let n = self.arch.latent_dim();
        MatRef::from_row_major_slice(&self.params[lay.a..lay.a + n * n], n, n)
    }

    /// B as a view (N × nu).
    pub fn b_ref(&self) -> MatRef<'_, f64> {
        let lay = self.arch.layout();
        let n = self.arch.latent_dim();
        MatRef::from_row_major_slice(
            &self.params[lay.b..lay.b + n * self.arch.nu],
            n,
            self.arch.nu,
        )
    }

    /// Lifts every row of `x` (rows × nx): returns `Z = [x, ψ(x)]` (rows × N).
    pub fn lift_rows(&self, x: MatRef<'_, f64>) -> Result<Mat<f64>> {
        let nx = self.arch.nx;
        if x.ncols() != nx {
            return Err(Error::dimension("state dimension", nx, x.ncols()));
        }
        let rows = x.nrows();
        let mut z = Mat::zeros(rows, self.arch.latent_dim());
        let chunk = rows.clamp(1, 4096);
        let mut ws = EncoderWs::<f64>::new(&self.arch, chunk, Par::Seq);
        let mut start = 0;
        while start < rows {
            let r = chunk.min(rows - start);
            let inp = ws.input_mut(r);
            for j in 0..nx {
                for i in 0..r {
                    inp[j * r + i] = x[(start + i, j)];
                }
            }
            ws.forward(&self.params);
            let psi = ws.output();
            for i in 0..r {
                for j in 0..nx {
                    z[(start + i, j)] = x[(start + i, j)];
                }
                for j in 0..psi.ncols() {
                    z[(start + i, nx + j)] = psi[(i, j)];
                }
            }
            start += r;
        }
        Ok(z)
    }

    /// Saves `model.safetensors` and `config.json` (with `"kind": "koopman"`) into `dir`,
    /// creating it if needed; each file is written atomically.
    pub fn save(&self, dir: &Path) -> Result<()> {
        self.save_kind(dir, "koopman", Vec::new(), &self.metadata)
    }

    /// [`KoopmanModel::save`] with another `"kind"`, `extra` tensors in the same file and the
    /// given metadata (for models that extend this one, e.g. the bilinear model).
    pub(crate) fn save_kind(
        &self,
        dir: &Path,
        kind: &str,
        extra: Vec<Tensor>,
        metadata: &serde_json::Value,
    ) -> Result<()> {
        store::ensure_dir(dir)?;
        let lay = self.arch.layout();
        let mut tensors = Vec::new();
        for (l, blk) in lay.blocks.iter().enumerate() {
            let (o, i) = (blk.out, blk.fan_in);
            let w = &self.params[blk.w..blk.w + blk.rows() * i];
            let b = &self.params[blk.b..blk.b + blk.rows()];
            tensors.push(Tensor {
                name: format!("encoder.{l}.weight"),
                shape: vec![o, i],
                data: w[..o * i].to_vec(),
            });
            tensors.push(Tensor {
                name: format!("encoder.{l}.bias"),
                shape: vec![o],
                data: b[..o].to_vec(),
            });
            if blk.linear_residual {
                tensors.push(Tensor {
                    name: format!("encoder.{l}.residual.weight"),
                    shape: vec![o, i],
                    data: w[o * i..].to_vec(),
                });
                tensors.push(Tensor {
                    name: format!("encoder.{l}.residual.bias"),
                    shape: vec![o],
                    data: b[o..].to_vec(),
                });
            }
        }
        let n = self.arch.latent_dim();
        tensors.push(Tensor {
            name: "A".into(),
            shape: vec![n, n],
            data: self.params[lay.a..lay.a + n * n].to_vec(),
        });
        if self.arch.nu > 0 {
            tensors.push(Tensor {
                name: "B".into(),
                shape: vec![n, self.arch.nu],
                data: self.params[lay.b..lay.len].to_vec(),
            });
        }
        tensors.extend(extra);
        crate::fsutil::write_atomic(
            &dir.join("model.safetensors"),
            &store::to_safetensors(&tensors)?,
        )?;
        let cfg = ConfigFile {
            kind: kind.into(),
            format_version: FORMAT_VERSION,
            nx: self.arch.nx,
            nu: self.arch.nu,
            n_enc: self.arch.n_enc(),
            latent_dim: n,
            widths: self.arch.widths.clone(),
            normalisation: self.normalisation.clone(),
            block: "y = relu(W x + b) + R(x); R linear with bias if widths differ, identity otherwise; \
                    z = [x, psi(x)]; z+ = A z + B u; tensors row-major [out, in]"
                .into(),
            metadata: metadata.clone(),
        };
        let json =
            serde_json::to_vec_pretty(&cfg).map_err(|e| Error::InvalidArgument(e.to_string()))?;
        crate::fsutil::write_atomic(&dir.join("config.json"), &json)
    }

    /// Loads a model saved by [`KoopmanModel::save`] (F32 or F64 tensors).
    pub fn load(dir: &Path) -> Result<Self> {
        Ok(Self::load_kind(dir, "koopman", "a Koopman model", |_, _, _| Ok(()))?.0)
    }

    /// [`KoopmanModel::load`] of a model saved with [`KoopmanModel::save_kind`]: checks
    /// `"kind"`, and `extra` reads the extending model's tensors from the same file.
    pub(crate) fn load_kind<X>(
        dir: &Path,
        kind: &str,
        label: &str,
        extra: impl FnOnce(&safetensors::SafeTensors<'_>, &Path, &Arch) -> Result<X>,
    ) -> Result<(Self, X)> {
        let (value, cfg_path) = store::read_config_checked(dir, kind, FORMAT_VERSION, label)?;
        let cfg: ConfigFile = serde_json::from_value(value)
            .map_err(|e| Error::format(&cfg_path, format!("not a Koopman model config: {e}")))?;
        let arch = Arch {
            nx: cfg.nx,
            nu: cfg.nu,
            widths: cfg.widths,
        };
        arch.check()
            .map_err(|e| Error::format(&cfg_path, e.to_string()))?;
        if arch.latent_dim() != cfg.latent_dim || arch.n_enc() != cfg.n_enc {
            return Err(Error::format(
                &cfg_path,
                "latent_dim/n_enc disagree with widths",
            ));
        }
        let st_path = dir.join("model.safetensors");
        let bytes = store::read_file(&st_path)?;
        let st = safetensors::SafeTensors::deserialize(&bytes)
            .map_err(|e| Error::format(&st_path, format!("not a safetensors file: {e}")))?;
        let lay = arch.layout();
        let mut params = vec![0.0; lay.len];
        for (l, blk) in lay.blocks.iter().enumerate() {
            let (o, i) = (blk.out, blk.fan_in);
            let w = store::read_tensor(&st, &st_path, &format!("encoder.{l}.weight"), &[o, i])?;
            params[blk.w..blk.w + o * i].copy_from_slice(&w);
            let b = store::read_tensor(&st, &st_path, &format!("encoder.{l}.bias"), &[o])?;
            params[blk.b..blk.b + o].copy_from_slice(&b);
            if blk.linear_residual {
                let w = store::read_tensor(
                    &st,
                    &st_path,
                    &format!("encoder.{l}.residual.weight"),
                    &[o, i],
                )?;
                params[blk.w + o * i..blk.w + 2 * o * i].copy_from_slice(&w);
                let b =
                    store::read_tensor(&st, &st_path, &format!("encoder.{l}.residual.bias"), &[o])?;
                params[blk.b + o..blk.b + 2 * o].copy_from_slice(&b);
            }
        }
        let n = arch.latent_dim();
        let a = store::read_tensor(&st, &st_path, "A", &[n, n])?;
        params[lay.a..lay.a + n * n].copy_from_slice(&a);
        if arch.nu > 0 {
            let b = store::read_tensor(&st, &st_path, "B", &[n, arch.nu])?;
            params[lay.b..lay.len].copy_from_slice(&b);
        }
        let x = extra(&st, &st_path, &arch)?;
        let mut model = Self::from_params(arch, params)?;
        if let Some(norm) = cfg.normalisation {
            if kind != "koopman" {
                return Err(Error::format(
                    &cfg_path,
                    format!("normalised data are not supported for {label}"),
                ));
            }
            model = model
                .with_normalisation(norm)
                .map_err(|e| Error::format(&cfg_path, e.to_string()))?;
        }
        model.metadata = cfg.metadata;
        Ok((model, x))
    }
}

impl LiftedModel for KoopmanModel {
    fn nx(&self) -> usize {
        self.arch.nx
    }
    fn nu(&self) -> usize {
        self.arch.nu
    }
    fn latent_dim(&self) -> usize {
        self.arch.latent_dim()
    }
    fn a(&self) -> Mat<f64> {
        self.a_ref().to_owned()
    }
    fn b(&self) -> Mat<f64> {
        self.b_ref().to_owned()
    }
    /// Panics if `x.len() != nx` (use [`KoopmanModel::lift_rows`] for a checked version).
    fn lift(&self, x: &[f64]) -> Vec<f64> {
        assert_eq!(x.len(), self.arch.nx, "lift: state of the wrong length");
        let mut ws = EncoderWs::<f64>::new(&self.arch, 1, Par::Seq);
        ws.input_mut(1).copy_from_slice(x);
        ws.forward(&self.params);
        let psi = ws.output();
        let mut z = x.to_vec();
        z.extend((0..psi.ncols()).map(|j| psi[(0, j)]));
        z
    }
}
