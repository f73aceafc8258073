//! `koopbridge train`: trains a neural Koopman model (or a baseline) on a dataset folder written by
//! `koopbridge data gen`, saves it with its `metrics.json`, and shows progress while it runs.

use super::learning_curve::{CurvePoint, LearningCurve};
use anyhow::Context;
use koopman::data::{Dataset, Splits};
use koopman::fsutil::write_atomic;
use koopman::train::{Precision, Progress, TrainConfig, TrainMetrics};
use serde::Serialize;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Which model to train.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ModelKind {
    /// Neural Koopman model (SPEC.md).
    Koopman,
    /// Bilinear Koopman model z⁺ = A z + B u + Σ u_i N_i z: SPEC's encoder, losses and recipe,
    /// N_i starting at zero (the inverse-control loss uses B(z) = B + [N_1 z … N_nu z]).
    Bilinear,
    /// EDMD with control (polynomial dictionary, least squares).
    Edmd,
    /// NNDM baseline: an MLP x⁺ = x + g([x, u]) with equal hidden layers (as many as --hidden)
    /// sized to the parameter count of the Koopman model of --n-mult/--hidden, trained on the same
    /// prediction loss and recipe (--no-ctrl/--no-cov do not apply).
    Nndm,
}

/// Arguments of `koopbridge train`.
#[derive(clap::Args, Debug)]
#[command(
    about = "Train a model on a dataset folder (train.npz, val.npz, test.npz from 'koopbridge data gen')",
    long_about = "Train a model on a dataset folder (train.npz, val.npz, test.npz from 'koopbridge data gen').\n\n\
        Defaults are SPEC.md's recipe: n_mult 16, hidden 256,256,256, 60000 iterations, batch 64, Adam lr 1e-3 \
        decayed x0.9 every 1000 iterations, gradient-norm clipping 0.1, gamma 0.8, both regularisers, seed 17382, \
        validation every 1000 iterations; the best checkpoint by validation prediction error is saved and its \
        test prediction error reported. The model goes to OUT/ (model.safetensors + config.json), the figures \
        to OUT/metrics.json (with the learning curve: one point per validation), and the learning curve is drawn \
        as OUT/learning-curve.png.\n\n\
        Example: koopbridge train --data data/damped --out models/damped-m140k --train-samples 140000"
)]
pub struct TrainArgs {
    /// Dataset folder with train.npz, val.npz and test.npz.
    #[arg(long)]
    pub data: PathBuf,
    /// Output folder for the model and metrics.json (created if needed).
    #[arg(long)]
    pub out: PathBuf,
    /// Model to train.
    #[arg(long, value_enum, default_value_t = ModelKind::Koopman)]
    pub model: ModelKind,
    /// Train on the first m windows of the train pool (default: all).
    #[arg(long, value_name = "M")]
    pub train_samples: Option<usize>,
    /// Encoder output width as a multiple of nx (n_enc = n_mult·nx).
    #[arg(long, default_value_t = 16)]
    pub n_mult: usize,
    /// Hidden widths of the encoder, comma separated.
    #[arg(long, value_delimiter = ',', default_value = "256,256,256")]
    pub hidden: Vec<usize>,
    /// Optimiser iterations.
    #[arg(long, default_value_t = 60_000)]
    pub iterations: usize,
    /// Windows per batch.
    #[arg(long, default_value_t = 64)]
    pub batch: usize,
    /// Initial learning rate (decayed ×0.9 every 1000 iterations).
    #[arg(long, default_value_t = 1e-3)]
    pub lr: f64,
    /// Training seed (initialisation and batches).
    #[arg(long, default_value_t = 17382)]
    pub seed: u64,
    /// Turn the inverse-control loss off. On data paired as x_{t+1} = f(x_t, u_t) (--pairing
    /// aligned) it costs the damped pendulum 75% of prediction error for a 7x better-conditioned
    /// latent space (BENCHMARKS.md, "Training › Regulariser table").
    #[arg(long)]
    pub no_ctrl: bool,
    /// Turn the covariance loss off. Keep it whenever the inverse-control loss is on: alone, that
    /// loss gave the worst prediction error and conditioning of the four combinations.
    #[arg(long)]
    pub no_cov: bool,
    /// Discount γ of the multi-step losses (0.99 for legged robots).
    #[arg(long, default_value_t = 0.8)]
    pub gamma: f64,
    /// Train on z-scored states and inputs (SPEC.md for legged robots): mean and standard
    /// deviation of every dimension over the training pool, kept in the model, which the MPC
    /// and every other consumer then use in raw units. The reported prediction errors are in
    /// normalised units. Koopman models only.
    #[arg(long)]
    pub normalise: bool,
    /// Train in f64 instead of f32.
    #[arg(long)]
    pub f64: bool,
    /// Iterations between validations.
    #[arg(long, default_value_t = 1000)]
    pub validate_every: usize,
    /// Threads (0 = all cores). The batch is split into one row part per thread and the parts'
    /// gradients are summed, so the trained bits depend on this number: the default, 2, gives
    /// the same model on every machine (and what the trainer service uses).
    #[arg(long, default_value_t = 2)]
    pub threads: usize,
    /// EDMD only: total degree of the polynomial dictionary (default: chosen by validation error
    /// among 1 up to the largest with at most --edmd-max-features features — degree 20 on a 2-D
    /// state, 6 on a 4-D one; every degree tried is in metrics.json `degree_selection`).
    #[arg(long, value_name = "D")]
    pub edmd_degree: Option<usize>,
    /// EDMD only: the feature budget that bounds the degrees tried when --edmd-degree is not given.
    #[arg(long, value_name = "F", default_value_t = 250)]
    pub edmd_max_features: usize,
    /// EDMD only: ridge weight λ on the mean squared residual.
    #[arg(long, value_name = "LAMBDA", default_value_t = 1e-10)]
    pub edmd_ridge: f64,
    /// Print the metrics as one JSON object on the last line of stdout.
    #[arg(long)]
    pub json: bool,
}

