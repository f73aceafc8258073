//! The safetensors + `config.json` files that models are saved as (written with
//! [`crate::fsutil::write_atomic`]).

use crate::{Error, Result};
use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use std::path::Path;

/// Creates `dir` (and its parents) if needed.
pub fn ensure_dir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))
}

/// A named f64 tensor to save.
pub struct Tensor {
    /// Name in the file.
    pub name: String,
    /// Shape (row-major).
    pub shape: Vec<usize>,
    /// Values, row-major.
    pub data: Vec<f64>,
}

/// Serialises f64 tensors into safetensors bytes.
pub fn to_safetensors(tensors: &[Tensor]) -> Result<Vec<u8>> {
    let bytes: Vec<Vec<u8>> = tensors
        .iter()
        .map(|t| t.data.iter().flat_map(|v| v.to_le_bytes()).collect())
        .collect();
    let mut views = Vec::with_capacity(tensors.len());
    for (t, b) in tensors.iter().zip(&bytes) {
        let view = TensorView::new(Dtype::F64, t.shape.clone(), b)
            .map_err(|e| Error::InvalidArgument(format!("tensor {}: {e}", t.name)))?;
        views.push((t.name.clone(), view));
    }
    safetensors::serialize(views, None)
        .map_err(|e| Error::InvalidArgument(format!("safetensors serialisation: {e}")))
}

/// Reads one tensor (F32 or F64) of the expected shape from parsed safetensors, as f64.
pub fn read_tensor(
    st: &SafeTensors<'_>,
    path: &Path,
    name: &str,
    shape: &[usize],
) -> Result<Vec<f64>> {
    let t = st
        .tensor(name)
        .map_err(|e| Error::format(path, format!("tensor '{name}': {e}")))?;
    if t.shape() != shape {
        return Err(Error::format(
            path,
            format!(
                "tensor '{name}' has shape {:?}, expected {:?}",
                t.shape(),
                shape
            ),
        ));
    }
    let data = t.data();
    let values: Vec<f64> = match t.dtype() {
        Dtype::F64 => data
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect(),
        Dtype::F32 => data
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")) as f64)
            .collect(),
        other => {
            return Err(Error::format(
                path,
                format!("tensor '{name}' has dtype {other:?}, expected F32 or F64"),
            ))
        }
    };
    if values.iter().any(|v| !v.is_finite()) {
        return Err(Error::NonFinite(format!(
            "{}: tensor '{name}'",
            path.display()
        )));
    }
    Ok(values)
}

/// Reads a whole file.
pub fn read_file(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| Error::io(path, e))
}

/// Reads and parses `config.json` in `dir`.
pub fn read_config(dir: &Path) -> Result<serde_json::Value> {
    let path = dir.join("config.json");
    let bytes = read_file(&path)?;
    serde_json::from_slice(&bytes).map_err(|e| Error::format(&path, format!("invalid JSON: {e}")))
}

/// The `"kind"` field of `dir/config.json`.
pub fn read_kind(dir: &Path) -> Result<String> {
    let cfg = read_config(dir)?;
    cfg.get("kind")
        .and_then(|k| k.as_str())
        .map(str::to_string)
        .ok_or_else(|| Error::format(dir.join("config.json"), "no string field \"kind\""))
}

/// Reads `dir/config.json` and checks the header every saved model shares: `"kind"` equals
/// `kind` and `"format_version"` is not newer than `max_version`. `label` names the model in
/// errors (e.g. "a Koopman model"). Returns the parsed config for the caller's own fields, and
/// its path. Kinds without a normalisation layer refuse one with [`refuse_normalisation`].
pub fn read_config_checked(
    dir: &Path,
    kind: &str,
    max_version: u32,
    label: &str,
) -> Result<(serde_json::Value, std::path::PathBuf)> {
    let path = dir.join("config.json");
    let cfg = read_config(dir)?;
    let found = cfg.get("kind").and_then(|k| k.as_str());
    if found != Some(kind) {
        return Err(Error::format(
            &path,
            format!(
                "not {label} config: kind is {}, expected '{kind}'",
                found.map_or("missing".to_string(), |k| format!("'{k}'"))
            ),
        ));
    }
    match cfg.get("format_version").and_then(|v| v.as_u64()) {
        None => {
            return Err(Error::format(
                &path,
                format!("not {label} config: missing field `format_version`"),
            ))
        }
        Some(v) if v > u64::from(max_version) => {
            return Err(Error::format(
                &path,
                format!("format_version {v} is newer than this build"),
            ))
        }
        Some(_) => {}
    }
    Ok((cfg, path))
}

/// A format error when `cfg` carries a non-null `"normalisation"`: for the model kinds that have
/// no normalisation layer (`label` names the kind, e.g. "an NNDM").
pub fn refuse_normalisation(cfg: &serde_json::Value, path: &Path, label: &str) -> Result<()> {
    if cfg.get("normalisation").is_some_and(|n| !n.is_null()) {
        return Err(Error::format(
            path,
            format!("normalised data are not supported for {label}"),
        ));
    }
    Ok(())
}
