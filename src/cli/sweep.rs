//! `koopbridge sweep`: expands a scaling-law grid (m × n_mult × seeds × regularisers, m fixed or on
//! budget curves m = c·N·ln N), spreads it
//! over every trainer service that answers (or over trainers it starts itself), shows one progress
//! bar, and leaves a folder that `koopbridge scaling` reads, plus `results.csv` for pandas.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use bridge::client::{Client, Liveliness};
use bridge::keyexpr::{fresh_session_id, Keys};
use bridge::services::trainer::DatasetRef;
use bridge::session::{free_loopback_endpoint, open_session};
use bridge::sweep::{
    data_budget, read_results, run_dir, run_sweep, write_csv, DataShape, Regularisers, SweepData,
    SweepEvent, SweepGrid, SweepOptions, PAPER_BUDGET,
};
use koopman::data::Dataset;

use super::sweep_local::{LocalTrainerSpec, LocalTrainers};
use crate::plot::{time_series_png, Panel, Series};

/// Arguments of `koopbridge sweep`.
#[derive(clap::Args, Debug)]
#[command(
    about = "Train a scaling-law grid (m or m = c·N·ln N × n_mult × seeds × regularisers) on every trainer service that answers",
    long_about = "Expands the grid --samples × --n-mult × --seeds × --regularisers over one dataset (a \
        'koopbridge data gen' folder with train/val/test.npz), submits each training to the trainer services \
        of the session ('…/trainer/*/jobs'; the least loaded first, --per-trainer jobs each), follows them with \
        one progress bar, and collects every finished point into OUT/runs/<point>/ (model, metrics.json, \
        result.json) and OUT/results.csv (env, pairing, m, n_mult, N, seed, regularisers, test error, κ(G), \
        κ(BᵀB), wall time, trainer). A trainer that vanishes keeps its points for --grace seconds (a restarted \
        trainer resumes them from its checkpoints); after that they go to the others and its orphaned jobs are \
        cancelled when it returns, so no point is trained twice. A rerun into the same OUT skips finished \
        points. At the end, `koopbridge scaling OUT/runs` fits are printed and drawn into OUT/scaling-m/ (and \
        OUT/scaling-n/ with several n_mult), with OUT/conditioning.png (κ(G) against test error, with and without \
        the covariance loss).\n\n\
        Budget curves (--budget C[,C...]): besides the fixed m of --samples, every n_mult trains on \
        m = ⌈c·N·ln N⌉ windows for each factor c (N = nx·(1 + n_mult); the paper's heuristic is c = 40, see \
        'koopbridge plan'), so that data grow with the latent size. An m above the train pool is capped at \
        the pool, with a note (that point is the full-data point). Without --samples a budget sweep trains \
        only the budget points. Points keep their names (…-m<m>-n<n_mult>-…): a budget point with the m of a \
        fixed-m point, or of a finished point of an earlier sweep into OUT, is that point and is not trained \
        again. Each run's result.json and metrics.json list the factors c it lies on (\"budgets\", also a \
        results.csv column), and the end of the sweep fits E(N) = A·N^(−α) + C per c into \
        OUT/scaling-budget/ ('koopbridge scaling OUT/runs --over budget').",
    after_help = "Examples:\n  \
        koopbridge sweep --data data/damped-pendulum-reference --samples 1000,4000,16000 --seeds 17382,76849 \\\n    \
            --local-trainers 2                         # one machine: starts two trainers itself\n  \
        koopbridge serve trainer models --id gpu1 --connect tcp/ROUTER:7447   # on each compute host\n  \
        koopbridge sweep --data data/double-pendulum-reference --n-mult 1,2,4,8,16 --samples 16000 \\\n    \
            --connect tcp/ROUTER:7447 --serve-data     # trainers elsewhere fetch the data from here\n  \
        koopbridge sweep --data data/damped-pendulum-reference --n-mult 1,2,4,8,16 --budget 1,10,40 \\\n    \
            --local-trainers 2                         # E(N) along m = c·N ln N for c = 1, 10, 40"
)]
pub struct SweepArgs {
    /// Dataset folder with train.npz, val.npz and test.npz ('koopbridge data gen --out DIR').
    #[arg(long)]
    pub data: PathBuf,
    /// Training windows m (comma-separated). Default: 1000,4000,16000, or none with --budget.
    #[arg(long, value_delimiter = ',')]
    pub samples: Vec<usize>,
    /// Budget factors c (comma-separated, e.g. 1,10,40): every n_mult also trains on
    /// m = ⌈c·N·ln N⌉ windows (N = nx·(1 + n_mult)), capped at the train pool.
    #[arg(long, value_delimiter = ',', value_name = "C")]
    pub budget: Vec<f64>,
    /// Encoder width multipliers n_mult (comma-separated; N = nx · (1 + n_mult)).
    #[arg(long = "n-mult", value_delimiter = ',', default_values_t = [16usize])]
    pub n_mult: Vec<usize>,
    /// Training seeds (comma-separated; SPEC's are 17382, 76849, 20965, 84902, 51194).
    #[arg(long, value_delimiter = ',', default_values_t = [17382u64])]
    pub seeds: Vec<u64>,
    /// Regulariser settings: both, none, ctrl, cov (comma-separated). Default: both; for data
    /// without inputs (nu = 0) cov, since the inverse-control loss needs inputs (asking for ctrl
    /// or both there is refused).
    #[arg(long, value_delimiter = ',')]
    pub regularisers: Vec<String>,
    /// Training iterations of every point (default: SPEC's 60,000).
    #[arg(long)]
    pub iterations: Option<usize>,
    /// A further training setting shared by every point, as KEY=JSON (e.g. `hidden=[64,64]`,
    /// `batch=128`; `koopbridge train --help` names the settings). Repeatable.
    #[arg(long = "set", value_name = "KEY=JSON")]
    pub set: Vec<String>,
    /// The sweep's folder (default: results/sweep-<data folder name>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Start this many trainer services as children (1 thread each unless --train-threads),
    /// in addition to any already in the session. One that exits mid-sweep is started again
    /// (up to 3 times) and resumes its job from its checkpoint.
    #[arg(long, default_value_t = 0)]
    pub local_trainers: usize,
    /// Threads per job of the trainers started with --local-trainers.
    #[arg(long, default_value_t = 1)]
    pub train_threads: usize,
    /// Queued + running jobs a trainer holds at a time (more = less idle time between jobs,
    /// coarser balancing).
    #[arg(long, default_value_t = 1)]
    pub per_trainer: usize,
    /// Seconds a vanished trainer keeps its points before they go to the others.
    #[arg(long, default_value_t = 30.0)]
    pub grace: f64,
    /// Seconds to wait while no trainer answers before giving up.
    #[arg(long, default_value_t = 120.0)]
    pub wait_trainers: f64,
    /// Serve the dataset from this process (as recordings at '…/data/<name>') instead of passing
    /// file paths: for trainers on other hosts, which then need no copy of the data.
    #[arg(long)]
    pub serve_data: bool,
    /// koopbridge session id (default: 'default', or a fresh one with --local-trainers).
    #[arg(long)]
    pub session: Option<String>,
    /// Print the summary as one JSON object on the last line.
    #[arg(long)]
    pub json: bool,
    /// Seconds between the progress lines printed when there is no terminal (a log, CI): the
    /// points done and each running point's iterations. On a terminal the bar shows them.
    #[arg(long, default_value_t = 60.0)]
    pub progress_every: f64,
    #[command(flatten)]
    pub zenoh: super::ZenohArgs,
}