/// What `metrics.json` holds for a gradient-trained run (`M` = [`TrainMetrics`] or, for the
/// NNDM, `NndmMetrics`).
#[derive(Serialize)]
struct MetricsFile<'a, M: Serialize> {
    model: ModelKind,
    data: &'a Path,
    out: &'a Path,
    #[serde(flatten)]
    metrics: &'a M,
    /// One point per validation (also drawn as `learning-curve.png`).
    learning_curve: &'a [CurvePoint],
}

/// Runs `koopbridge train`.
pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    let splits = Splits::load(&args.data)
        .with_context(|| format!("loading the dataset folder {}", args.data.display()))?;
    if args.normalise && args.model != ModelKind::Koopman {
        anyhow::bail!(
            "--normalise is implemented for the Koopman model only (asked for {:?})",
            args.model
        );
    }
    let edmd_defaults = koopman::model::edmd::EdmdConfig::default();
    if args.model != ModelKind::Edmd
        && (args.edmd_degree.is_some()
            || args.edmd_max_features != edmd_defaults.max_features
            || args.edmd_ridge != edmd_defaults.ridge)
    {
        anyhow::bail!(
            "--edmd-degree, --edmd-max-features and --edmd-ridge set the EDMD dictionary; \
             they do nothing for --model {:?} (use --model edmd)",
            args.model
        );
    }
    match args.model {
        ModelKind::Koopman => train_koopman(&args, &splits, false),
        ModelKind::Bilinear => train_koopman(&args, &splits, true),
        ModelKind::Edmd => train_edmd(&args, &splits),
        ModelKind::Nndm => train_nndm(&args, &splits),
    }
}

fn config(args: &TrainArgs) -> TrainConfig {
    TrainConfig {
        n_mult: args.n_mult,
        hidden: args.hidden.clone(),
        iterations: args.iterations,
        batch: args.batch,
        lr: args.lr,
        gamma: args.gamma,
        ctrl: !args.no_ctrl,
        cov: !args.no_cov,
        seed: args.seed,
        validate_every: args.validate_every,
        train_samples: args.train_samples,
        precision: if args.f64 {
            Precision::F64
        } else {
            Precision::F32
        },
        threads: args.threads,
        normalise: args.normalise,
        ..TrainConfig::default()
    }
}

