//! The training loop: sampling, loss and gradient, clipping, Adam, validation, checkpoints.

use super::adam::{clip_grad_norm, step_lr, Adam};
use super::checkpoint::{data_fingerprint, Checkpoint};
use super::eval::{check_dataset, PredEval};
use super::loss::{LossOptions, LossParts, LossWs};
use super::tracker::{RunTracker, StepInfo};
use super::{BilinearOutcome, Precision, Progress, TrainConfig, TrainMetrics, TrainOutcome};
use crate::data::{Dataset, Normalisation};
use crate::model::arch::Arch;
use crate::model::bilinear::BilinearModel;
use crate::model::init::init_params;
use crate::model::koopman::KoopmanModel;
use crate::model::scalar::Real;
use crate::rng::Rng;
use crate::{Error, Result};
use faer::Par;
use std::ops::ControlFlow;
use std::time::Instant;

/// Trains a neural Koopman model on the first `cfg.train_samples` windows of `train`, validating
/// on `val` and reporting the best checkpoint's prediction error on `test`. `observer` sees
/// every iteration; returning `Break` stops the run with [`Error::Cancelled`].
pub fn train(
    cfg: &TrainConfig,
    train: &Dataset,
    val: &Dataset,
    test: Option<&Dataset>,
    observer: &mut dyn FnMut(&Progress) -> ControlFlow<()>,
) -> Result<TrainOutcome> {
    train_resumable(cfg, train, val, test, None, observer, &mut |_| {})
}

/// [`train`] that can be interrupted and continued: `on_checkpoint` receives a [`Checkpoint`]
/// after every validation (every `validate_every` iterations and the last one), and a run given
/// `resume: Some(checkpoint)` continues from it. With the same `threads`, a resumed run ends with
/// bit-for-bit the model and metrics (timings aside) of an uninterrupted one. A checkpoint of
/// another configuration or other data is refused with [`Error::InvalidArgument`].
pub fn train_resumable(
    cfg: &TrainConfig,
    train: &Dataset,
    val: &Dataset,
    test: Option<&Dataset>,
    resume: Option<&Checkpoint>,
    observer: &mut dyn FnMut(&Progress) -> ControlFlow<()>,
    on_checkpoint: &mut dyn FnMut(&Checkpoint),
) -> Result<TrainOutcome> {
    if cfg.bilinear {
        return Err(Error::InvalidArgument(
            "the configuration asks for a bilinear model: use train_bilinear".into(),
        ));
    }
    // The fingerprint is of the data as given, before any z-scoring: what a trainer checks a
    // checkpoint against before it resumes (`data_fingerprint` on the files it loaded).
    let fingerprint = run_fingerprint(cfg, train, val);
    let normalised = NormalisedSplits::new(cfg, train, val, test)?;
    let (train, val, test) = normalised.views(train, val, test);
    let (arch, best, mut metrics) = train_params(
        cfg,
        (train, val, test),
        fingerprint,
        resume,
        observer,
        on_checkpoint,
    )?;
    let mut model = KoopmanModel::from_params(arch, best)?;
    if let Some(norm) = normalised.norm.clone() {
        model = model.with_normalisation(norm)?;
    }
    if let Some(t) = test {
        metrics.test_prediction_error = Some(super::prediction_error(&model, t, cfg.gamma)?);
    }
    model.metadata = run_metadata(&metrics, train);
    Ok(TrainOutcome { model, metrics })
}

/// The z-scored copies of a run's splits when `cfg.normalise` is set (statistics over the whole
/// training pool, SPEC.md); empty otherwise.
struct NormalisedSplits {
    norm: Option<Normalisation>,
    data: Option<(Dataset, Dataset, Option<Dataset>)>,
}

impl NormalisedSplits {
    fn new(
        cfg: &TrainConfig,
        train: &Dataset,
        val: &Dataset,
        test: Option<&Dataset>,
    ) -> Result<Self> {
        if !cfg.normalise {
            return Ok(NormalisedSplits {
                norm: None,
                data: None,
            });
        }
        let norm = Normalisation::fit(train)?;
        let data = (
            norm.apply(train)?,
            norm.apply(val)?,
            test.map(|t| norm.apply(t)).transpose()?,
        );
        Ok(NormalisedSplits {
            norm: Some(norm),
            data: Some(data),
        })
    }