/// Runs `koopbridge sweep`.
pub fn run(args: SweepArgs) -> anyhow::Result<()> {
    let data_dir = std::fs::canonicalize(&args.data).with_context(|| {
        format!(
            "dataset folder {} (make it with 'koopbridge data gen --env ENV --pairing PAIRING --out {}')",
            args.data.display(),
            args.data.display()
        )
    })?;
    let data_name = data_dir
        .file_name()
        .and_then(|n| n.to_str())
        .map(|n| {
            n.to_ascii_lowercase()
                .replace(|c: char| !c.is_ascii_alphanumeric() && c != '-', "-")
        })
        .context("dataset folder has no name")?;
    let pool = Dataset::load_npz(&data_dir.join("train.npz"))
        .with_context(|| format!("reading the train pool in {}", data_dir.display()))?;
    let regularisers = Regularisers::for_data(&args.regularisers, pool.nu)?;
    let mut settings = serde_json::Map::new();
    for kv in &args.set {
        let (k, v) = kv
            .split_once('=')
            .with_context(|| format!("--set {kv}: expected KEY=JSON"))?;
        let v: serde_json::Value = serde_json::from_str(v)
            .with_context(|| format!("--set {kv}: the value is not JSON"))?;
        settings.insert(k.trim().to_string(), v);
    }
    bridge::services::koopman_trainer::train_config(&settings)?;
    let samples = if args.samples.is_empty() && args.budget.is_empty() {
        vec![1000, 4000, 16000]
    } else {
        args.samples.clone()
    };
    let grid = SweepGrid {
        data: data_name.clone(),
        samples: samples.clone(),
        n_mult: args.n_mult.clone(),
        seeds: args.seeds.clone(),
        regularisers,
        iterations: args.iterations,
        settings,
        budgets: args.budget.clone(),
        shape: Some(DataShape {
            nx: pool.nx,
            pool: pool.n,
        }),
    };
    let points = grid.points()?;
    for cell in grid.budget_cells()? {
        if cell.capped() {
            println!(
                "note: c = {}, n_mult {} (N = {}): c·N·ln N = {} windows exceeds the train pool of {}; \
                 the point trains on all {} (the full-data point)",
                cell.c, cell.n_mult, cell.latent_dim, cell.wanted, pool.n, cell.m
            );
        }
    }
    if args.budget.iter().any(|&c| c < PAPER_BUDGET) {
        println!(
            "note: budget points with c < {PAPER_BUDGET} are below the paper's heuristic m ≳ 40·N·ln N by design"
        );
    }
    let test_path = data_dir.join("test.npz");
    let test_set = Dataset::load_npz(&test_path)
        .with_context(|| format!("reading the test set {}", test_path.display()))?;
    if let Some(m) = samples.iter().find(|&&m| m > pool.n) {
        bail!("--samples {m} exceeds the train pool of {} windows", pool.n);
    }
    for p in points.iter().filter(|p| p.budgets.is_empty()) {
        let n = pool.nx * (1 + p.n_mult);
        if (p.m as f64) < data_budget(n) {
            eprintln!(
                "warning: {} is over-parameterised: m = {} < 40·N·ln N = {:.0} for N = {n} (see 'koopbridge plan')",
                p.name,
                p.m,
                data_budget(n)
            );
        }
    }
    drop(pool);
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("results").join(format!("sweep-{data_name}")));
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    if let Ok(bytes) = std::fs::read(out.join("sweep.json")) {
        let earlier: SweepGrid = serde_json::from_slice(&bytes).with_context(|| {
            format!(
                "{} is not a sweep description",
                out.join("sweep.json").display()
            )
        })?;
        if earlier.settings != grid.settings || earlier.data != grid.data {
            bail!(
                "{} holds a sweep of {} with other settings ({}); use another --out",
                out.display(),
                earlier.data,
                serde_json::Value::Object(earlier.settings)
            );
        }
    }
    koopman::fsutil::write_atomic(&out.join("sweep.json"), &serde_json::to_vec_pretty(&grid)?)?;

    // The session: the given one, or a fresh one on a free port for trainers started here.
    let mut z = args.zenoh.options();
    let session_id = match (&args.session, args.local_trainers) {
        (Some(s), _) => s.clone(),
        (None, 0) => "default".to_string(),
        (None, _) => fresh_session_id(),
    };
    if args.local_trainers > 0 && z.listen.is_empty() {
        z.listen = vec![free_loopback_endpoint()?];
    }
    let session = open_session(&z)?;
    let client = Client::new(session, Keys::new(&session_id)?);
    let live = Liveliness::new(&client)?;
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let data_server = if args.serve_data {
        Some(serve_data(
            &client,
            &data_dir,
            &data_name,
            &out,
            stop.clone(),
        )?)
    } else {
        None
    };
    // The bar exists before the local trainers: their supervisor prints its restarts above it.
    let bar = indicatif::ProgressBar::new(points.len() as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{bar:30} {pos}/{len} points  {elapsed_precise}  {msg}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let local = if args.local_trainers > 0 {
        let spec = LocalTrainerSpec {
            exe: std::env::current_exe()?,
            session_id: session_id.clone(),
            connect: std::iter::once(z.listen[0].clone())
                .chain(z.connect.iter().cloned())
                .collect(),
            out: out.clone(),
            data_root: data_dir.clone(),
            threads: args.train_threads,
        };
        let b = bar.clone();
        Some(LocalTrainers::start(
            &spec,
            args.local_trainers,
            move |l| say(&b, l),
        )?)
    } else {
        None
    };
    let (train, val, test) = match &data_server {
        Some(names) => (
            DatasetRef::Recording {
                recording: names[0].clone(),
            },
            DatasetRef::Recording {
                recording: names[1].clone(),
            },
            DatasetRef::Recording {
                recording: names[2].clone(),
            },
        ),
        None => (
            DatasetRef::Path {
                path: data_dir.join("train.npz"),
            },
            DatasetRef::Path {
                path: data_dir.join("val.npz"),
            },
            DatasetRef::Path {
                path: test_path.clone(),
            },
        ),
    };
    let data = SweepData {
        train,
        val,
        test,
        test_set,
    };
    let mut opts = SweepOptions::new(out.clone());
    opts.per_trainer = args.per_trainer.max(1);
    opts.grace = Duration::from_secs_f64(args.grace.max(0.0));
    opts.no_trainer_timeout = Duration::from_secs_f64(args.wait_trainers.max(1.0));

    println!(
        "sweep of {} points over {} (session '{session_id}') -> {}",
        points.len(),
        data_dir.display(),
        out.display()
    );
    let started = Instant::now();
    let mut trained_here = 0usize;
    // The running points' iterations: in the bar's message on a terminal, else a line a minute.
    let mut running: std::collections::BTreeMap<String, String> = Default::default();
    let mut last_line = Instant::now();
    let summary = run_sweep(&client, &live, &points, &data, &opts, &mut |e| match e {
        SweepEvent::Progress {
            point,
            trainer,
            iteration,
            total,
        } => {
            running.insert(
                point.name.clone(),
                format!("{} {iteration}/{total} ({trainer})", point.name),
            );
            let now: Vec<&str> = running.values().map(String::as_str).collect();
            if !bar.is_hidden() {
                bar.set_message(now.join(", "));
            } else if last_line.elapsed().as_secs_f64() >= args.progress_every {
                last_line = Instant::now();
                println!(
                    "  {}/{} points done, {:.0} min; training: {}",
                    bar.position(),
                    points.len(),
                    started.elapsed().as_secs_f64() / 60.0,
                    now.join(", ")
                );
            }
        }
        SweepEvent::Resumed { done } => {
            bar.set_position(done as u64);
            if done > 0 {
                say(
                    &bar,
                    format!(
                        "{done} points already finished in {} (skipped)",
                        out.display()
                    ),
                );
            }
        }
        SweepEvent::Trainers { alive } => {
            bar.set_message(format!("trainers: {}", alive.join(", ")))
        }
        SweepEvent::Submitted {
            point,
            trainer,
            job,
        } => say(
            &bar,
            format!("{} -> trainer '{trainer}' (job {job})", point.name),
        ),
        SweepEvent::Moved { point } => say(
            &bar,
            format!(
                "{}: its trainer vanished for more than {:.0} s; the point goes to another",
                point.name, args.grace
            ),
        ),
        SweepEvent::Finished { point, result } => {
            running.remove(&point.name);
            trained_here += 1;
            bar.inc(1);
            say(
                &bar,
                format!(
                    "{}: test error {:.6} (trainer '{}', {:.0} s)",
                    point.name, result.test_error, result.trainer, result.wall_seconds
                ),
            );
        }
        SweepEvent::Failed {
            point,
            error,
            retry,
        } => {
            running.remove(&point.name);
            say(
                &bar,
                format!(
                    "{}: failed{}: {error}",
                    point.name,
                    if retry { " (retrying)" } else { "" }
                ),
            );
        }
    });
    bar.finish_and_clear();
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    drop(local);
    let summary = summary?;
    let csv = write_csv(&out)?;
    let hours = started.elapsed().as_secs_f64() / 3600.0;
    println!(
        "{} of {} points done ({} trained in this run, {:.1} per hour); results in {}",
        summary.done,
        points.len(),
        trained_here,
        if hours > 0.0 {
            trained_here as f64 / hours
        } else {
            0.0
        },
        csv.display()
    );
    for (name, err) in &summary.failed {
        println!("failed: {name}: {err}");
    }
    let results = read_results(&out)?;
    conditioning_plot(&out.join("conditioning.png"), &results)?;
    let runs = out.join("runs");
    // The m and n fits are over the finished runs of the fixed-m family (--samples); the budget
    // points have their own m each and would only add one-point curves there. The budget fit reads
    // every run and keeps those that carry budget factors.
    let fixed_m_runs: Vec<PathBuf> = results
        .iter()
        .filter(|r| samples.contains(&r.m))
        .map(|r| run_dir(&out, &r.name))
        .collect();
    if results.len() >= 3 {
        for (over, dir, wanted, fitted_runs) in [
            (
                super::scaling::Axis::M,
                "scaling-m",
                samples.len() > 1,
                fixed_m_runs.clone(),
            ),
            (
                super::scaling::Axis::N,
                "scaling-n",
                !samples.is_empty() && args.n_mult.len() > 1,
                fixed_m_runs.clone(),
            ),
            (
                super::scaling::Axis::Budget,
                "scaling-budget",
                !args.budget.is_empty() && args.n_mult.len() > 1,
                vec![runs.clone()],
            ),
        ] {
            if wanted && !fitted_runs.is_empty() {
                super::scaling::run(super::scaling::ScalingArgs {
                    runs: fitted_runs,
                    over,
                    out: Some(out.join(dir)),
                    json: false,
                })?;
            }
        }
    }
    if args.json {
        println!(
            "{}",
            serde_json::json!({
                "points": points.len(),
                "done": summary.done,
                "trained": trained_here,
                "failed": summary.failed,
                "results": csv,
                "wall_seconds": started.elapsed().as_secs_f64(),
            })
        );
    }
    if !summary.failed.is_empty() {
        bail!("{} points failed", summary.failed.len());
    }
    Ok(())
}