/// The progress observer of every gradient-trained model: the bar (iteration, losses, best
/// validation error, it/s, ETA), one line per validation, and the learning curve.
fn observer<'b>(
    bar: &'b indicatif::ProgressBar,
    started: Instant,
    curve: &'b mut LearningCurve,
) -> impl FnMut(&Progress) -> ControlFlow<()> + 'b {
    move |p: &Progress| {
        curve.record(p);
        if p.iteration % 10 == 0 || p.validation.is_some() || p.iteration == p.total {
            bar.set_position(p.iteration as u64);
            bar.set_message(format!(
                "loss {:.5} (pred {:.5} ctrl {:.5} cov {:.2e}) val {} {:.0} it/s",
                p.loss.total,
                p.loss.pred,
                p.loss.ctrl,
                p.loss.cov,
                p.best_validation.map_or("-".into(), |v| format!("{v:.5}")),
                p.iterations_per_second
            ));
        }
        if let Some(v) = p.validation {
            let line = format!(
                "it {}/{} loss {:.5} pred {:.5} val_pred {:.5} best {:.5} lr {:.2e} {:.1} it/s {:.0}s",
                p.iteration,
                p.total,
                p.loss.total,
                p.loss.pred,
                v,
                p.best_validation.unwrap_or(f64::NAN),
                p.lr,
                p.iterations_per_second,
                started.elapsed().as_secs_f64()
            );
            if bar.is_hidden() {
                eprintln!("{line}");
            } else {
                bar.println(line);
            }
        }
        ControlFlow::Continue(())
    }
}

/// The Koopman model of SPEC, or with `bilinear` its bilinear variant
/// `z⁺ = A z + B u + Σ u_i N_i z` (same recipe, N_i initialised to zero).
fn train_koopman(args: &TrainArgs, splits: &Splits, bilinear: bool) -> anyhow::Result<()> {
    let mut cfg = TrainConfig {
        bilinear,
        ..config(args)
    };
    // No flag turns ctrl on explicitly (it is on by default), so data without inputs turn it off.
    if cfg.settle_ctrl_for(splits.train.nu, false)? {
        eprintln!("note: the data have no inputs (nu = 0): the inverse-control loss is off");
    }
    let (train, val, test) = (&splits.train, &splits.val, Some(&splits.test));
    type Save = Box<dyn FnOnce(&Path) -> koopman::Result<()>>;
    let ((save, metrics), curve) = with_progress(cfg.iterations, |observer| {
        let trained: (Save, TrainMetrics) = if bilinear {
            let o = koopman::train::train_bilinear(&cfg, train, val, test, observer)?;
            (Box::new(move |dir| o.model.save(dir)), o.metrics)
        } else {
            let o = koopman::train::train(&cfg, train, val, test, observer)?;
            (Box::new(move |dir| o.model.save(dir)), o.metrics)
        };
        Ok(trained)
    })?;
    save(&args.out).with_context(|| format!("saving the model to {}", args.out.display()))?;
    write_metrics(args, &metrics, &curve)?;
    report(args, &metrics, &metrics, &curve, &splits.test)
}

/// The NNDM baseline (SPEC's ablation): an MLP x⁺ = x + g([x, u]) with the parameter count of
/// the Koopman model of the same --n-mult/--hidden, trained on the same prediction loss.
fn train_nndm(args: &TrainArgs, splits: &Splits) -> anyhow::Result<()> {
    let cfg = config(args);
    let (outcome, curve) = with_progress(cfg.iterations, |observer| {
        koopman::train::nndm::train_nndm(
            &cfg,
            &splits.train,
            &splits.val,
            Some(&splits.test),
            observer,
        )
    })?;
    outcome
        .model
        .save(&args.out)
        .with_context(|| format!("saving the model to {}", args.out.display()))?;
    write_metrics(args, &outcome.metrics, &curve)?;
    println!(
        "NNDM hidden {:?}: {} parameters (the Koopman model of the same config has {})",
        outcome.metrics.hidden, outcome.metrics.base.num_params, outcome.metrics.koopman_num_params
    );
    report(
        args,
        &outcome.metrics.base,
        &outcome.metrics,
        &curve,
        &splits.test,
    )
}

/// Runs `fit` (a gradient-trained model's loop) behind the progress bar with [`observer`];
/// returns its outcome and the learning curve, the bar cleared.
fn with_progress<O>(
    iterations: usize,
    fit: impl FnOnce(&mut dyn FnMut(&Progress) -> ControlFlow<()>) -> koopman::Result<O>,
) -> anyhow::Result<(O, LearningCurve)> {
    let bar = progress_bar(iterations);
    let mut curve = LearningCurve::default();
    let mut observer = observer(&bar, Instant::now(), &mut curve);
    let outcome = fit(&mut observer)?;
    drop(observer);
    bar.finish_and_clear();
    Ok((outcome, curve))
}

