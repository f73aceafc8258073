//! `koopbridge bench train`: training iterations per second on generated data, for comparison
//! with the PyTorch anchor (`scripts/bench-train-vs-anchor.sh` runs both side by side).

use anyhow::Context;
use koopman::data::{generate, Dataset, Pairing};
use koopman::train::{train, Precision, TrainConfig};
use serde::Serialize;
use std::ops::ControlFlow;

/// Arguments of `koopbridge bench train`.
#[derive(clap::Args, Debug)]
#[command(
    about = "Training speed (iterations/second) of the neural Koopman trainer on generated data"
)]
pub struct BenchTrainArgs {
    /// Reference system to generate the data from.
    #[arg(long, default_value = "damped-pendulum", conflicts_with = "data")]
    pub system: String,
    /// Time on a recorded dataset instead (a directory with `train.npz` and `val.npz`, e.g. the
    /// Go2 expert data: N = 35 * 17 = 595, nu = 12); `--windows` then caps the training windows.
    #[arg(long, value_name = "DIR")]
    pub data: Option<std::path::PathBuf>,
    /// Timed training iterations.
    #[arg(long, default_value_t = 2000)]
    pub iters: usize,
    /// Untimed warm-up iterations run before (same model, same data).
    #[arg(long, default_value_t = 50)]
    pub warmup: usize,
    /// Encoder width multiplier n_mult.
    #[arg(long, default_value_t = 16)]
    pub n_mult: usize,
    /// Windows per batch.
    #[arg(long, default_value_t = 64)]
    pub batch: usize,
    /// Generated training windows to sample batches from.
    #[arg(long, default_value_t = 4096)]
    pub windows: usize,
    /// Turn the inverse-control loss off.
    #[arg(long)]
    pub no_ctrl: bool,
    /// Turn the covariance loss off.
    #[arg(long)]
    pub no_cov: bool,
    /// Train in f64 instead of f32.
    #[arg(long)]
    pub f64: bool,
    /// Threads for the large products (0 = all cores).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

#[derive(Serialize)]
struct Report {
    bench: &'static str,
    system: String,
    iterations: usize,
    iterations_per_second: f64,
    seconds: f64,
    n_mult: usize,
    batch: usize,
    ctrl: bool,
    cov: bool,
    precision: Precision,
    threads: usize,
    loadavg_1min: Option<f64>,
    /// Process CPU time (user + system, all threads) per timed iteration, in ms: meaningful
    /// even when other processes load the machine.
    cpu_ms_per_iteration: Option<f64>,
}

/// Runs `koopbridge bench train`.
pub fn run(args: BenchTrainArgs) -> anyhow::Result<()> {
    if args.iters == 0 {
        anyhow::bail!("--iters must be at least 1");
    }
    let (label, data, val) = bench_data(&args)?;
    let mut cfg = TrainConfig {
        n_mult: args.n_mult,
        batch: args.batch,
        ctrl: !args.no_ctrl,
        cov: !args.no_cov,
        precision: if args.f64 {
            Precision::F64
        } else {
            Precision::F32
        },
        threads: args.threads,
        ..TrainConfig::default()
    };
    if args.warmup > 0 {
        cfg.iterations = args.warmup;
        cfg.validate_every = args.warmup;
        train(&cfg, &data, &val, None, &mut |_| ControlFlow::Continue(()))?;
    }
    cfg.iterations = args.iters;
    cfg.validate_every = args.iters;
    let cpu0 = cpu_seconds();
    let out = train(&cfg, &data, &val, None, &mut |_| ControlFlow::Continue(()))?;
    let ips = out.metrics.iterations_per_second;
    let cpu_ms = match (cpu0, cpu_seconds()) {
        (Some(a), Some(b)) => Some(1000.0 * (b - a) / args.iters as f64),
        _ => None,
    };
    let report = Report {
        bench: "train",
        system: label,
        iterations: args.iters,
        iterations_per_second: ips,
        seconds: args.iters as f64 / ips,
        n_mult: args.n_mult,
        batch: args.batch,
        ctrl: cfg.ctrl,
        cov: cfg.cov,
        precision: cfg.precision,
        threads: if args.threads == 0 {
            rayon_threads()
        } else {
            args.threads
        },
        loadavg_1min: loadavg(),
        cpu_ms_per_iteration: cpu_ms,
    };
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        println!(
            "bench train: {} n_mult {} batch {} ctrl {} cov {} {:?}, {} iterations: {:.1} it/s ({:.2} ms/it wall, {:.2} ms/it CPU), load {:?}",
            report.system,
            report.n_mult,
            report.batch,
            report.ctrl,
            report.cov,
            report.precision,
            report.iterations,
            ips,
            1000.0 / ips,
            cpu_ms.unwrap_or(f64::NAN),
            report.loadavg_1min
        );
    }
    Ok(())
}

/// The benchmark's label, training windows and validation windows: generated from `--system`,
/// or read from `--data DIR` (at most `--windows` training windows).
fn bench_data(args: &BenchTrainArgs) -> anyhow::Result<(String, Dataset, Dataset)> {
    if let Some(dir) = &args.data {
        let train = Dataset::load_npz(&dir.join("train.npz"))
            .with_context(|| format!("reading the benchmark data in {}", dir.display()))?;
        let val = Dataset::load_npz(&dir.join("val.npz"))
            .with_context(|| format!("reading the benchmark data in {}", dir.display()))?;
        let train = train.head(args.windows.max(2).min(train.n))?;
        let val = val.head(256.min(val.n))?;
        let label = format!("{} (nx {}, nu {})", dir.display(), train.nx, train.nu);
        return Ok((label, train, val));
    }
    let system = koopman::systems::by_name(&args.system)?;
    let data = generate(
        system.as_ref(),
        args.windows.max(2),
        15,
        42,
        Pairing::Aligned,
    )
    .context("generating benchmark data")?;
    let val = data.head(256.min(data.n))?;
    Ok((args.system.clone(), data, val))
}

fn rayon_threads() -> usize {
    std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1)
}

fn loadavg() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// User + system CPU seconds of this process (Linux `/proc/self/stat`; 10 ms resolution).
fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    let fields: Vec<&str> = stat.rsplit(')').next()?.split_whitespace().collect();
    let ticks: f64 = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}
