//! Short training runs on small generated datasets: the loss decreases, runs are deterministic,
//! save → load keeps predictions, and bad input gives typed errors.

mod common;

use common::{data, small_cfg};

use koopman::data::{generate, Dataset, Pairing};
use koopman::model::koopman::KoopmanModel;
use koopman::model::{load_lifted, LiftedModel};
use koopman::train::{prediction_error, train, Precision, TrainConfig};
use koopman::Error;
use std::ops::ControlFlow;

fn no_observer() -> impl FnMut(&koopman::train::Progress) -> ControlFlow<()> {
    |_| ControlFlow::Continue(())
}

#[test]
fn a_short_run_decreases_the_prediction_error_and_reports_it() {
    let (tr, va, te) = (data(200, 1), data(100, 2), data(100, 3));
    let cfg = small_cfg(300);
    let untrained = KoopmanModel::init(
        koopman::model::arch::Arch::new(2, 1, &cfg.hidden, cfg.n_mult).unwrap(),
        cfg.seed,
    )
    .unwrap();
    let before = prediction_error(&untrained, &te, 0.8).unwrap();
    let mut seen = 0;
    let mut vals = Vec::new();
    let out = train(&cfg, &tr, &va, Some(&te), &mut |p| {
        seen += 1;
        if let Some(v) = p.validation {
            vals.push(v);
        }
        ControlFlow::Continue(())
    })
    .unwrap();
    assert_eq!(seen, 300);
    assert_eq!(vals.len(), 6);
    let after = out.metrics.test_prediction_error.unwrap();
    assert!(after < 0.5 * before, "test error {before} → {after}");
    // The reported test error is the one of the returned (best) model, and the best validation
    // error is the minimum seen.
    assert_eq!(after, prediction_error(&out.model, &te, 0.8).unwrap());
    let min = vals.iter().cloned().fold(f64::INFINITY, f64::min);
    assert_eq!(out.metrics.best_validation_prediction_error, min);
    // The f32 validation and the f64 evaluation of the same checkpoint agree closely.
    let v64 = prediction_error(&out.model, &va, 0.8).unwrap();
    assert!((v64 - min).abs() < 1e-4 * min.max(1e-3), "{v64} vs {min}");
    // Independent implementation of the metric (koopman::analysis) agrees.
    let other = koopman::analysis::prediction_error(&out.model, &te, 0.8).unwrap();
    assert!((other - after).abs() < 1e-9 * after, "{other} vs {after}");
}

#[test]
fn runs_are_deterministic_for_a_seed_in_f32_and_f64() {
    let (tr, va) = (data(100, 4), data(50, 5));
    for precision in [Precision::F32, Precision::F64] {
        let cfg = TrainConfig {
            precision,
            ..small_cfg(40)
        };
        let a = train(&cfg, &tr, &va, None, &mut no_observer()).unwrap();
        let b = train(&cfg, &tr, &va, None, &mut no_observer()).unwrap();
        assert_eq!(a.model.params(), b.model.params());
        let c = train(
            &TrainConfig {
                seed: 1,
                ..cfg.clone()
            },
            &tr,
            &va,
            None,
            &mut no_observer(),
        )
        .unwrap();
        assert_ne!(a.model.params(), c.model.params());
    }
}

#[test]
fn save_load_round_trip_keeps_predictions_exactly() {
    let (tr, va) = (data(100, 6), data(50, 7));
    let out = train(&small_cfg(20), &tr, &va, None, &mut no_observer()).unwrap();
    let dir = std::env::temp_dir().join(format!("kb-train-roundtrip-{}", std::process::id()));
    out.model.save(&dir).unwrap();
    let back = KoopmanModel::load(&dir).unwrap();
    assert_eq!(back.params(), out.model.params());
    let x = [0.3, -1.2];
    assert_eq!(back.lift(&x), out.model.lift(&x));
    let dynm: Box<dyn LiftedModel> = load_lifted(&dir).unwrap();
    assert_eq!(dynm.lift(&x), out.model.lift(&x));
    assert_eq!(dynm.a(), out.model.a());
    assert_eq!(dynm.b(), out.model.b());
    assert_eq!(
        prediction_error(&back, &va, 0.8).unwrap(),
        prediction_error(&out.model, &va, 0.8).unwrap()
    );
    // The lifting's first nx coordinates are x itself.
    assert_eq!(&back.lift(&x)[..2], &x);
    // The checked lifting agrees, and refuses wrong lengths and NaN with typed errors.
    assert_eq!(dynm.try_lift(&x).unwrap(), out.model.lift(&x));
    assert!(matches!(
        dynm.try_lift(&[0.3]),
        Err(Error::Dimension { .. })
    ));
    assert!(matches!(
        dynm.try_lift(&[0.3, f64::NAN]),
        Err(Error::NonFinite(_))
    ));
    // Loading it as another kind of model names both kinds.
    match koopman::model::nndm::NndmModel::load(&dir) {
        Err(Error::Format { message, .. }) => {
            assert!(
                message.contains("kind is 'koopman', expected 'nndm'"),
                "{message}"
            )
        }
        other => panic!("expected a format error, got {:?}", other.map(|_| ())),
    }
    // A truncated weights file is a typed error, not a panic.
    let st = dir.join("model.safetensors");
    let bytes = std::fs::read(&st).unwrap();
    std::fs::write(&st, &bytes[..bytes.len() / 2]).unwrap();
    assert!(matches!(
        KoopmanModel::load(&dir),
        Err(Error::Format { .. })
    ));
    std::fs::remove_dir_all(&dir).unwrap();
    assert!(matches!(KoopmanModel::load(&dir), Err(Error::Io { .. })));
}

#[test]
fn bad_inputs_are_typed_errors() {
    let (tr, va) = (data(20, 8), data(10, 9));
    let cfg = small_cfg(5);
    let run = |cfg: &TrainConfig, tr: &Dataset, va: &Dataset| {
        train(cfg, tr, va, None, &mut no_observer())
    };
    // m larger than the pool.
    let big = TrainConfig {
        train_samples: Some(21),
        ..cfg.clone()
    };
    assert!(matches!(
        run(&big, &tr, &va),
        Err(Error::InvalidArgument(_))
    ));
    // NaN in the data.
    let mut nan = tr.clone();
    nan.x[5] = f64::NAN;
    assert!(matches!(run(&cfg, &nan, &va), Err(Error::NonFinite(_))));
    // Validation data of another dimension.
    let sys = koopman::systems::by_name("double-pendulum").unwrap();
    let other = generate(sys.as_ref(), 10, 15, 1, Pairing::Aligned).unwrap();
    assert!(matches!(
        run(&cfg, &tr, &other),
        Err(Error::Dimension { .. })
    ));
    // Inconsistent buffers.
    let mut short = tr.clone();
    short.u.pop();
    assert!(matches!(
        run(&cfg, &short, &va),
        Err(Error::Dimension { .. })
    ));
    // Nonsense settings.
    assert!(matches!(
        run(
            &TrainConfig {
                batch: 0,
                ..cfg.clone()
            },
            &tr,
            &va
        ),
        Err(Error::InvalidArgument(_))
    ));
    assert!(matches!(
        run(
            &TrainConfig {
                lr: f64::NAN,
                ..cfg.clone()
            },
            &tr,
            &va
        ),
        Err(Error::InvalidArgument(_))
    ));
    // Cancellation through the observer.
    let r = train(&cfg, &tr, &va, None, &mut |p| {
        if p.iteration == 2 {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    });
    assert!(matches!(r, Err(Error::Cancelled)));
}
