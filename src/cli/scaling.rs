//! `koopbridge scaling`: fits SPEC's scaling law `E = A·D^(−α) + C` to the test prediction errors
//! of trained runs (one curve per n_mult against m, per m against N, or per budget factor c
//! against N along m = c·N·ln N), prints α, A, C and R², and writes the fits as JSON and a log–log
//! plot.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::natural_order::natural_cmp;
use anyhow::{bail, Context};
use koopman::analysis::{fit_scaling_law, ScalingFit};
use koopman::data::Pairing;
use koopman::fsutil::write_atomic;
use koopman::model::store;
use koopman::train::TrainMetrics;
use serde::Serialize;
use serde_json::Value;

use crate::plot::{time_series_png, Panel, Series};

/// The D of the fit.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    /// Training windows m; one curve per (env, pairing, n_mult, regularisers).
    M,
    /// Latent dimension N = nx + n_enc; one curve per (env, pairing, m, regularisers).
    N,
    /// Latent dimension N along a data budget m = c·N·ln N ('koopbridge sweep --budget'); one
    /// curve per (env, pairing, c, regularisers). Runs without a budget factor are left out.
    Budget,
}

/// Arguments of `koopbridge scaling`.
#[derive(clap::Args, Debug)]
#[command(
    about = "Fit the scaling law E = A·D^(−α) + C to trained runs' test prediction errors",
    long_about = "Fit SPEC's scaling law E = A·D^(−α) + C (in log space, A ≥ 0, C ≥ 0) to the test prediction \
        errors of Koopman runs written by 'koopbridge train'. With --over m (default) D is the number of \
        training windows and there is one curve per environment, pairing, n_mult and regulariser setting; \
        with --over n D is the latent dimension N = nx + n_enc and there is one curve per m. With --over budget \
        D is N too, but the data grow with it: the runs of 'koopbridge sweep --budget C' (m = c·N·ln N, each \
        run's metrics.json lists its factors c as \"budgets\") form one curve per c, labelled \
        'm = c·N ln N, c = …' (a run capped at the full train pool, or shared by several c, is on each of \
        their curves; runs without budgets are left out). Every seed is its own point. A curve needs 3 points and 2 distinct D values to be fitted; smaller ones are listed \
        unfitted.\n\n\
        Examples:\n  \
        koopbridge scaling models/scaling --out results/scaling\n  \
        koopbridge scaling results/sweep-damped-pendulum-reference/runs --over budget --out results/budget"
)]
pub struct ScalingArgs {
    /// Run folders (each with the metrics.json and config.json of 'koopbridge train'), or folders
    /// whose sub-folders are runs.
    #[arg(required = true, value_name = "RUN")]
    pub runs: Vec<PathBuf>,
    /// What D is: the training windows m, the latent dimension N at fixed m, or N along the
    /// budget curves m = c·N·ln N (one curve per c).
    #[arg(long, value_enum, default_value_t = Axis::M)]
    pub over: Axis,
    /// Folder for scaling.json and scaling.png (nothing is written without it).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print the curves as one JSON object on the last line of stdout.
    #[arg(long)]
    pub json: bool,
}

/// One trained run, as far as the fit needs it.
#[derive(Clone, Debug, Serialize)]
struct RunPoint {
    path: PathBuf,
    env: String,
    pairing: Pairing,
    m: usize,
    n_mult: usize,
    latent_dim: usize,
    ctrl: bool,
    cov: bool,
    seed: u64,
    error: f64,
    /// Budget factors c of the run (`koopbridge sweep --budget`; empty otherwise).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    budgets: Vec<f64>,
}

/// One curve: its runs and, with enough points, the fit.
#[derive(Debug, Serialize)]
struct Curve {
    label: String,
    /// The budget factor c of an `--over budget` curve.
    #[serde(skip_serializing_if = "Option::is_none")]
    budget: Option<f64>,
    /// `(D, E)` per run, D ascending.
    points: Vec<(f64, f64)>,
    fit: Option<ScalingFit>,
    /// Why there is no fit.
    note: Option<String>,
}

