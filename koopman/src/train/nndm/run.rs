//! The NNDM training loop: batch sampling, BPTT loss and gradient, clipping, Adam, validation
//! and the best checkpoint — the Koopman loop's recipe with the NNDM's loss.

use super::eval::{prediction_error, NndmEval};
use super::loss::NndmLossWs;
use super::{NndmMetrics, NndmOutcome};
use crate::data::Dataset;
use crate::model::arch::Arch;
use crate::model::nndm::{init_params, NndmArch, NndmModel};
use crate::model::scalar::Real;
use crate::rng::Rng;
use crate::train::adam::{clip_grad_norm, step_lr, Adam};
use crate::train::eval::check_dataset;
use crate::train::loss::LossParts;
use crate::train::tracker::{RunTracker, StepInfo};
use crate::train::{Precision, Progress, TrainConfig, TrainMetrics};
use crate::{Error, Result};
use faer::Par;
use std::ops::ControlFlow;
use std::time::Instant;

/// Trains an NNDM on the first `cfg.train_samples` windows of `train` with SPEC's prediction
/// loss and optimiser settings, validating on `val` and reporting the best checkpoint's
/// prediction error on `test`. The hidden widths are `cfg.hidden.len()` equal layers sized to
/// match the parameter count of the Koopman model of `cfg` ([`NndmArch::matching_koopman`]);
/// `cfg.ctrl` and `cfg.cov` are ignored. `observer` sees every iteration; returning `Break`
/// stops the run with [`Error::Cancelled`].
pub fn train_nndm(
    cfg: &TrainConfig,
    train: &Dataset,
    val: &Dataset,
    test: Option<&Dataset>,
    observer: &mut dyn FnMut(&Progress) -> ControlFlow<()>,
) -> Result<NndmOutcome> {
    check_config(cfg)?;
    let (nx, nu) = (train.nx, train.nu);
    check_dataset(train, nx, nu)?;
    for (name, d) in [("validation", Some(val)), ("test", test)] {
        if let Some(d) = d {
            check_dataset(d, nx, nu)?;
            if d.steps != train.steps {
                return Err(Error::dimension(
                    format!("{name} steps per window"),
                    train.steps,
                    d.steps,
                ));
            }
        }
    }
    let m = cfg.train_samples.unwrap_or(train.n);
    if m == 0 || m > train.n {
        return Err(Error::InvalidArgument(format!(
            "train_samples m = {m} must be between 1 and the training pool size {}",
            train.n
        )));
    }
    let koopman_num_params = Arch::new(nx, nu, &cfg.hidden, cfg.n_mult)?.num_params();
    let arch = NndmArch::matching(nx, nu, cfg.hidden.len(), koopman_num_params)?;
    let start = Instant::now();
    let (best, best_val, best_it, secs, last) = match cfg.precision {
        Precision::F32 => run_loop::<f32>(cfg, &arch, train, m, val, observer)?,
        Precision::F64 => run_loop::<f64>(cfg, &arch, train, m, val, observer)?,
    };
    let mut model = NndmModel::from_params(arch.clone(), best)?;
    let test_err = match test {
        Some(t) => Some(prediction_error(&model, t, cfg.gamma)?),
        None => None,
    };
    let metrics = NndmMetrics {
        base: TrainMetrics {
            test_prediction_error: test_err,
            best_validation_prediction_error: best_val,
            best_iteration: best_it,
            iterations: cfg.iterations,
            iterations_per_second: cfg.iterations as f64 / secs,
            wall_seconds: start.elapsed().as_secs_f64(),
            train_samples: m,
            num_params: arch.num_params(),
            final_loss: last,
            pairing: train.meta.pairing,
            env: train.meta.env.clone(),
            config: TrainConfig {
                ctrl: false,
                cov: false,
                ..cfg.clone()
            },
        },
        hidden: arch.hidden.clone(),
        koopman_num_params,
    };
    model.metadata = serde_json::json!({
        "trainer": "koopbridge",
        "metrics": metrics,
        "dataset": train.meta,
    });
    Ok(NndmOutcome { model, metrics })
}

fn check_config(cfg: &TrainConfig) -> Result<()> {
    if cfg.normalise {
        return Err(Error::InvalidArgument(
            "normalised training is implemented for the Koopman model only, not the NNDM".into(),
        ));
    }
    if cfg.n_mult == 0 || cfg.hidden.is_empty() || cfg.hidden.contains(&0) {
        return Err(Error::InvalidArgument(
            "n_mult must be ≥ 1 and hidden a non-empty list of widths ≥ 1 (they set the NNDM's parameter budget)".into(),
        ));
    }
    crate::train::check_optimiser_settings(cfg)
}

/// (best parameters in f64, best validation error, its iteration, seconds spent iterating,
/// last batch's losses)
type LoopResult = (Vec<f64>, f64, usize, f64, LossParts);

fn run_loop<T: Real>(
    cfg: &TrainConfig,
    arch: &NndmArch,
    train: &Dataset,
    m: usize,
    val: &Dataset,
    observer: &mut dyn FnMut(&Progress) -> ControlFlow<()>,
) -> Result<LoopResult> {
    let par = Par::rayon(cfg.threads);
    let init = init_params(arch, &mut Rng::new(cfg.seed))?;
    let mut params: Vec<T> = init.iter().map(|&v| T::from_f64(v)).collect();
    let mut grad = vec![T::default(); params.len()];
    let mut tracker = RunTracker::new(&params);
    let mut adam = Adam::<T>::new(params.len());
    let mut ws = NndmLossWs::<T>::new(arch, cfg.batch, train.steps, par);
    let mut eval = NndmEval::<T>::new(arch, 1024, par);
    let mut rng = Rng::derive(cfg.seed, 1);
    let mut idx = vec![0usize; cfg.batch];
    let mut last = LossParts::default();
    for it in 0..cfg.iterations {
        let t0 = Instant::now();
        for v in idx.iter_mut() {
            *v = rng.below(m);
        }
        ws.fill(train, &idx)?;
        let pred = ws.loss_and_grad(&params, &mut grad, cfg.gamma)?;
        if !pred.is_finite() {
            return Err(Error::Numerical(format!(
                "training diverged at iteration {} (loss {pred})",
                it + 1
            )));
        }
        clip_grad_norm(&mut grad, cfg.clip);
        let lr = step_lr(cfg.lr, cfg.lr_decay, cfg.lr_step, it);
        adam.step(&mut params, &grad, lr);
        tracker.iter_secs += t0.elapsed().as_secs_f64();
        last = LossParts {
            pred,
            total: pred,
            ..LossParts::default()
        };
        tracker.after_step(
            cfg,
            StepInfo {
                done: it + 1,
                loss: last,
                lr,
            },
            &params,
            |p| eval.pred_loss(p, val, cfg.gamma),
            observer,
        )?;
    }
    let t = tracker.finish()?;
    let best = t.best.iter().map(|v| v.to_f64()).collect();
    Ok((best, t.best_val, t.best_it, t.iter_secs, last))
}