    /// The splits to train on: the normalised copies, or the given ones.
    fn views<'a>(
        &'a self,
        train: &'a Dataset,
        val: &'a Dataset,
        test: Option<&'a Dataset>,
    ) -> (&'a Dataset, &'a Dataset, Option<&'a Dataset>) {
        match &self.data {
            Some((t, v, s)) => (t, v, s.as_ref()),
            None => (train, val, test),
        }
    }
}

/// [`train`] for the bilinear model `z⁺ = A z + B u + Σ_i u_i N_i z` (`cfg.bilinear` must be
/// set): SPEC's encoder, losses and optimiser, N_i initialised to zero.
pub fn train_bilinear(
    cfg: &TrainConfig,
    train: &Dataset,
    val: &Dataset,
    test: Option<&Dataset>,
    observer: &mut dyn FnMut(&Progress) -> ControlFlow<()>,
) -> Result<BilinearOutcome> {
    train_bilinear_resumable(cfg, train, val, test, None, observer, &mut |_| {})
}

/// [`train_resumable`] for the bilinear model (`cfg.bilinear` must be set).
pub fn train_bilinear_resumable(
    cfg: &TrainConfig,
    train: &Dataset,
    val: &Dataset,
    test: Option<&Dataset>,
    resume: Option<&Checkpoint>,
    observer: &mut dyn FnMut(&Progress) -> ControlFlow<()>,
    on_checkpoint: &mut dyn FnMut(&Checkpoint),
) -> Result<BilinearOutcome> {
    if !cfg.bilinear {
        return Err(Error::InvalidArgument(
            "train_bilinear needs a configuration with bilinear = true".into(),
        ));
    }
    let fingerprint = run_fingerprint(cfg, train, val);
    let (arch, best, mut metrics) = train_params(
        cfg,
        (train, val, test),
        fingerprint,
        resume,
        observer,
        on_checkpoint,
    )?;
    let mut model = BilinearModel::from_params(arch, best)?;
    if let Some(t) = test {
        metrics.test_prediction_error =
            Some(super::bilinear_prediction_error(&model, t, cfg.gamma)?);
    }
    model.metadata = run_metadata(&metrics, train);
    Ok(BilinearOutcome { model, metrics })
}

fn run_metadata(metrics: &TrainMetrics, train: &Dataset) -> serde_json::Value {
    serde_json::json!({
        "trainer": "koopbridge",
        "metrics": metrics,
        "dataset": train.meta,
    })
}

/// [`data_fingerprint`] of a run of `cfg` on the data as given (its first
/// `train_samples` training windows and the validation set).
pub fn run_fingerprint(cfg: &TrainConfig, train: &Dataset, val: &Dataset) -> u64 {
    let m = cfg.train_samples.unwrap_or(train.n).min(train.n);
    data_fingerprint(train, m, val)
}