/// Runs `koopbridge scaling`.
pub fn run(args: ScalingArgs) -> anyhow::Result<()> {
    let runs = collect_runs(&args.runs)?;
    let curves = fit_curves(&runs, args.over);
    print_table(&curves, args.over);
    if let Some(out) = &args.out {
        std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
        let json = serde_json::json!({ "over": args.over, "runs": runs, "curves": curves });
        write_atomic(
            &out.join("scaling.json"),
            &serde_json::to_vec_pretty(&json)?,
        )?;
        let png = out.join("scaling.png");
        if plot(&png, &curves, args.over)? {
            println!("scaling.json and scaling.png in {}", out.display());
        } else {
            let _ = std::fs::remove_file(&png);
            println!(
                "scaling.json in {} (no plot: no curve has two distinct D values)",
                out.display()
            );
        }
    }
    if args.json {
        println!(
            "{}",
            serde_json::json!({ "over": args.over, "curves": curves })
        );
    }
    Ok(())
}

/// The runs named on the command line: each path is a run folder, or a folder of run folders
/// (sub-folders without metrics.json are passed over). Runs of other models are skipped with a
/// note on stderr; a run whose files cannot be read is an error naming the file.
fn collect_runs(paths: &[PathBuf]) -> anyhow::Result<Vec<RunPoint>> {
    let mut runs = Vec::new();
    for path in paths {
        if path.join("metrics.json").is_file() {
            runs.extend(read_run(path)?);
            continue;
        }
        if !path.is_dir() {
            bail!(
                "{} is neither a run folder (with metrics.json) nor a folder of runs",
                path.display()
            );
        }
        let mut children: Vec<PathBuf> = std::fs::read_dir(path)
            .with_context(|| format!("listing {}", path.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.join("metrics.json").is_file())
            .collect();
        children.sort();
        if children.is_empty() {
            bail!("no run folders (with metrics.json) in {}", path.display());
        }
        for child in children {
            runs.extend(read_run(&child)?);
        }
    }
    if runs.is_empty() {
        bail!("none of the runs is a Koopman model");
    }
    Ok(runs)
}

/// Reads one run folder (its metrics.json as [`TrainMetrics`], N from config.json); `None`
/// (with a note) for a model other than Koopman.
fn read_run(dir: &Path) -> anyhow::Result<Option<RunPoint>> {
    let file = dir.join("metrics.json");
    let metrics = read_json(&file)?;
    let budgets: Vec<f64> = match metrics.get("budgets") {
        None => Vec::new(),
        Some(b) => b
            .as_array()
            .and_then(|a| a.iter().map(Value::as_f64).collect::<Option<Vec<f64>>>())
            .with_context(|| format!("{}: \"budgets\" is not a list of numbers", file.display()))?,
    };
    let model = metrics.get("model").and_then(Value::as_str).unwrap_or("");
    if model != "koopman" {
        eprintln!(
            "skipping {}: a {model:?} run, the scaling law is fitted to Koopman models",
            dir.display()
        );
        return Ok(None);
    }
    let run: TrainMetrics = serde_json::from_value(metrics).with_context(|| {
        format!(
            "{} is not the metrics.json of a Koopman training run",
            file.display()
        )
    })?;
    let error = run
        .test_prediction_error
        .filter(|e| e.is_finite() && *e > 0.0)
        .with_context(|| {
            format!(
                "{}: test_prediction_error is missing or not a positive number",
                file.display()
            )
        })?;
    let config = store::read_config(dir)?;
    let latent_dim = config
        .get("latent_dim")
        .and_then(Value::as_u64)
        .with_context(|| {
            format!(
                "{}: no whole-number field \"latent_dim\"",
                dir.join("config.json").display()
            )
        })?;
    // Built-in systems with parameters (the polynomial system's n_poly) are different curves.
    let parameters = config
        .pointer("/metadata/dataset/source")
        .and_then(Value::as_str)
        .and_then(koopman::data::builtin_source_parameters);
    Ok(Some(RunPoint {
        path: dir.to_path_buf(),
        env: match parameters {
            Some(p) => format!("{} {p}", run.env),
            None => run.env,
        },
        pairing: run.pairing,
        m: run.train_samples,
        n_mult: run.config.n_mult,
        latent_dim: latent_dim as usize,
        ctrl: run.config.ctrl,
        cov: run.config.cov,
        seed: run.config.seed,
        error,
        budgets,
    }))
}

fn read_json(path: &Path) -> anyhow::Result<Value> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_slice(&bytes).with_context(|| format!("{} is not valid JSON", path.display()))
}

