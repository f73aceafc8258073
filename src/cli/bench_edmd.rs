//! `koopbridge bench edmd`: time the EDMD-with-control fit (normal equations + solve) on a
//! fixed number of (x, u, x⁺) pairs, and report the fitted model's SPEC prediction error.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use koopman::data::{generate, Dataset, Pairing};
use koopman::model::edmd::{fit, Basis, EdmdConfig};
use koopman::model::LiftedModel;
use koopman::systems::by_name;

/// Arguments of `koopbridge bench edmd`.
#[derive(clap::Args)]
#[command(
    after_help = "Example (the figure in BENCHMARKS.md, section EDMD):\n  \
    koopbridge bench edmd --env damped-pendulum --pairs 140000 --repeats 5 --json\n\n\
    Without --data, the pairs are the first --pairs transitions of generated windows (T = 15,\n\
    aligned pairing, seed 42), and a 2,000-window test set (seed 43) gives the prediction error.\n\
    cpu_seconds (user + system time of the process during the fits, from /proc) is reported\n\
    because wall time is only meaningful on an otherwise idle machine."
)]
pub struct BenchEdmdArgs {
    /// Reference system the pairs come from (when --data is not given).
    #[arg(long, default_value = "damped-pendulum")]
    env: String,
    /// Number of (x, u, x⁺) pairs to fit on.
    #[arg(long, default_value_t = 140_000)]
    pairs: usize,
    /// Fit on the first transitions of this .npz instead of generated pairs.
    #[arg(long)]
    data: Option<PathBuf>,
    /// Evaluate the prediction error on this test .npz (default with --data: none; without
    /// --data: 2,000 generated windows).
    #[arg(long)]
    test: Option<PathBuf>,
    /// Polynomial degree (default: the largest with at most --max-features features).
    #[arg(long)]
    degree: Option<usize>,
    /// Feature budget for the automatic degree.
    #[arg(long, default_value_t = 250)]
    max_features: usize,
    /// Ridge weight λ.
    #[arg(long, default_value_t = 1e-10)]
    ridge: f64,
    /// Use plain monomials instead of Chebyshev polynomials (same span).
    #[arg(long)]
    monomial: bool,
    /// Timed repetitions (the minimum and the median are reported).
    #[arg(long, default_value_t = 5)]
    repeats: usize,
    /// Print the result as one JSON object on the last line.
    #[arg(long)]
    json: bool,
}