/// The shared run: checks, the loop, and the metrics without the test error. Returns the
/// architecture and the best parameters (the bilinear ones end with the N_i). `fingerprint`:
/// [`run_fingerprint`] of the data as the caller was given them (before any z-scoring).
fn train_params(
    cfg: &TrainConfig,
    (train, val, test): (&Dataset, &Dataset, Option<&Dataset>),
    fingerprint: u64,
    resume: Option<&Checkpoint>,
    observer: &mut dyn FnMut(&Progress) -> ControlFlow<()>,
    on_checkpoint: &mut dyn FnMut(&Checkpoint),
) -> Result<(Arch, Vec<f64>, TrainMetrics)> {
    check_config(cfg)?;
    let (nx, nu) = (train.nx, train.nu);
    check_dataset(train, nx, nu)?;
    check_dataset(val, nx, nu)?;
    if val.steps != train.steps {
        return Err(Error::dimension(
            "validation steps per window",
            train.steps,
            val.steps,
        ));
    }
    if let Some(t) = test {
        check_dataset(t, nx, nu)?;
        if t.steps != train.steps {
            return Err(Error::dimension(
                "test steps per window",
                train.steps,
                t.steps,
            ));
        }
    }
    let m = cfg.train_samples.unwrap_or(train.n);
    if m == 0 || m > train.n {
        return Err(Error::InvalidArgument(format!(
            "train_samples m = {m} must be between 1 and the training pool size {}",
            train.n
        )));
    }
    let arch = Arch::new(nx, nu, &cfg.hidden, cfg.n_mult)?;
    if cfg.ctrl && nu == 0 {
        return Err(Error::InvalidArgument(super::AUTONOMOUS_CTRL.into()));
    }
    if cfg.bilinear && nu == 0 {
        return Err(Error::InvalidArgument(
            "a bilinear model needs inputs: this dataset has nu = 0".into(),
        ));
    }
    let num_params = arch.num_params() + n_bilinear(cfg, &arch);
    if let Some(ck) = resume {
        ck.check_compatible(cfg, num_params, fingerprint)?;
    }
    let start = Instant::now();
    let ctx = LoopCtx {
        cfg,
        arch: &arch,
        train,
        m,
        val,
        fingerprint,
    };
    let (best, best_val, best_it, its, last) = match cfg.precision {
        Precision::F32 => run_loop::<f32>(&ctx, resume, observer, on_checkpoint)?,
        Precision::F64 => run_loop::<f64>(&ctx, resume, observer, on_checkpoint)?,
    };
    let train_secs = its;
    let metrics = TrainMetrics {
        test_prediction_error: None,
        best_validation_prediction_error: best_val,
        best_iteration: best_it,
        iterations: cfg.iterations,
        iterations_per_second: cfg.iterations as f64 / train_secs,
        wall_seconds: start.elapsed().as_secs_f64(),
        train_samples: m,
        num_params,
        final_loss: last,
        pairing: train.meta.pairing,
        env: train.meta.env.clone(),
        config: cfg.clone(),
    };
    Ok((arch, best, metrics))
}

/// Bilinear parameters of the run (0 for the linear model).
fn n_bilinear(cfg: &TrainConfig, arch: &Arch) -> usize {
    if cfg.bilinear {
        super::bilinear::bilinear_len(arch)
    } else {
        0
    }
}

fn check_config(cfg: &TrainConfig) -> Result<()> {
    let bad = |m: &str| Err(Error::InvalidArgument(m.to_string()));
    if cfg.n_mult == 0 {
        return bad("n_mult must be ≥ 1");
    }
    super::check_optimiser_settings(cfg)?;
    if cfg.cov && cfg.batch < 2 {
        return bad("the covariance loss needs batch ≥ 2 (or --no-cov)");
    }
    if cfg.normalise && cfg.bilinear {
        return bad("normalised training is implemented for the linear Koopman model only, not the bilinear one");
    }
    Ok(())
}

/// (best parameters in f64, best validation error, its iteration, seconds spent iterating,
/// last batch's losses)
type LoopResult = (Vec<f64>, f64, usize, f64, LossParts);

/// What the loop trains on.
struct LoopCtx<'a> {
    cfg: &'a TrainConfig,
    arch: &'a Arch,
    train: &'a Dataset,
    m: usize,
    val: &'a Dataset,
    fingerprint: u64,
}

fn to_t<T: Real>(v: &[f64]) -> Vec<T> {
    v.iter().map(|&x| T::from_f64(x)).collect()
}

fn to_f64<T: Real>(v: &[T]) -> Vec<f64> {
    v.iter().map(|x| x.to_f64()).collect()
}