/// Groups the runs into curves along `over` and fits each one that can be fitted (with
/// `Axis::Budget` a run is on the curve of each of its budget factors).
fn fit_curves(runs: &[RunPoint], over: Axis) -> Vec<Curve> {
    // label -> (budget factor c, (D, E) per run)
    type Group = (Option<f64>, Vec<(f64, f64)>);
    let mut groups: BTreeMap<String, Group> = BTreeMap::new();
    for r in runs {
        let regularisers = match (r.ctrl, r.cov) {
            (true, true) => "both regularisers",
            (false, true) => "no inverse-control loss",
            (true, false) => "no covariance loss",
            (false, false) => "no regulariser",
        };
        let pairing = format!("{:?}", r.pairing).to_lowercase();
        let curves: Vec<(String, Option<f64>, f64)> = match over {
            Axis::M => vec![(format!("n_mult {}", r.n_mult), None, r.m as f64)],
            Axis::N => vec![(format!("m {}", r.m), None, r.latent_dim as f64)],
            Axis::Budget => r
                .budgets
                .iter()
                .map(|&c| (budget_label(c), Some(c), r.latent_dim as f64))
                .collect(),
        };
        for (fixed, budget, d) in curves {
            let label = format!("{} {pairing} {fixed} {regularisers}", r.env);
            let entry = groups.entry(label).or_insert((budget, Vec::new()));
            entry.1.push((d, r.error));
        }
    }
    let mut groups: Vec<(String, Group)> = groups.into_iter().collect();
    groups.sort_by(|a, b| natural_cmp(&a.0, &b.0));
    groups
        .into_iter()
        .map(|(label, (budget, mut points))| {
            points.sort_by(|a, b| a.0.total_cmp(&b.0));
            let d: Vec<f64> = points.iter().map(|p| p.0).collect();
            let e: Vec<f64> = points.iter().map(|p| p.1).collect();
            let (fit, note) = match fit_scaling_law(&d, &e) {
                Ok(fit) => (Some(fit), None),
                Err(err) => (None, Some(err.to_string())),
            };
            Curve {
                label,
                budget,
                points,
                fit,
                note,
            }
        })
        .collect()
}

/// The curve name of budget factor c.
fn budget_label(c: f64) -> String {
    format!("m = c·N ln N, c = {c}")
}

fn print_table(curves: &[Curve], over: Axis) {
    let d = match over {
        Axis::M => "m",
        Axis::N | Axis::Budget => "N",
    };
    println!("E = A·{d}^(−α) + C, fitted in log space");
    if over == Axis::Budget && curves.is_empty() {
        println!("no run has a budget factor (runs of 'koopbridge sweep --budget C' do)");
    }
    // The label column is as wide as the longest label (counted in characters, not bytes).
    let w = curves
        .iter()
        .map(|c| c.label.chars().count())
        .max()
        .unwrap_or(0)
        .max(60);
    println!(
        "{:<w$} {:>6} {:>8} {:>10} {:>10} {:>7}",
        "curve", "points", "α", "A", "C", "R²"
    );
    for c in curves {
        match &c.fit {
            Some(f) => println!(
                "{:<w$} {:>6} {:>8.4} {:>10.4e} {:>10.4e} {:>7.4}",
                c.label, f.points, f.alpha, f.a, f.c, f.r2
            ),
            None => println!(
                "{:<w$} {:>6} not fitted: {}",
                c.label,
                c.points.len(),
                c.note.as_deref().unwrap_or("")
            ),
        }
    }
}

