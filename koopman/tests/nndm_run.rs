//! NNDM runs on small generated damped-pendulum datasets: a short run decreases the error and
//! reports it faithfully, runs are deterministic, save → load keeps predictions, bad input
//! gives typed errors, and a trained NNDM drives random-shooting MPC in a closed loop.

mod common;

use common::{data, small_cfg};

use koopman::data::{generate, Pairing};
use koopman::model::nndm::{NndmArch, NndmModel};
use koopman::model::{load_lifted, load_one_step};
use koopman::mpc::metrics::GoalSpec;
use koopman::mpc::{run_closed_loop, RandomShooting, ShootingPolicy, Task, TaskKind};
use koopman::train::nndm::{prediction_error, train_nndm};
use koopman::train::{Precision, TrainConfig};
use koopman::Error;
use std::ops::ControlFlow;

fn quiet(_: &koopman::train::Progress) -> ControlFlow<()> {
    ControlFlow::Continue(())
}

#[test]
fn a_short_run_decreases_the_prediction_error_and_reports_it() {
    let (tr, va, te) = (data(300, 1), data(100, 2), data(100, 3));
    let cfg = small_cfg(300);
    let arch = NndmArch::matching_koopman(2, 1, &cfg.hidden, cfg.n_mult).unwrap();
    let untrained = NndmModel::init(arch.clone(), cfg.seed).unwrap();
    let before = prediction_error(&untrained, &te, 0.8).unwrap();
    let mut vals = Vec::new();
    let mut seen = 0;
    let out = train_nndm(&cfg, &tr, &va, Some(&te), &mut |p| {
        seen += 1;
        assert_eq!(p.loss.ctrl, 0.0);
        if let Some(v) = p.validation {
            vals.push(v);
        }
        ControlFlow::Continue(())
    })
    .unwrap();
    assert_eq!(seen, 300);
    assert_eq!(vals.len(), 6);
    assert!(
        vals.last().unwrap() < &(0.5 * vals[0]),
        "validation {vals:?}"
    );
    let after = out.metrics.base.test_prediction_error.unwrap();
    assert!(after < 0.3 * before, "test error {before} → {after}");
    // The reported figures are those of the returned (best) model.
    assert_eq!(after, prediction_error(&out.model, &te, 0.8).unwrap());
    let min = vals.iter().cloned().fold(f64::INFINITY, f64::min);
    assert_eq!(out.metrics.base.best_validation_prediction_error, min);
    // The parameter budget is the Koopman model's of the same config.
    let koopman = koopman::model::arch::Arch::new(2, 1, &cfg.hidden, cfg.n_mult).unwrap();
    assert_eq!(out.metrics.koopman_num_params, koopman.num_params());
    assert_eq!(out.metrics.base.num_params, arch.num_params());
    assert_eq!(out.model.arch(), &arch);
    assert!(!out.metrics.base.config.ctrl && !out.metrics.base.config.cov);
}

#[test]
fn runs_are_deterministic_in_f32_and_f64() {
    let (tr, va) = (data(100, 4), data(40, 5));
    for precision in [Precision::F32, Precision::F64] {
        let cfg = TrainConfig {
            precision,
            ..small_cfg(40)
        };
        let a = train_nndm(&cfg, &tr, &va, None, &mut quiet).unwrap();
        let b = train_nndm(&cfg, &tr, &va, None, &mut quiet).unwrap();
        assert_eq!(a.model.params(), b.model.params(), "{precision:?}");
        let c = train_nndm(
            &TrainConfig {
                seed: 5,
                ..cfg.clone()
            },
            &tr,
            &va,
            None,
            &mut quiet,
        )
        .unwrap();
        assert_ne!(a.model.params(), c.model.params());
    }
}