/// EDMD with control (SPEC's baseline): a least-squares fit on the first m windows.
fn train_edmd(args: &TrainArgs, splits: &Splits) -> anyhow::Result<()> {
    let started = Instant::now();
    let m = args.train_samples.unwrap_or(splits.train.n);
    let data = splits.train.head(m)?;
    let cfg = koopman::model::edmd::EdmdConfig {
        degree: args.edmd_degree,
        max_features: args.edmd_max_features,
        ridge: args.edmd_ridge,
        ..Default::default()
    };
    let (model, selection) =
        koopman::model::edmd::fit_by_validation(&data, &splits.val, &cfg, args.gamma)?;
    let fit_seconds = started.elapsed().as_secs_f64();
    model
        .save(&args.out)
        .with_context(|| format!("saving the model to {}", args.out.display()))?;
    let test = koopman::analysis::prediction_error(&model, &splits.test, args.gamma)?;
    let val = koopman::analysis::prediction_error(&model, &splits.val, args.gamma)?;
    let metrics = serde_json::json!({
        "model": args.model,
        "data": args.data,
        "out": args.out,
        "test_prediction_error": test,
        "validation_prediction_error": val,
        "iterations_per_second": null,
        "fit_seconds": fit_seconds,
        "wall_seconds": started.elapsed().as_secs_f64(),
        "train_samples": m,
        "pairing": splits.train.meta.pairing,
        "env": splits.train.meta.env,
        "gamma": args.gamma,
        "config": model.config,
        "degree_selection": selection,
        "fit": model.info,
    });
    write_atomic(
        &args.out.join("metrics.json"),
        &serde_json::to_vec_pretty(&metrics)?,
    )?;
    println!(
        "fitted EDMD on {} ({m} windows, {:?} pairing) in {fit_seconds:.2} s: degree {} ({}), test prediction error {test:.6} over {} windows",
        splits.train.meta.env,
        splits.train.meta.pairing,
        selection.chosen,
        if selection.by_validation {
            format!(
                "the lowest within 5 % of the best validation error of degrees 1 to {}",
                selection.trials.len()
            )
        } else {
            "--edmd-degree".to_string()
        },
        splits.test.n
    );
    println!("model and metrics.json in {}", args.out.display());
    if args.json {
        println!("{}", serde_json::to_string(&metrics)?);
    }
    Ok(())
}

fn progress_bar(total: usize) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(total as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{elapsed_precise} [{bar:30}] {pos}/{len} eta {eta} {msg}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    bar
}

/// Writes `OUT/metrics.json` and `OUT/learning-curve.png`.
fn write_metrics<M: Serialize>(
    args: &TrainArgs,
    metrics: &M,
    curve: &LearningCurve,
) -> anyhow::Result<()> {
    let file = MetricsFile {
        model: args.model,
        data: &args.data,
        out: &args.out,
        metrics,
        learning_curve: curve.points(),
    };
    let json = serde_json::to_vec_pretty(&file)?;
    write_atomic(&args.out.join("metrics.json"), &json)?;
    let title = format!(
        "{:?} {} (data {})",
        args.model,
        args.out.display(),
        args.data.display()
    );
    curve.write_png(&args.out.join("learning-curve.png"), &title)
}

/// Prints the summary of `m`; with `--json`, `full` (what metrics.json holds) as the last line.
fn report<M: Serialize>(
    args: &TrainArgs,
    m: &TrainMetrics,
    full: &M,
    curve: &LearningCurve,
    test: &Dataset,
) -> anyhow::Result<()> {
    println!(
        "trained {:?} on {} ({} windows, {:?} pairing): test prediction error {} over {} windows; best validation {:.6} at iteration {}; {:.1} it/s, {:.1} s",
        args.model,
        m.env,
        m.train_samples,
        m.pairing,
        m.test_prediction_error.map_or("-".into(), |e| format!("{e:.6}")),
        test.n,
        m.best_validation_prediction_error,
        m.best_iteration,
        m.iterations_per_second,
        m.wall_seconds
    );
    println!(
        "model, metrics.json and learning-curve.png in {}",
        args.out.display()
    );
    if args.json {
        let file = MetricsFile {
            model: args.model,
            data: &args.data,
            out: &args.out,
            metrics: full,
            learning_curve: curve.points(),
        };
        println!("{}", serde_json::to_string(&file)?);
    }
    Ok(())
}
