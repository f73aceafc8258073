//! What travels in the FMU's `resources/`: the controller file (`controller.json`: names, units,
//! step, reference, MPC settings) next to the saved model (`model/`), and the MPC file the
//! export command reads (`--mpc mpc.toml`).

use std::path::{Path, PathBuf};

use koopman::mpc::{MpcConfig, OffsetFreeConfig};
use serde::{Deserialize, Serialize};

/// Version of `resources/controller.json`'s format.
pub const FORMAT_VERSION: u32 = 1;
/// The controller file's name inside `resources/`.
pub const CONTROLLER_FILE: &str = "controller.json";
/// The model folder's name inside `resources/`.
pub const MODEL_DIR: &str = "model";
/// The largest horizon the FMU's `horizon` parameter accepts.
pub const MAX_HORIZON: i32 = 10_000;

/// The MPC file of `koopbridge export-fmu --mpc FILE` (TOML), shaped like the MPC service's
/// `configure` request: the reference, the MPC settings, the offset-free correction.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MpcFile {
    /// The reference state (nx values) the FMU's reference inputs start at; `None` = zeros.
    pub reference: Option<Vec<f64>>,
    /// The MPC settings (SPEC defaults for absent fields; [`MpcConfig`]).
    pub mpc: MpcConfig,
    /// The offset-free correction of the MPC (lifted-linear or bilinear models; refused for an
    /// NNDM).
    pub offset_free: Option<OffsetFreeConfig>,
}

/// `resources/controller.json`: everything the FMU needs besides the model's own files.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControllerFile {
    /// [`FORMAT_VERSION`].
    pub format_version: u32,
    /// The instantiation token (FMI 3) / GUID (FMI 2) of the model description it belongs to.
    pub token: String,
    /// The model's kind (`koopman`, `edmd`, `bilinear`, `nndm`).
    pub model_kind: String,
    /// Names of the measured state's components (the state inputs), nx.
    pub state_names: Vec<String>,
    /// Names of the commands (the outputs), nu.
    pub input_names: Vec<String>,
    /// Units of the state components (`None`: not known), nx.
    pub state_units: Vec<Option<String>>,
    /// Units of the commands, nu.
    pub input_units: Vec<Option<String>>,
    /// The model's sampling period in seconds: the communication step it was trained for.
    pub dt: f64,
    /// The reference the reference inputs start at, nx.
    pub reference: Vec<f64>,
    /// The MPC settings.
    pub mpc: MpcConfig,
    /// The offset-free correction (lifted-linear or bilinear models).
    pub offset_free: Option<OffsetFreeConfig>,
}

impl ControllerFile {
    /// Reads `resources/controller.json` from the folder `resources`.
    ///
    /// Errors: a message naming the missing or malformed file.
    pub fn read(resources: &Path) -> Result<Self, String> {
        let path = resources.join(CONTROLLER_FILE);
        let bytes = std::fs::read(&path).map_err(|e| {
            format!(
                "cannot read the FMU's controller file {}: {e}",
                path.display()
            )
        })?;
        let file: ControllerFile = serde_json::from_slice(&bytes)
            .map_err(|e| format!("{}: not a controller file: {e}", path.display()))?;
        if file.format_version != FORMAT_VERSION {
            return Err(format!(
                "{}: format_version {} (this FMU binary reads {FORMAT_VERSION})",
                path.display(),
                file.format_version
            ));
        }
        Ok(file)
    }

    /// The model folder inside `resources`.
    pub fn model_dir(resources: &Path) -> PathBuf {
        resources.join(MODEL_DIR)
    }

    /// Checks the lengths against the model's `nx` and `nu`, the names (unique, non-empty, of
    /// the characters `[A-Za-z0-9_.]`), the step and the reference.
    pub fn check(&self, nx: usize, nu: usize) -> Result<(), String> {
        let len = |what: &str, got: usize, want: usize| {
            if got == want {
                Ok(())
            } else {
                Err(format!("{what}: {got} values for a model with {want}"))
            }
        };
        len("state_names", self.state_names.len(), nx)?;
        len("state_units", self.state_units.len(), nx)?;
        len("reference", self.reference.len(), nx)?;
        len("input_names", self.input_names.len(), nu)?;
        len("input_units", self.input_units.len(), nu)?;
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return Err(format!(
                "dt must be a positive number of seconds, got {}",
                self.dt
            ));
        }
        if self.reference.iter().any(|v| !v.is_finite()) {
            return Err(format!(
                "the reference must be finite, got {:?}",
                self.reference
            ));
        }
        for n in self.state_names.iter().chain(&self.input_names) {
            let ok = !n.is_empty()
                && n.chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '.')
                && !n.starts_with(|c: char| c.is_ascii_digit());
            if !ok {
                return Err(format!(
                    "variable name '{n}': use letters, digits, '_' and '.', not starting with a digit"
                ));
            }
        }
        Ok(())
    }
}

