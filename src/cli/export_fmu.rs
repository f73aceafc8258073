//! `koopbridge export-fmu`: packs a trained model and its MPC settings with the controller
//! binary (`libkoopbridge_fmu.so`, crate `fmu/`) into an FMI 3.0 or FMI 2.0 co-simulation FMU.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use koopbridge_fmu::describe::{model_description, FmiVersion, Header};
use koopbridge_fmu::layout::Layout;
use koopbridge_fmu::settings::{self, MpcFile, CONTROLLER_FILE, MODEL_DIR};

/// The FMU's `modelIdentifier`: its binary is `binaries/<platform>/koopbridge_mpc.so`.
pub const MODEL_IDENTIFIER: &str = "koopbridge_mpc";
/// The file name cargo gives the controller binary.
pub const LIBRARY: &str = "libkoopbridge_fmu.so";

/// Arguments of `koopbridge export-fmu`.
#[derive(clap::Args)]
#[command(after_help = "\
The FMU (co-simulation, platform x86_64-linux for FMI 3 / linux64 for FMI 2) has:
  inputs      the measured state, one real per state, named after the model's state names
              (from its training data, else x0, x1, …), and the reference, one real per state
              (<name>_ref, starting at the MPC file's `reference`);
  outputs     the command, one real per input (named after the model's inputs, else u0, …),
              and mpc_status (0 solved, 1 inaccurate, 2 suboptimal, 3 fallback);
  parameters  q_<state>, r_<input> (diagonals of Q and R), u_min_<input>, u_max_<input>,
              horizon. All are `fixed`: each changes the condensed QP the controller builds,
              so they are set before initialisation ends (the controller is built in
              exitInitializationMode); none can change during the run without a rebuild.
At each doStep the FMU solves the MPC for the inputs as set and holds the first planned input
over the step (zero-order hold), as the MPC service does. A NaN or infinite input, an
out-of-range parameter or a failed solve is fmi3Error/fmi2Error with a logged message.

The MPC file (TOML) is shaped like the service's `configure` request:
  reference = [0.0, 0.0]            # optional, default zeros
  [mpc]                             # MpcConfig: horizon, q, r, terminal, u_min, u_max, solver, …
  horizon = 15
  u_min = [-8.0]
  u_max = [8.0]
  [offset_free]                     # optional: lifted-linear or bilinear models
  mode = \"trajectory\"
  radius = 1.0
  gain = [0.5, 0.5]

The controller binary is looked for next to the koopbridge executable (target/release/ after
`cargo build --release --workspace`, or `cargo build --release -p koopbridge-fmu`).

Examples:
  koopbridge export-fmu --model models/damped --mpc mpc.toml --out controller.fmu
  koopbridge export-fmu --bilinear models/damped-bil --mpc mpc.toml --fmi 2 --out controller2.fmu \\
      --unit theta=rad --unit theta_dot=rad/s --unit u=N.m")]
pub struct ExportFmuArgs {
    /// The trained model to plan with: a folder written by `koopbridge train` (koopman, edmd,
    /// bilinear or nndm; the kind is read from its config.json, as the MPC service does).
    #[arg(long, value_name = "DIR", required_unless_present = "bilinear")]
    model: Option<PathBuf>,
    /// A bilinear model (`koopbridge train --model bilinear`) to plan with by sequential convex
    /// MPC, as `koopbridge control --bilinear` does; use it instead of --model.
    #[arg(long, value_name = "DIR", conflicts_with = "model")]
    bilinear: Option<PathBuf>,
    /// The MPC file (TOML, see below): reference, [mpc] settings, [offset_free]. Default: SPEC's
    /// settings (H = 15, Q = I, R = 0, no bounds) and a zero reference.
    #[arg(long, value_name = "FILE")]
    mpc: Option<PathBuf>,
    /// The FMU to write (written to a temporary name, then renamed).
    #[arg(long, value_name = "FILE")]
    out: PathBuf,
    /// FMI version: 3 (FMI 3.0) or 2 (FMI 2.0).
    #[arg(long, default_value = "3", value_parser = ["3", "2"])]
    fmi: String,
    /// A variable's unit in the model description, e.g. `theta=rad`, `u=N.m` (a state or an
    /// input name; the reference and the bounds take the same unit). Repeatable.
    #[arg(long = "unit", value_name = "NAME=UNIT")]
    units: Vec<String>,
    /// The communication step in seconds, when the model's metadata does not say its
    /// sampling period (models trained by koopbridge do).
    #[arg(long, value_name = "SECONDS")]
    dt: Option<f64>,
    /// The controller binary to pack [default: libkoopbridge_fmu.so next to this executable].
    #[arg(long, value_name = "FILE")]
    library: Option<PathBuf>,
}

/// Runs `koopbridge export-fmu`.
pub fn run(args: ExportFmuArgs) -> anyhow::Result<()> {
    let model_dir = args
        .bilinear
        .clone()
        .or(args.model.clone())
        .context("give --model DIR or --bilinear DIR")?;
    let version = if args.fmi == "2" {
        FmiVersion::V2
    } else {
        FmiVersion::V3
    };
    let mpc: MpcFile = match &args.mpc {
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            toml::from_str(&text).with_context(|| format!("{}: not an MPC file", p.display()))?
        }
        None => MpcFile::default(),
    };
    let mut units = Vec::new();
    for u in &args.units {
        let (name, unit) = u
            .split_once('=')
            .filter(|(n, u)| !n.is_empty() && !u.is_empty())
            .with_context(|| format!("--unit {u}: expected NAME=UNIT, e.g. theta=rad"))?;
        units.push((name.to_string(), unit.to_string()));
    }
    let file =
        settings::controller_file(&model_dir, &mpc, &units, args.dt).map_err(anyhow::Error::msg)?;
    if args.bilinear.is_some() && file.model_kind != "bilinear" {
        bail!(
            "--bilinear {}: the model there is of kind '{}' (use --model for it)",
            model_dir.display(),
            file.model_kind
        );
    }
    let layout = Layout::new(&file).map_err(anyhow::Error::msg)?;
    let library = match &args.library {
        Some(l) => l.clone(),
        None => default_library()?,
    };
    let binary = std::fs::read(&library)
        .with_context(|| format!("reading the controller binary {}", library.display()))?;
    let name = format!(
        "koopbridge MPC ({} model {})",
        file.model_kind,
        model_dir.display()
    );
    let description = format!(
        "Koopman MPC exported by koopbridge: inputs = measured state ({}) and reference, outputs = command ({}); \
         each doStep solves the MPC and holds the first input over the step",
        file.state_names.join(", "),
        file.input_names.join(", ")
    );
    let xml = model_description(
        version,
        &layout,
        &file,
        &Header {
            model_identifier: MODEL_IDENTIFIER,
            model_name: &name,
            description: &description,
            generation_tool: concat!("koopbridge ", env!("CARGO_PKG_VERSION"), " export-fmu"),
        },
    );
    let controller_json = serde_json::to_vec_pretty(&file)?;
    let mut entries: Vec<(String, Vec<u8>)> = vec![
        ("modelDescription.xml".into(), xml.into_bytes()),
        (
            format!("binaries/{}/{MODEL_IDENTIFIER}.so", version.platform()),
            binary,
        ),
        (format!("resources/{CONTROLLER_FILE}"), controller_json),
    ];
    if let Some(p) = &args.mpc {
        entries.push(("resources/mpc.toml".into(), std::fs::read(p)?));
    }
    for f in settings::model_files(&model_dir).map_err(anyhow::Error::msg)? {
        let name = f
            .file_name()
            .and_then(|n| n.to_str())
            .context("model file name")?;
        entries.push((format!("resources/{MODEL_DIR}/{name}"), std::fs::read(&f)?));
    }
    write_zip(&args.out, &entries)?;
    println!(
        "wrote {} (FMI {}, {} model, nx = {}, nu = {}, dt = {} s, {} variables)",
        args.out.display(),
        if version == FmiVersion::V3 {
            "3.0"
        } else {
            "2.0"
        },
        file.model_kind,
        layout.nx,
        layout.nu,
        file.dt,
        layout.variables.len() - usize::from(version == FmiVersion::V2)
    );
    Ok(())
}

/// `libkoopbridge_fmu.so` next to the running executable (cargo puts both in target/<profile>/),
/// or in its `deps/` folder, whichever is newer.
fn default_library() -> anyhow::Result<PathBuf> {
    let exe = std::env::current_exe().context("locating the koopbridge executable")?;
    let dir = exe.parent().context("the executable's folder")?;
    // `cargo build` puts it next to the executable; `cargo test` and a dependency's build leave
    // it in deps/ only: the newer of the two.
    let modified = |p: &PathBuf| std::fs::metadata(p).and_then(|m| m.modified()).ok();
    let lib = [dir.join(LIBRARY), dir.join("deps").join(LIBRARY)]
        .into_iter()
        .filter(|p| p.is_file())
        .max_by_key(modified)
        .unwrap_or_else(|| dir.join(LIBRARY));
    if !lib.is_file() {
        bail!(
            "the FMU's controller binary {} is missing: build it with `cargo build --release -p koopbridge-fmu` \
             (or `cargo build --release --workspace`), or give its path with --library",
            lib.display()
        );
    }
    Ok(lib)
}

/// Writes the zip archive `out` from `entries` (stored, no compression) to a temporary name
/// next to it, then renames it: a failure never leaves a half FMU under the real name.
fn write_zip(out: &Path, entries: &[(String, Vec<u8>)]) -> anyhow::Result<()> {
    let dir = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let tmp = dir.join(format!(
        ".{}.tmp-{}",
        out.file_name().and_then(|n| n.to_str()).unwrap_or("fmu"),
        std::process::id()
    ));
    let result = (|| -> anyhow::Result<()> {
        let f =
            std::fs::File::create(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
        let mut zip = zip::ZipWriter::new(std::io::BufWriter::new(f));
        let opts = zip::write::SimpleFileOptions::default()
            .compression_method(zip::CompressionMethod::Stored)
            .unix_permissions(0o644);
        for (name, bytes) in entries {
            let opts = if name.ends_with(".so") {
                opts.unix_permissions(0o755)
            } else {
                opts
            };
            zip.start_file(name.as_str(), opts)?;
            zip.write_all(bytes)?;
        }
        let w = zip.finish()?;
        w.into_inner().map_err(|e| e.into_error())?.sync_all()?;
        std::fs::rename(&tmp, out)
            .with_context(|| format!("renaming {} to {}", tmp.display(), out.display()))?;
        Ok(())
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}