/// Prints a line above the progress bar, or plainly when there is no terminal to draw it on
/// (logs, pipes), where indicatif would swallow it.
fn say(bar: &indicatif::ProgressBar, line: String) {
    if bar.is_hidden() {
        println!("{line}");
    } else {
        bar.println(line);
    }
}

/// Serves the dataset's three files from this process through a recorder service (its data
/// folder holds links to them under names made from the dataset's name); returns the names.
fn serve_data(
    client: &Client,
    data_dir: &Path,
    data_name: &str,
    out: &Path,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
) -> anyhow::Result<[String; 3]> {
    let served = out.join("served-data");
    std::fs::create_dir_all(&served)?;
    let names = ["train", "val", "test"].map(|s| format!("{data_name}-{s}"));
    for (split, name) in ["train", "val", "test"].iter().zip(&names) {
        let link = served.join(format!("{name}.npz"));
        let _ = std::fs::remove_file(&link);
        std::fs::hard_link(data_dir.join(format!("{split}.npz")), &link)
            .or_else(|_| std::fs::copy(data_dir.join(format!("{split}.npz")), &link).map(|_| ()))
            .with_context(|| format!("linking {} into {}", split, served.display()))?;
    }
    let (session, keys) = (client.session.clone(), client.keys.clone());
    let id = format!("sweep{}", std::process::id());
    std::thread::spawn(move || {
        if let Err(e) = bridge::services::recorder::serve(&session, &keys, &id, &served, &stop) {
            eprintln!("error: the sweep's data server stopped: {e}");
        }
    });
    Ok(names)
}

/// κ(G) against test error, one series per regulariser setting (the paper's conditioning
/// figure); nothing is drawn without results.
fn conditioning_plot(path: &Path, results: &[bridge::sweep::PointResult]) -> anyhow::Result<()> {
    let mut series = Vec::new();
    for (k, r) in Regularisers::ALL.iter().enumerate() {
        let pts: Vec<(f64, f64)> = results
            .iter()
            .filter(|p| p.regularisers == *r)
            .filter_map(|p| Some((p.gram_condition?.log10(), p.test_error.log10())))
            .filter(|(a, b)| a.is_finite() && b.is_finite())
            .collect();
        if pts.is_empty() {
            continue;
        }
        let (x, y): (Vec<f64>, Vec<f64>) = pts.into_iter().unzip();
        series.push(Series::new(r.as_str(), &x, &y).colored(k).markers());
    }
    if series.is_empty() {
        return Ok(());
    }
    time_series_png(
        path,
        "latent conditioning vs prediction error",
        "log10 κ(G) on the test set",
        &[Panel {
            title: "each point one run; colour: regularisers".into(),
            y_label: "log10 test error".into(),
            series,
        }],
        900,
    )
}
