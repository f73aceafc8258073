//! `koopbridge data`: generate SPEC datasets from the reference systems and inspect `.npz` files.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use anyhow::Context;
use koopman::data::{generate_splits_with_progress, DataRegion, Dataset, Pairing, SplitSpec};
use koopman::systems::{by_name_with, SystemOptions};

/// Arguments of `koopbridge data`.
#[derive(clap::Args)]
pub struct DataArgs {
    #[command(subcommand)]
    what: DataCommand,
}

#[derive(clap::Subcommand)]
enum DataCommand {
    /// Generate train/val/test windows from a reference system (SPEC: 180k windows, seed 42,
    /// shuffled, 140k/20k/20k) and write DIR/{train,val,test}.npz plus JSON sidecars.
    #[command(after_help = "Examples:\n  \
        koopbridge data gen --env damped-pendulum                 # data/damped-pendulum-aligned\n  \
        koopbridge data gen --env damped --pairing reference      # reproduces the published numbers\n  \
        koopbridge data gen --env polynomial --n-poly 10 --windows 9000\n  \
        koopbridge data gen --env double --x0-low=-0.2,-1,-2,-2 --x0-high=1.4,0.2,2,2 --u-bound 40 \
        --out data/double-task   # the control task's region, recorded in the metadata\n\n\
        Pairing: 'aligned' stores u_t with x_{t+1} = f(x_t, u_t); 'reference' stores in row t the\n\
        input that drove x_{t-1} -> x_t (row 0's is never applied), as the public reference code.")]
    Gen(Box<GenArgs>),
    /// Print the shape, metadata and value ranges of a dataset file.
    Info(InfoArgs),
}

/// Arguments of `koopbridge data gen`.
#[derive(clap::Args)]
struct GenArgs {
    /// Environment: damped-pendulum, double-pendulum or polynomial (aliases damped, double, poly).
    #[arg(long)]
    env: String,
    /// Output directory (default: data/<env>-<pairing>; data/polynomial-npoly<N>-<pairing>).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Total number of windows (train + val + test).
    #[arg(long, default_value_t = 180_000)]
    windows: usize,
    /// Train pool size (default: 7/9 of --windows, i.e. 140,000 of 180,000).
    #[arg(long)]
    train: Option<usize>,
    /// Validation size (default: 1/9 of --windows).
    #[arg(long)]
    val: Option<usize>,
    /// Test size (default: 1/9 of --windows).
    #[arg(long)]
    test: Option<usize>,
    /// Data seed (generation and shuffle); independent of any training seed.
    #[arg(long, default_value_t = 42)]
    seed: u64,
    /// Input/transition pairing: aligned (the method) or reference (the public reference code).
    #[arg(long, value_enum, default_value_t = PairingArg::Aligned)]
    pairing: PairingArg,
    /// Transitions per window T (default: the system's own, 15, or 1 for polynomial).
    #[arg(long)]
    steps: Option<usize>,
    /// n_poly of the polynomial system (≥ 3).
    #[arg(long, default_value_t = koopman::systems::polynomial::DEFAULT_N_POLY)]
    n_poly: usize,
    /// Lower bounds of the initial states (nx values, comma separated; with --x0-high),
    /// replacing the system's SPEC distribution, e.g. `--x0-low=-0.2,-1,-2,-2`.
    #[arg(
        long,
        value_delimiter = ',',
        allow_hyphen_values = true,
        value_name = "X"
    )]
    x0_low: Option<Vec<f64>>,
    /// Upper bounds of the initial states (nx values; with --x0-low).
    #[arg(
        long,
        value_delimiter = ',',
        allow_hyphen_values = true,
        value_name = "X"
    )]
    x0_high: Option<Vec<f64>>,
    /// Lower bounds of the random inputs (nu values; with --u-high), replacing SPEC's.
    #[arg(
        long,
        value_delimiter = ',',
        allow_hyphen_values = true,
        value_name = "U"
    )]
    u_low: Option<Vec<f64>>,
    /// Upper bounds of the random inputs (nu values; with --u-low).
    #[arg(
        long,
        value_delimiter = ',',
        allow_hyphen_values = true,
        value_name = "U"
    )]
    u_high: Option<Vec<f64>>,
    /// Random inputs U(±B) on every input instead of SPEC's (instead of --u-low/--u-high).
    #[arg(long, value_name = "B", conflicts_with_all = ["u_low", "u_high"])]
    u_bound: Option<f64>,
    /// Print the summary as one JSON object on the last line.
    #[arg(long)]
    json: bool,
}