/// Runs `koopbridge bench edmd`.
pub fn run(a: BenchEdmdArgs) -> anyhow::Result<()> {
    anyhow::ensure!(a.repeats >= 1, "--repeats must be at least 1");
    anyhow::ensure!(a.pairs >= 1, "--pairs must be at least 1");
    let t0 = Instant::now();
    let (train, mut test) = match &a.data {
        Some(path) => {
            let d = Dataset::load_npz(path)?;
            let pool = one_step_pairs(&d, a.pairs)
                .with_context(|| format!("taking {} pairs from {}", a.pairs, path.display()))?;
            (pool, None)
        }
        None => {
            let sys = by_name(&a.env)?;
            let steps = sys.window_steps();
            let windows = a.pairs.div_ceil(steps);
            let pool = generate(sys.as_ref(), windows, steps, 42, Pairing::Aligned)?;
            let test = generate(sys.as_ref(), 2000, steps, 43, Pairing::Aligned)?;
            (one_step_pairs(&pool, a.pairs)?, Some(test))
        }
    };
    if let Some(path) = &a.test {
        test = Some(Dataset::load_npz(path)?);
    }
    eprintln!(
        "{} pairs of {} ready in {:.1} s",
        train.transitions(),
        train.meta.env,
        t0.elapsed().as_secs_f64()
    );
    let cfg = EdmdConfig {
        degree: a.degree,
        max_features: a.max_features,
        basis: if a.monomial {
            Basis::Monomial
        } else {
            Basis::Chebyshev
        },
        ridge: a.ridge,
        ..EdmdConfig::default()
    };
    let mut times = Vec::with_capacity(a.repeats);
    let mut model = None;
    let mut cpu = Vec::with_capacity(a.repeats);
    for r in 0..a.repeats {
        let c0 = cpu_seconds();
        let t = Instant::now();
        let m = fit(&train, &cfg)?;
        let s = t.elapsed().as_secs_f64();
        if let (Some(c0), Some(c1)) = (c0, cpu_seconds()) {
            cpu.push(c1 - c0);
        }
        eprintln!(
            "  fit {}/{}: {s:.3} s (accumulate {:.3} s, solve {:.3} s, {:?})",
            r + 1,
            a.repeats,
            m.info.accumulate_seconds,
            m.info.solve_seconds,
            m.info.solver
        );
        times.push(s);
        model = Some(m);
    }
    let model = model.expect("repeats >= 1");
    times.sort_by(f64::total_cmp);
    let min = times[0];
    let median = times[times.len() / 2];
    cpu.sort_by(f64::total_cmp);
    let cpu_median = cpu.get(cpu.len() / 2).copied();
    let pred = match &test {
        Some(t) => Some(model.prediction_error(t, 0.8)?),
        None => None,
    };
    println!(
        "EDMD fit: {} pairs, N = {} features (degree {}, {:?}), {} thread(s): min {min:.3} s, median {median:.3} s",
        model.info.pairs,
        model.latent_dim(),
        model.dict.degree,
        model.dict.basis,
        koopman::data::worker_threads()
    );
    if let Some(c) = cpu_median {
        println!("  CPU time per fit (user + system, median): {c:.3} s");
    }
    if let Some(p) = pred {
        let n = test.as_ref().map_or(0, |t| t.n);
        println!("  test prediction error (SPEC L_pred, γ = 0.8, {n} windows): {p:.6}");
    }
    if a.json {
        let out = serde_json::json!({
            "bench": "edmd",
            "env": model.info.env,
            "pairs": model.info.pairs,
            "features": model.latent_dim(),
            "degree": model.dict.degree,
            "basis": model.dict.basis,
            "ridge": a.ridge,
            "solver": model.info.solver,
            "threads": koopman::data::worker_threads(),
            "repeats": a.repeats,
            "fit_seconds_min": min,
            "fit_seconds_median": median,
            "fit_cpu_seconds_median": cpu_median,
            "test_prediction_error": pred,
        });
        println!("{out}");
    }
    Ok(())
}

/// The first `pairs` transitions of `d` as windows of one step each.
fn one_step_pairs(d: &Dataset, pairs: usize) -> anyhow::Result<Dataset> {
    anyhow::ensure!(
        pairs <= d.transitions(),
        "the file has only {} transitions",
        d.transitions()
    );
    let (nx, nu) = (d.nx, d.nu);
    let mut x = Vec::with_capacity(pairs * 2 * nx);
    let mut u = Vec::with_capacity(pairs * nu);
    for p in 0..pairs {
        let (i, t) = (p / d.steps, p % d.steps);
        x.extend_from_slice(d.state(i, t));
        x.extend_from_slice(d.state(i, t + 1));
        u.extend_from_slice(d.input(i, t));
    }
    Ok(Dataset {
        n: pairs,
        steps: 1,
        nx,
        nu,
        x,
        u,
        meta: d.meta.clone(),
    })
}

/// User + system CPU seconds of this process so far (Linux `/proc/self/stat`), if available.
fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which is in parentheses and may contain spaces).
    let rest = &stat[stat.rfind(')')? + 2..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // utime and stime are fields 14 and 15 of the full line, i.e. 11 and 12 after the name.
    let utime: f64 = fields.get(11)?.parse().ok()?;
    let stime: f64 = fields.get(12)?.parse().ok()?;
    // Clock ticks per second: 100 on every Linux configuration koopbridge targets.
    Some((utime + stime) / 100.0)
}