/// log₁₀ E against log₁₀ D: each curve's runs as markers and its fit as a line, in one colour,
/// with one legend entry per curve giving α, C and R².
/// Curves with a single D value are left out; `false` (nothing drawn) when no curve is left.
fn plot(path: &Path, curves: &[Curve], over: Axis) -> anyhow::Result<bool> {
    let mut series = Vec::new();
    let spans = curves
        .iter()
        .filter(|c| c.points.first().map(|p| p.0) != c.points.last().map(|p| p.0));
    for (i, c) in spans.enumerate() {
        let ld: Vec<f64> = c.points.iter().map(|p| p.0.log10()).collect();
        let le: Vec<f64> = c.points.iter().map(|p| p.1.log10()).collect();
        let label = match &c.fit {
            Some(f) => format!(
                "{}: α {:.3}, C {:.2e}, R² {:.3}",
                c.label, f.alpha, f.c, f.r2
            ),
            None => format!("{} (not fitted)", c.label),
        };
        series.push(Series::new(label, &ld, &le).markers().colored(i));
        if let Some(f) = &c.fit {
            let (lo, hi) = (ld[0], ld[ld.len() - 1]);
            let xs: Vec<f64> = (0..=60).map(|k| lo + (hi - lo) * k as f64 / 60.0).collect();
            let ys: Vec<f64> = xs
                .iter()
                .map(|x| f.predict(10f64.powf(*x)).log10())
                .collect();
            series.push(Series::new("", &xs, &ys).colored(i));
        }
    }
    let x_label = match over {
        Axis::M => "log10 m (training windows)",
        Axis::N => "log10 N (latent dimension)",
        Axis::Budget => "log10 N (latent dimension), trained on m = c·N ln N windows",
    };
    let panel = Panel {
        title: "test prediction error".into(),
        y_label: "log10 E".into(),
        series,
    };
    if panel.series.is_empty() {
        return Ok(false);
    }
    time_series_png(
        path,
        "Scaling law E = A·D^(−α) + C",
        x_label,
        &[panel],
        1000,
    )?;
    Ok(true)
}

#[cfg(test)]
#[path = "scaling_tests_budget.rs"]
mod tests_budget;

#[cfg(test)]
mod tests {
    use super::*;
    use koopman::train::TrainConfig;

    /// Writes a run folder as `koopbridge train` would (its TrainMetrics, tagged "model").
    fn write_run(dir: &Path, m: usize, n_mult: usize, seed: u64, error: f64) {
        write_budget_run(dir, m, n_mult, seed, error, &[]);
    }

    /// Writes a run folder as `koopbridge sweep` does (TrainMetrics tagged "model", and
    /// "budgets" when the point lies on budget curves); the damped pendulum's nx = 2.
    pub(super) fn write_budget_run(
        dir: &Path,
        m: usize,
        n_mult: usize,
        seed: u64,
        error: f64,
        budgets: &[f64],
    ) {
        std::fs::create_dir_all(dir).unwrap();
        let metrics = TrainMetrics {
            test_prediction_error: Some(error),
            best_validation_prediction_error: 0.01,
            best_iteration: 1,
            iterations: 1,
            iterations_per_second: 1.0,
            wall_seconds: 1.0,
            train_samples: m,
            num_params: 1,
            final_loss: Default::default(),
            pairing: Pairing::Reference,
            env: "damped-pendulum".into(),
            config: TrainConfig {
                n_mult,
                seed,
                ..TrainConfig::default()
            },
        };
        let mut json = serde_json::to_value(&metrics).unwrap();
        json["model"] = "koopman".into();
        if !budgets.is_empty() {
            json["budgets"] = serde_json::json!(budgets);
        }
        std::fs::write(dir.join("metrics.json"), json.to_string()).unwrap();
        let config = serde_json::json!({ "kind": "koopman", "latent_dim": 2 + 2 * n_mult });
        std::fs::write(dir.join("config.json"), config.to_string()).unwrap();
    }

    /// Runs `koopbridge scaling ROOT --over AXIS --out ROOT/report`, checks that it wrote a PNG
    /// and returns its scaling.json.
    pub(super) fn write_report(root: &Path, over: Axis) -> Value {
        let out = root.join("report");
        run(ScalingArgs {
            runs: vec![root.to_path_buf()],
            over,
            out: Some(out.clone()),
            json: false,
        })
        .unwrap();
        assert_eq!(
            &std::fs::read(out.join("scaling.png")).unwrap()[1..4],
            b"PNG"
        );
        serde_json::from_slice(&std::fs::read(out.join("scaling.json")).unwrap()).unwrap()
    }