/// Arguments of `koopbridge data info`.
#[derive(clap::Args)]
struct InfoArgs {
    /// A dataset file (.npz) written by `data gen` or numpy (`np.savez(f, x=..., u=...)`).
    file: PathBuf,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum PairingArg {
    Aligned,
    Reference,
}

impl From<PairingArg> for Pairing {
    fn from(p: PairingArg) -> Self {
        match p {
            PairingArg::Aligned => Pairing::Aligned,
            PairingArg::Reference => Pairing::Reference,
        }
    }
}

/// Runs `koopbridge data`.
pub fn run(args: DataArgs) -> anyhow::Result<()> {
    match args.what {
        DataCommand::Gen(a) => gen(*a),
        DataCommand::Info(a) => info(&a.file),
    }
}

/// The split sizes: the given ones, the rest filled in with the SPEC ratio 140:20:20.
fn split_sizes(a: &GenArgs) -> anyhow::Result<(usize, usize, usize)> {
    let ninth = a.windows / 9;
    let val = a.val.unwrap_or(ninth);
    let test = a.test.unwrap_or(ninth);
    let train = match a.train {
        Some(t) => t,
        None => val
            .checked_add(test)
            .and_then(|vt| a.windows.checked_sub(vt))
            .with_context(|| {
                format!("--val {val} + --test {test} exceed --windows {}", a.windows)
            })?,
    };
    Ok((train, val, test))
}

fn gen(a: GenArgs) -> anyhow::Result<()> {
    let system = by_name_with(&a.env, &SystemOptions { n_poly: a.n_poly })?;
    let (train, val, test) = split_sizes(&a)?;
    let pairing: Pairing = a.pairing.into();
    let region = DataRegion::from_parts(
        system.as_ref(),
        (a.x0_low.clone(), a.x0_high.clone()),
        (a.u_low.clone(), a.u_high.clone()),
        a.u_bound,
    )
    .context("--x0-low/--x0-high/--u-low/--u-high/--u-bound")?;
    let spec = SplitSpec {
        windows: a.windows,
        train,
        val,
        test,
        seed: a.seed,
        pairing,
        steps: a.steps,
        region: region.clone(),
    };
    let pairing_name = match pairing {
        Pairing::Aligned => "aligned",
        Pairing::Reference => "reference",
    };
    // Default directory: data/<env>[-<parameters>]-<pairing>, e.g. data/polynomial-npoly10-aligned.
    let params: String = system
        .parameters()
        .chars()
        .filter(|c| c.is_ascii_alphanumeric())
        .collect();
    let stem = if params.is_empty() {
        system.name().to_string()
    } else {
        format!("{}-{params}", system.name())
    };
    let out = a
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("data").join(format!("{stem}-{pairing_name}")));
    let bar = indicatif::ProgressBar::new(a.windows as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{msg} [{bar:40}] {pos}/{len} windows {per_sec} ETA {eta}",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    bar.set_message(format!("{} ({pairing_name})", system.name()));
    let done = AtomicUsize::new(0);
    let t0 = Instant::now();
    let splits = generate_splits_with_progress(system.as_ref(), &spec, &|k| {
        let d = done.fetch_add(k, Ordering::Relaxed) + k;
        bar.set_position(d as u64);
    })?;
    let gen_s = t0.elapsed().as_secs_f64();
    bar.finish_and_clear();
    let t1 = Instant::now();
    splits
        .save(&out)
        .with_context(|| format!("writing the splits to {}", out.display()))?;
    let write_s = t1.elapsed().as_secs_f64();
    let steps = splits.train.steps;
    println!(
        "{}: {} windows (T = {steps}, nx = {}, nu = {}, dt = {}), pairing {pairing_name}, seed {}",
        system.name(),
        a.windows,
        system.nx(),
        system.nu(),
        system.dt(),
        a.seed
    );
    println!(
        "  generated in {gen_s:.2} s ({:.0} windows/s on {} threads), written in {write_s:.2} s",
        a.windows as f64 / gen_s,
        koopman::data::worker_threads()
    );
    if let Some(r) = &region {
        println!("  region {}", serde_json::to_string(r)?);
    }
    for name in ["train", "val", "test"] {
        let d = match name {
            "train" => &splits.train,
            "val" => &splits.val,
            _ => &splits.test,
        };
        println!(
            "  {:<5} {:>7} windows  {}",
            name,
            d.n,
            out.join(format!("{name}.npz")).display()
        );
    }
    if a.json {
        let summary = serde_json::json!({
            "env": system.name(),
            "pairing": pairing_name,
            "seed": a.seed,
            "windows": a.windows,
            "train": train, "val": val, "test": test,
            "steps": steps,
            "generate_seconds": gen_s,
            "write_seconds": write_s,
            "threads": koopman::data::worker_threads(),
            "region": region,
            "out": out,
        });
        println!("{summary}");
    }
    Ok(())
}

fn info(path: &Path) -> anyhow::Result<()> {
    let d = Dataset::load_npz(path)?;
    let m = &d.meta;
    println!("{}", path.display());
    println!(
        "  x [{}, {}, {}]   u [{}, {}, {}]   ({} transitions)",
        d.n,
        d.steps + 1,
        d.nx,
        d.n,
        d.steps,
        d.nu,
        d.transitions()
    );
    println!(
        "  env {}   dt {}   pairing {:?}   seed {}",
        m.env, m.dt, m.pairing, m.seed
    );
    println!("  source {}   policy {}", m.source, m.policy);
    let range = |vals: &[f64], stride: usize, k: usize| {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for v in vals.iter().skip(k).step_by(stride) {
            lo = lo.min(*v);
            hi = hi.max(*v);
        }
        (lo, hi)
    };
    for (k, name) in m.state_names.iter().enumerate() {
        let (lo, hi) = range(&d.x, d.nx, k);
        println!("  state {name:<12} [{lo:>10.4}, {hi:>10.4}]");
    }
    for (k, name) in m.input_names.iter().enumerate() {
        let (lo, hi) = range(&d.u, d.nu, k);
        println!("  input {name:<12} [{lo:>10.4}, {hi:>10.4}]");
    }
    Ok(())
}
