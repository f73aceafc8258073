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
    Without --data, the pairs are generated: --pairs windows of one transition each (aligned\n\
    pairing, seed 42), plus a 2,000-window test set (T = 15, seed 43) for the prediction error."
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
            let train = generate(sys.as_ref(), a.pairs, 1, 42, Pairing::Aligned)?;
            let test = generate(sys.as_ref(), 2000, sys.window_steps(), 43, Pairing::Aligned)?;
            (train, Some(test))
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
    for r in 0..a.repeats {
        let t = Instant::now();
        let m = fit(&train, &cfg)?;
        let s = t.elapsed().as_secs_f64();
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