/// The controller file for the model saved in `model_dir` with the settings of `mpc`: names
/// and step from the model's training metadata (`x0…`, `u0…` and `dt` = `fallback_dt` when it
/// has none), `units` by variable name, the token a hash of the model's files and the
/// settings. Checks the settings by building the controller once.
///
/// Errors: a model that does not load, settings the controller refuses, a reference of the
/// wrong length, a unit for a name that is not a state or an input.
pub fn controller_file(
    model_dir: &Path,
    mpc: &MpcFile,
    units: &[(String, String)],
    fallback_dt: Option<f64>,
) -> Result<ControllerFile, String> {
    let model = koopman::mpc::LoadedModel::load(model_dir).map_err(|e| e.to_string())?;
    let (nx, nu) = (model.nx(), model.nu());
    let config = koopman::model::store::read_config(model_dir).map_err(|e| e.to_string())?;
    let kind = config["kind"].as_str().unwrap_or("koopman").to_string();
    let data = &config["metadata"]["dataset"];
    let names = |key: &str, n: usize, prefix: &str| -> Vec<String> {
        data[key]
            .as_array()
            .filter(|a| a.len() == n)
            .and_then(|a| a.iter().map(|v| v.as_str().map(str::to_string)).collect())
            .unwrap_or_else(|| (0..n).map(|i| format!("{prefix}{i}")).collect())
    };
    let state_names = names("state_names", nx, "x");
    let input_names = names("input_names", nu, "u");
    let dt = data["dt"].as_f64().or(fallback_dt).ok_or_else(|| {
        format!(
            "{}: the model's metadata has no sampling period (dataset.dt); give it with --dt",
            model_dir.display()
        )
    })?;
    for (name, _) in units {
        if !state_names.contains(name) && !input_names.contains(name) {
            return Err(format!(
                "--unit {name}=…: no state or input is named '{name}' (states: {}; inputs: {})",
                state_names.join(", "),
                input_names.join(", ")
            ));
        }
    }
    let unit_of = |n: &String| {
        units
            .iter()
            .rev()
            .find(|(k, _)| k == n)
            .map(|(_, u)| u.clone())
    };
    let reference = mpc.reference.clone().unwrap_or_else(|| vec![0.0; nx]);
    model
        .controller(&mpc.mpc, mpc.offset_free.as_ref())
        .map_err(|e| format!("the MPC settings do not fit the model: {e}"))?;
    let mut file = ControllerFile {
        format_version: FORMAT_VERSION,
        token: String::new(),
        model_kind: kind,
        state_units: state_names.iter().map(unit_of).collect(),
        input_units: input_names.iter().map(unit_of).collect(),
        state_names,
        input_names,
        dt,
        reference,
        mpc: mpc.mpc.clone(),
        offset_free: mpc.offset_free.clone(),
    };
    file.check(nx, nu)?;
    let mut bytes = serde_json::to_vec(&file).map_err(|e| e.to_string())?;
    for f in model_files(model_dir)? {
        bytes.extend(std::fs::read(&f).map_err(|e| format!("{}: {e}", f.display()))?);
    }
    file.token = token(&bytes);
    Ok(file)
}

/// The model's files that travel in `resources/model/`: every regular file at the top of
/// `dir` except plots (`.png`, `.svg`) and hidden files, in name order.
pub fn model_files(dir: &Path) -> Result<Vec<PathBuf>, String> {
    let entries = std::fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let mut files = Vec::new();
    for e in entries {
        let p = e.map_err(|e| format!("{}: {e}", dir.display()))?.path();
        let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
        let plot = name.ends_with(".png") || name.ends_with(".svg");
        if p.is_file() && !plot && !name.starts_with('.') {
            files.push(p);
        }
    }
    files.sort();
    Ok(files)
}

/// A GUID-shaped token from two FNV-1a hashes of `bytes`.
fn token(bytes: &[u8]) -> String {
    let fnv = |seed: u64| {
        bytes.iter().fold(seed, |h, b| {
            (h ^ u64::from(*b)).wrapping_mul(0x100_0000_01b3)
        })
    };
    let (a, b) = (fnv(0xcbf2_9ce4_8422_2325), fnv(0x6c62_272e_07bb_0142));
    format!(
        "{{{:08x}-{:04x}-{:04x}-{:04x}-{:012x}}}",
        a >> 32,
        (a >> 16) & 0xffff,
        a & 0xffff,
        b >> 48,
        b & 0xffff_ffff_ffff
    )
}