fn run_loop<T: Real>(
    ctx: &LoopCtx<'_>,
    resume: Option<&Checkpoint>,
    observer: &mut dyn FnMut(&Progress) -> ControlFlow<()>,
    on_checkpoint: &mut dyn FnMut(&Checkpoint),
) -> Result<LoopResult> {
    let LoopCtx {
        cfg,
        arch,
        train,
        m,
        val,
        fingerprint,
    } = *ctx;
    let par = Par::rayon(cfg.threads);
    let mut params: Vec<T> = match resume {
        Some(ck) => to_t(&ck.params),
        None => {
            let mut p = init_params(arch, &mut Rng::new(cfg.seed))?;
            p.resize(p.len() + n_bilinear(cfg, arch), 0.0);
            to_t(&p)
        }
    };
    let mut grad = vec![T::default(); params.len()];
    let mut tracker = RunTracker::new(&params);
    if let Some(ck) = resume {
        tracker.best = to_t(&ck.best);
        tracker.best_val = ck.best_validation.unwrap_or(f64::INFINITY);
        tracker.best_it = ck.best_iteration;
        tracker.iter_secs = ck.iter_seconds;
    }
    let mut adam = match resume {
        Some(ck) => Adam::<T>::from_state(to_t(&ck.adam_m), to_t(&ck.adam_v), ck.adam_steps)
            .filter(|a| a.moments().0.len() == params.len())
            .ok_or_else(|| {
                Error::InvalidArgument(
                    "cannot resume: the checkpoint's Adam moments do not match the parameters"
                        .into(),
                )
            })?,
        None => Adam::<T>::new(params.len()),
    };
    let (b, steps, nx, nu) = (cfg.batch, train.steps, arch.nx, arch.nu);
    let mut ws = LossWs::<T>::with_dynamics(arch, b, steps, par, cfg.bilinear);
    let mut eval = PredEval::<T>::with_dynamics(arch, 2048, par, cfg.bilinear);
    let mut rng = match resume {
        Some(ck) => Rng::from_state(ck.rng, ck.rng_spare),
        None => Rng::derive(cfg.seed, 1),
    };
    let mut idx = vec![0usize; b];
    let opts = LossOptions {
        gamma: cfg.gamma,
        ctrl: cfg.ctrl,
        cov: cfg.cov,
    };
    let mut last = resume.map_or(LossParts::default(), |ck| ck.last_loss);
    let n = (steps + 1) * b;
    for it in resume.map_or(0, |ck| ck.iteration)..cfg.iterations {
        let t0 = Instant::now();
        for v in idx.iter_mut() {
            *v = rng.below(m);
        }
        {
            let xs = ws.states_mut();
            for (i, &w) in idx.iter().enumerate() {
                for t in 0..=steps {
                    let s = train.state(w, t);
                    for j in 0..nx {
                        xs[j * n + t * b + i] = T::from_f64(s[j]);
                    }
                }
            }
            let us = ws.inputs_mut();
            for (i, &w) in idx.iter().enumerate() {
                for t in 0..steps {
                    let u = train.input(w, t);
                    for j in 0..nu {
                        us[j * steps * b + t * b + i] = T::from_f64(u[j]);
                    }
                }
            }
        }
        let parts = ws.loss_and_grad(&params, &mut grad, &opts)?;
        if !parts.total.is_finite() {
            return Err(Error::Numerical(format!(
                "training diverged at iteration {} (loss {:?})",
                it + 1,
                parts
            )));
        }
        clip_grad_norm(&mut grad, cfg.clip);
        let lr = step_lr(cfg.lr, cfg.lr_decay, cfg.lr_step, it);
        adam.step(&mut params, &grad, lr);
        tracker.iter_secs += t0.elapsed().as_secs_f64();
        last = parts;
        let done = it + 1;
        let validation = tracker.after_step(
            cfg,
            StepInfo {
                done,
                loss: parts,
                lr,
            },
            &params,
            |p| eval.pred_loss(p, val, cfg.gamma),
            observer,
        )?;
        if validation.is_some() {
            let (am, av) = adam.moments();
            let (state, spare) = rng.state();
            on_checkpoint(&Checkpoint {
                iteration: done,
                config: cfg.clone(),
                data_fingerprint: fingerprint,
                params: to_f64(&params),
                adam_m: to_f64(am),
                adam_v: to_f64(av),
                adam_steps: adam.steps(),
                rng: state,
                rng_spare: spare,
                best: to_f64(&tracker.best),
                best_validation: tracker.best_validation(),
                best_iteration: tracker.best_it,
                iter_seconds: tracker.iter_secs,
                last_loss: last,
            });
        }
    }
    let t = tracker.finish()?;
    Ok((to_f64(&t.best), t.best_val, t.best_it, t.iter_secs, last))
}
