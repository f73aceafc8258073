//! Saving and loading [`EdmdModel`]s: `config.json` (`"kind": "edmd"`, dimensions, dictionary,
//! settings, fit diagnostics) and `model.safetensors` (f64 tensors `A` [N, N] and `B` [N, nu]),
//! each written atomically.

use super::{Dictionary, EdmdConfig, EdmdModel, FitInfo};
use crate::fsutil::write_atomic;
use crate::{Error, Result};
use faer::Mat;
use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The JSON written as `config.json`.
#[derive(Serialize, Deserialize)]
struct ConfigFile {
    kind: String,
    nx: usize,
    nu: usize,
    latent_dim: usize,
    dictionary: Dictionary,
    config: EdmdConfig,
    fit: FitInfo,
}

fn tensor_bytes(m: &Mat<f64>) -> Vec<u8> {
    let mut out = Vec::with_capacity(m.nrows() * m.ncols() * 8);
    for i in 0..m.nrows() {
        for j in 0..m.ncols() {
            out.extend_from_slice(&m[(i, j)].to_le_bytes());
        }
    }
    out
}

fn read_matrix(
    st: &SafeTensors<'_>,
    path: &Path,
    name: &str,
    r: usize,
    c: usize,
) -> Result<Mat<f64>> {
    let t = st
        .tensor(name)
        .map_err(|e| Error::format(path, format!("tensor '{name}': {e}")))?;
    if t.dtype() != Dtype::F64 || t.shape() != [r, c] {
        return Err(Error::format(
            path,
            format!(
                "tensor '{name}' is {:?} {:?}, expected F64 [{r}, {c}]",
                t.dtype(),
                t.shape()
            ),
        ));
    }
    let v: Vec<f64> = t
        .data()
        .chunks_exact(8)
        .map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes")))
        .collect();
    crate::error::ensure_finite(name, &v)?;
    Ok(Mat::from_fn(r, c, |i, j| v[i * c + j]))
}

impl EdmdModel {
    /// Writes `dir/config.json` and `dir/model.safetensors` (creating `dir`).
    pub fn save(&self, dir: &Path) -> Result<()> {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        let a = tensor_bytes(&self.a);
        let b = tensor_bytes(&self.b);
        let n = self.dict.len();
        let views = vec![
            (
                "A".to_string(),
                TensorView::new(Dtype::F64, vec![n, n], &a)
                    .map_err(|e| Error::InvalidArgument(format!("tensor A: {e}")))?,
            ),
            (
                "B".to_string(),
                TensorView::new(Dtype::F64, vec![n, self.nu], &b)
                    .map_err(|e| Error::InvalidArgument(format!("tensor B: {e}")))?,
            ),
        ];
        let bytes = safetensors::serialize(views, None)
            .map_err(|e| Error::InvalidArgument(format!("safetensors: {e}")))?;
        write_atomic(&dir.join("model.safetensors"), &bytes)?;
        let cfg = ConfigFile {
            kind: "edmd".into(),
            nx: self.dict.nx,
            nu: self.nu,
            latent_dim: n,
            dictionary: self.dict.clone(),
            config: self.config.clone(),
            fit: self.info.clone(),
        };
        let json = serde_json::to_vec_pretty(&cfg)
            .map_err(|e| Error::InvalidArgument(format!("config.json: {e}")))?;
        write_atomic(&dir.join("config.json"), &json)
    }

    /// Reads a model written by [`EdmdModel::save`].
    pub fn load(dir: &Path) -> Result<EdmdModel> {
        let cpath = dir.join("config.json");
        let text = std::fs::read(&cpath).map_err(|e| Error::io(&cpath, e))?;
        let cfg: ConfigFile = serde_json::from_slice(&text)
            .map_err(|e| Error::format(&cpath, format!("not an EDMD config: {e}")))?;
        if cfg.kind != "edmd" {
            return Err(Error::format(
                &cpath,
                format!("model kind is '{}', expected 'edmd'", cfg.kind),
            ));
        }
        let d = &cfg.dictionary;
        let n = d.len();
        if cfg.latent_dim != n
            || cfg.nx != d.nx
            || d.center.len() != d.nx
            || d.half_width.len() != d.nx
            || d.exponents
                .iter()
                .any(|e| e.len() != d.nx || e.iter().any(|&k| k as usize > d.degree))
            || d.half_width.iter().any(|h| h.is_nan() || *h <= 0.0)
        {
            return Err(Error::format(&cpath, "inconsistent dictionary dimensions"));
        }
        let wpath = dir.join("model.safetensors");
        let bytes = std::fs::read(&wpath).map_err(|e| Error::io(&wpath, e))?;
        let st = SafeTensors::deserialize(&bytes)
            .map_err(|e| Error::format(&wpath, format!("not a safetensors file: {e}")))?;
        let a = read_matrix(&st, &wpath, "A", n, n)?;
        let b = read_matrix(&st, &wpath, "B", n, cfg.nu)?;
        Ok(EdmdModel {
            dict: cfg.dictionary,
            nu: cfg.nu,
            a,
            b,
            config: cfg.config,
            info: cfg.fit,
        })
    }
}