#[test]
fn save_load_round_trip_keeps_predictions_and_step_matches_the_batched_rollout() {
    let (tr, va) = (data(100, 6), data(40, 7));
    let out = train_nndm(&small_cfg(30), &tr, &va, None, &mut quiet).unwrap();
    let dir = std::env::temp_dir().join(format!("koopbridge-nndm-{}", std::process::id()));
    out.model.save(&dir).unwrap();
    let back = NndmModel::load(&dir).unwrap();
    assert_eq!(back.params(), out.model.params());
    assert_eq!(back.metadata, out.model.metadata);
    let (x, u) = ([0.3, -1.2], [2.5]);
    assert_eq!(back.step(&x, &u).unwrap(), out.model.step(&x, &u).unwrap());
    assert_eq!(
        prediction_error(&back, &va, 0.8).unwrap(),
        prediction_error(&out.model, &va, 0.8).unwrap()
    );
    let one = load_one_step(&dir).unwrap();
    let mut next = [0.0; 2];
    one.predict(&x, &u, &mut next);
    assert_eq!(next.to_vec(), out.model.step(&x, &u).unwrap());
    // The batched one-step prediction (random shooting's path) equals single steps.
    let xs = [0.3, -1.2, 2.0, 0.5, -3.0, 7.0];
    let us = [2.5, -8.0, 0.1];
    let mut rows = [0.0; 6];
    one.predict_rows(&xs, &us, &mut rows);
    for i in 0..3 {
        let single = back.step(&xs[2 * i..2 * i + 2], &us[i..i + 1]).unwrap();
        for j in 0..2 {
            assert!((rows[2 * i + j] - single[j]).abs() <= 1e-12 * (1.0 + single[j].abs()));
        }
    }
    // load_lifted stays for lifted models.
    assert!(matches!(load_lifted(&dir), Err(Error::UnknownName { .. })));
    // The batched rollout (training/eval path) agrees with repeated single steps.
    let mut manual = 0.0;
    let (gamma, steps) = (0.8f64, va.steps);
    let wsum: f64 = (0..steps).map(|k| gamma.powi(k as i32)).sum();
    for i in 0..va.n {
        let mut xh = va.state(i, 0).to_vec();
        for t in 0..steps {
            xh = back.step(&xh, va.input(i, t)).unwrap();
            let e: f64 = (0..2)
                .map(|j| (xh[j] - va.state(i, t + 1)[j]).powi(2))
                .sum();
            manual += gamma.powi(t as i32) * e / (va.n * 2) as f64;
        }
    }
    let batched = prediction_error(&back, &va, gamma).unwrap();
    assert!(
        (manual / wsum - batched).abs() <= 1e-12 * batched,
        "{manual} vs {batched}"
    );
    // A corrupt config is a typed error.
    std::fs::write(dir.join("config.json"), b"{\"kind\": \"nndm\", \"nx\": 2}").unwrap();
    assert!(matches!(NndmModel::load(&dir), Err(Error::Format { .. })));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_input_gives_typed_errors() {
    let (tr, va) = (data(50, 8), data(20, 9));
    let cfg = small_cfg(5);
    let too_many = TrainConfig {
        train_samples: Some(51),
        ..cfg.clone()
    };
    assert!(matches!(
        train_nndm(&too_many, &tr, &va, None, &mut quiet),
        Err(Error::InvalidArgument(_))
    ));
    let mut nan = tr.clone();
    nan.x[7] = f64::NAN;
    assert!(matches!(
        train_nndm(&cfg, &nan, &va, None, &mut quiet),
        Err(Error::NonFinite(_))
    ));
    let other = generate(
        koopman::systems::by_name("double-pendulum")
            .unwrap()
            .as_ref(),
        20,
        15,
        1,
        Pairing::Aligned,
    )
    .unwrap();
    assert!(matches!(
        train_nndm(&cfg, &tr, &other, None, &mut quiet),
        Err(Error::Dimension { .. })
    ));
    let no_hidden = TrainConfig {
        hidden: vec![],
        ..cfg.clone()
    };
    assert!(train_nndm(&no_hidden, &tr, &va, None, &mut quiet).is_err());
    let model = NndmModel::init(NndmArch::new(2, 1, &[8]).unwrap(), 1).unwrap();
    assert!(matches!(
        model.step(&[0.0], &[0.0]),
        Err(Error::Dimension { .. })
    ));
    assert!(matches!(
        model.step(&[0.0, 0.0], &[]),
        Err(Error::Dimension { .. })
    ));
    assert!(matches!(
        model.step(&[f64::NAN, 0.0], &[0.0]),
        Err(Error::NonFinite(_))
    ));
    assert!(matches!(
        prediction_error(&model, &other, 0.8),
        Err(Error::Dimension { .. })
    ));
    assert!(matches!(
        NndmModel::from_params(NndmArch::new(2, 1, &[8]).unwrap(), vec![0.0; 3]),
        Err(Error::Dimension { .. })
    ));
    let cancelled = train_nndm(&cfg, &tr, &va, None, &mut |_| ControlFlow::Break(()));
    assert!(matches!(cancelled, Err(Error::Cancelled)));
}

#[test]
fn a_trained_nndm_drives_random_shooting_in_closed_loop() {
    let (tr, va) = (data(2000, 10), data(200, 11));
    // One thread: the same batch parts (so the same model) on every machine.
    let cfg = TrainConfig {
        iterations: 400,
        validate_every: 100,
        threads: 1,
        ..small_cfg(400)
    };
    let out = train_nndm(&cfg, &tr, &va, None, &mut quiet).unwrap();
    let sys = koopman::systems::by_name("damped-pendulum").unwrap();
    let (lo, hi) = sys.input_bounds();
    let planner = RandomShooting::new(200, 10, vec![1.0, 1.0], lo.clone(), hi.clone(), 3).unwrap();
    let mut policy = ShootingPolicy::new(planner, &out.model, "nndm");
    let mut task = Task::standard(sys.as_ref(), TaskKind::Regulate).unwrap();
    task.steps = 60;
    let (m, traj) = run_closed_loop(
        sys.as_ref(),
        &mut policy,
        &task,
        &lo,
        &hi,
        &GoalSpec::default(),
        |_, _| {},
    )
    .unwrap();
    assert_eq!(m.controller, "random-shooting/nndm");
    assert!(!m.diverged);
    assert_eq!(m.steps, 60);
    assert_eq!(traj.x.len(), 61);
    assert!(traj.x.iter().flatten().all(|v| v.is_finite()));
    for u in &traj.u {
        assert!(u[0] >= lo[0] && u[0] <= hi[0], "input {u:?} out of bounds");
    }
    assert_eq!(m.input_violations, 0);
    // The controller acted: the pendulum left its initial state.
    let moved: f64 = traj.x[1]
        .iter()
        .zip(&traj.x[0])
        .map(|(a, b)| (a - b).abs())
        .sum();
    assert!(moved > 0.0);
    // It brought the pendulum at least halfway to the target (|x_0 − r| ≈ 2.5).
    assert!(m.final_error < 1.25, "final error {}", m.final_error);
}