    fn temp(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("koopbridge-scaling-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    #[test]
    fn recovers_the_law_the_runs_follow_and_lists_small_curves_unfitted() {
        let root = temp("law");
        // n_mult 16: E = 3·m^(−0.6) + 0.004, two seeds with ±1% deviations.
        for (k, m) in [1000usize, 4000, 16000, 64000, 140000]
            .into_iter()
            .enumerate()
        {
            let e = 3.0 * (m as f64).powf(-0.6) + 0.004;
            write_run(&root.join(format!("a{k}")), m, 16, 1, e * 1.01);
            write_run(&root.join(format!("b{k}")), m, 16, 2, e * 0.99);
        }
        // n_mult 4: two points only.
        write_run(&root.join("c0"), 1000, 4, 1, 0.05);
        write_run(&root.join("c1"), 4000, 4, 1, 0.03);
        let runs = collect_runs(std::slice::from_ref(&root)).unwrap();
        assert_eq!(runs.len(), 12);
        let curves = fit_curves(&runs, Axis::M);
        assert_eq!(curves.len(), 2);
        let big = curves
            .iter()
            .find(|c| c.label.contains("n_mult 16"))
            .unwrap();
        let fit = big.fit.as_ref().unwrap();
        assert_eq!(fit.points, 10);
        assert!((fit.alpha - 0.6).abs() < 0.05, "α = {}", fit.alpha);
        assert!((fit.c - 0.004).abs() < 5e-4, "C = {}", fit.c);
        assert!(fit.r2 > 0.99);
        let small = curves
            .iter()
            .find(|c| c.label.contains("n_mult 4"))
            .unwrap();
        assert!(small.fit.is_none());
        assert!(small.note.as_deref().unwrap().contains("at least 3 points"));

        // Over N: the m = 1000 runs of n_mult 16 and 4 form one curve of 3 points.
        let by_n = fit_curves(&runs, Axis::N);
        let m1000 = by_n.iter().find(|c| c.label.contains("m 1000 ")).unwrap();
        assert_eq!(
            m1000.points.iter().map(|p| p.0).collect::<Vec<_>>(),
            [10.0, 34.0, 34.0]
        );

        let saved = write_report(&root, Axis::M);
        assert_eq!(saved["curves"].as_array().unwrap().len(), 2);
        std::fs::remove_dir_all(&root).unwrap();
    }

    #[test]
    fn built_in_systems_with_different_parameters_are_different_curves() {
        let root = temp("params");
        for (n_poly, scale) in [(3, 1.0), (10, 100.0)] {
            for (k, m) in [1000usize, 4000, 16000].into_iter().enumerate() {
                let dir = root.join(format!("p{n_poly}-{k}"));
                write_run(&dir, m, 16, 1, scale * (m as f64).powf(-1.0));
                let config = serde_json::json!({
                    "kind": "koopman",
                    "latent_dim": 34,
                    "metadata": { "dataset": {
                        "source": koopman::data::builtin_source(&format!("n_poly={n_poly}"))
                    } }
                });
                std::fs::write(dir.join("config.json"), config.to_string()).unwrap();
            }
        }
        let curves = fit_curves(&collect_runs(std::slice::from_ref(&root)).unwrap(), Axis::M);
        let labels: Vec<&str> = curves.iter().map(|c| c.label.as_str()).collect();
        assert_eq!(curves.len(), 2, "{labels:?}");
        // Natural order in the table and the legend: n_poly=3 before n_poly=10.
        assert!(labels[0].contains("n_poly=3 "), "{labels:?}");
        for n_poly in [3, 10] {
            let c = curves
                .iter()
                .find(|c| {
                    c.label
                        .contains(&format!("damped-pendulum n_poly={n_poly} "))
                })
                .unwrap_or_else(|| panic!("no curve for n_poly={n_poly} in {labels:?}"));
            assert!((c.fit.as_ref().unwrap().alpha - 1.0).abs() < 0.05);
        }
        std::fs::remove_dir_all(&root).unwrap();
    }

    #[test]
    fn unreadable_runs_are_errors_that_name_the_file() {
        let root = temp("bad");
        write_run(&root.join("r"), 1000, 16, 1, 0.01);
        let metrics = root.join("r").join("metrics.json");
        let text = std::fs::read_to_string(&metrics).unwrap();
        std::fs::write(&metrics, &text[..text.len() / 2]).unwrap();
        let err = format!("{:#}", collect_runs(&[root.join("r")]).unwrap_err());
        assert!(err.contains("metrics.json is not valid JSON"), "{err}");

        write_run(&root.join("r"), 1000, 16, 1, f64::NAN);
        let err = format!("{:#}", collect_runs(&[root.join("r")]).unwrap_err());
        assert!(err.contains("test_prediction_error"), "{err}");

        let err = format!("{:#}", collect_runs(&[root.join("missing")]).unwrap_err());
        assert!(err.contains("neither a run folder"), "{err}");
        std::fs::remove_dir_all(&root).unwrap();
    }
}
