//! Tests of EDMD with control against independent computations.

use super::*;
use crate::data::{generate, Dataset, Pairing};
use crate::rng::Rng;
use crate::systems::{by_name, by_name_with, System, SystemOptions};
use faer::linalg::solvers::SolveLstsq;

/// A linear test system `x⁺ = M x + N u` (nx = 2, nu = 1); with `frozen` the second state stays 0.
struct Linear {
    frozen: bool,
}

impl System for Linear {
    fn name(&self) -> &str {
        "linear"
    }
    fn nx(&self) -> usize {
        2
    }
    fn nu(&self) -> usize {
        1
    }
    fn dt(&self) -> f64 {
        1.0
    }
    fn state_names(&self) -> Vec<String> {
        vec!["a".into(), "b".into()]
    }
    fn input_names(&self) -> Vec<String> {
        vec!["u".into()]
    }
    fn input_bounds(&self) -> (Vec<f64>, Vec<f64>) {
        (vec![-1.0], vec![1.0])
    }
    fn angle_indices(&self) -> Vec<usize> {
        vec![]
    }
    fn window_steps(&self) -> usize {
        4
    }
    fn sample_initial_state(&self, rng: &mut Rng) -> Vec<f64> {
        let b = if self.frozen {
            0.0
        } else {
            rng.uniform(-2.0, 2.0)
        };
        vec![rng.uniform(-1.0, 1.0), b]
    }
    fn step(&self, x: &[f64], u: &[f64], y: &mut [f64]) {
        if self.frozen {
            y[0] = 0.8 * x[0] + 0.5 * u[0];
            y[1] = 0.0;
        } else {
            y[0] = 0.9 * x[0] + 0.2 * x[1] + 0.5 * u[0];
            y[1] = -0.1 * x[0] + 0.7 * x[1] - 0.3 * u[0];
        }
    }
}

#[test]
fn linear_system_is_recovered_exactly() {
    let data = generate(&Linear { frozen: false }, 200, 4, 1, Pairing::Aligned).unwrap();
    let cfg = EdmdConfig {
        degree: Some(1),
        ridge: 0.0,
        ..EdmdConfig::default()
    };
    let m = fit(&data, &cfg).unwrap();
    assert_eq!(m.latent_dim(), 3);
    let want_a = [[0.9, 0.2, 0.0], [-0.1, 0.7, 0.0], [0.0, 0.0, 1.0]];
    let want_b = [0.5, -0.3, 0.0];
    for (i, row) in want_a.iter().enumerate() {
        for (j, want) in row.iter().enumerate() {
            let got = m.a[(i, j)];
            assert!((got - want).abs() < 1e-10, "A[{i},{j}] = {got}");
        }
        assert!((m.b[(i, 0)] - want_b[i]).abs() < 1e-10);
    }
    assert_eq!(m.info.solver, Solver::Cholesky);
    assert!(m.prediction_error(&data, 0.8).unwrap() < 1e-20);
}

#[test]
fn normal_equations_match_a_dense_qr_least_squares() {
    let sys = by_name("damped").unwrap();
    let data = generate(sys.as_ref(), 150, 3, 9, Pairing::Aligned).unwrap();
    let ridge = 1e-6;
    let cfg = EdmdConfig {
        degree: Some(5),
        ridge,
        chunk: 37,
        ..EdmdConfig::default()
    };
    let m = fit(&data, &cfg).unwrap();
    let (n, nu) = (m.latent_dim(), 1);
    let p = data.transitions();
    // Stacked problem [W; √(λP) I] K = [Y; 0], solved by Householder QR.
    let rows = p + n + nu;
    let mut w = Mat::<f64>::zeros(rows, n + nu);
    let mut y = Mat::<f64>::zeros(rows, n);
    for q in 0..p {
        let (i, t) = (q / data.steps, q % data.steps);
        let z = m.dict.lift(data.state(i, t));
        let zp = m.dict.lift(data.state(i, t + 1));
        for j in 0..n {
            w[(q, j)] = z[j];
            y[(q, j)] = zp[j];
        }
        w[(q, n)] = data.input(i, t)[0];
    }
    let s = (ridge * p as f64).sqrt();
    for j in 0..n + nu {
        w[(p + j, j)] = s;
    }
    let k = w.qr().solve_lstsq(&y);
    let mut max_diff: f64 = 0.0;
    let mut max_abs: f64 = 0.0;
    for i in 0..n {
        for j in 0..n {
            max_diff = max_diff.max((m.a[(i, j)] - k[(j, i)]).abs());
            max_abs = max_abs.max(k[(j, i)].abs());
        }
        max_diff = max_diff.max((m.b[(i, 0)] - k[(n, i)]).abs());
    }
    assert!(
        max_diff < 1e-7 * max_abs.max(1.0),
        "max diff {max_diff} (max |K| {max_abs})"
    );
    // The training residual from the normal equations equals the explicit one.
    let mut explicit = 0.0;
    for q in 0..p {
        for r in 0..n {
            let pred: f64 =
                (0..n).map(|c| m.a[(r, c)] * w[(q, c)]).sum::<f64>() + m.b[(r, 0)] * w[(q, n)];
            explicit += (y[(q, r)] - pred).powi(2);
        }
    }
    let explicit = explicit / (p * n) as f64;
    assert!(
        (m.info.train_residual - explicit).abs() < 1e-6 * explicit + 1e-14,
        "{} vs {explicit}",
        m.info.train_residual
    );
    assert!(explicit > 1e-10, "the residual check must not be trivial");
    // A different chunk size gives the same normal equations up to rounding.
    let m2 = fit(&data, &EdmdConfig { chunk: 4096, ..cfg }).unwrap();
    let d2 = (0..n)
        .flat_map(|i| (0..n).map(move |j| (i, j)))
        .map(|(i, j)| (m.a[(i, j)] - m2.a[(i, j)]).abs())
        .fold(0.0, f64::max);
    assert!(d2 < 1e-8 * max_abs.max(1.0), "chunking changed A by {d2}");
}

#[test]
fn polynomial_system_one_step_state_prediction_is_exact() {
    // x⁺ is a polynomial of degree n_poly − 2 = 3 in x, inside the degree-6 dictionary.
    let sys = by_name_with("polynomial", &SystemOptions { n_poly: 5 }).unwrap();
    let train = generate(sys.as_ref(), 2000, 1, 3, Pairing::Aligned).unwrap();
    let test = generate(sys.as_ref(), 200, 1, 4, Pairing::Aligned).unwrap();
    let m = fit(
        &train,
        &EdmdConfig {
            degree: Some(6),
            ridge: 0.0,
            ..EdmdConfig::default()
        },
    )
    .unwrap();
    let err = m.prediction_error(&test, 0.8).unwrap();
    assert!(err < 1e-20, "one-step error {err}");
    // With a dictionary that cannot represent x1³ the error is clearly non-zero.
    let low = fit(
        &train,
        &EdmdConfig {
            degree: Some(2),
            ridge: 0.0,
            ..EdmdConfig::default()
        },
    )
    .unwrap();
    assert!(low.prediction_error(&test, 0.8).unwrap() > 1e-6);
}

#[test]
fn chebyshev_and_monomial_bases_predict_the_same() {
    let sys = by_name("damped").unwrap();
    let data = generate(sys.as_ref(), 300, 15, 2, Pairing::Aligned).unwrap();
    let test = generate(sys.as_ref(), 50, 15, 3, Pairing::Aligned).unwrap();
    let cfg = EdmdConfig {
        degree: Some(4),
        ridge: 0.0,
        ..EdmdConfig::default()
    };
    let c = fit(&data, &cfg).unwrap();
    let m = fit(
        &data,
        &EdmdConfig {
            basis: Basis::Monomial,
            ..cfg
        },
    )
    .unwrap();
    let (ec, em) = (
        c.prediction_error(&test, 0.8).unwrap(),
        m.prediction_error(&test, 0.8).unwrap(),
    );
    assert!((ec - em).abs() < 1e-8 * ec, "{ec} vs {em}");
}

#[test]
fn closed_form_prediction_error_equals_an_explicit_rollout() {
    let sys = by_name("damped").unwrap();
    let data = generate(sys.as_ref(), 400, 15, 5, Pairing::Aligned).unwrap();
    let m = fit(
        &data,
        &EdmdConfig {
            degree: Some(8),
            ..EdmdConfig::default()
        },
    )
    .unwrap();
    let test = generate(sys.as_ref(), 40, 15, 6, Pairing::Aligned).unwrap();
    let gamma: f64 = 0.8;
    let mut total = 0.0;
    for w in 0..test.n {
        let mut z = m.lift(test.state(w, 0));
        for i in 0..15 {
            let u = test.input(w, i);
            z = (0..z.len())
                .map(|r| (0..z.len()).map(|c| m.a[(r, c)] * z[c]).sum::<f64>() + m.b[(r, 0)] * u[0])
                .collect();
            let x = test.state(w, i + 1);
            total += gamma.powi(i as i32) * ((z[0] - x[0]).powi(2) + (z[1] - x[1]).powi(2));
        }
    }
    let wsum: f64 = (0..15).map(|i| gamma.powi(i)).sum();
    let explicit = total / (wsum * 2.0 * test.n as f64);
    let fast = m.prediction_error(&test, gamma).unwrap();
    assert!(
        (fast - explicit).abs() < 1e-9 * explicit,
        "{fast} vs {explicit}"
    );
    assert!(explicit > 0.0 && explicit < 10.0);
}

#[test]
fn singular_gram_falls_back_to_svd() {
    // The second state is always 0: every feature with a power of it is constant or duplicated.
    let data = generate(&Linear { frozen: true }, 100, 4, 1, Pairing::Aligned).unwrap();
    let m = fit(
        &data,
        &EdmdConfig {
            degree: Some(3),
            ridge: 0.0,
            ..EdmdConfig::default()
        },
    )
    .unwrap();
    assert_eq!(m.info.solver, Solver::Svd);
    assert!(m.prediction_error(&data, 0.8).unwrap() < 1e-18);
}

#[test]
fn save_load_round_trip_and_errors() {
    let sys = by_name("double").unwrap();
    let data = generate(sys.as_ref(), 100, 15, 1, Pairing::Aligned).unwrap();
    let m = fit(
        &data,
        &EdmdConfig {
            degree: Some(3),
            ..EdmdConfig::default()
        },
    )
    .unwrap();
    let dir = std::env::temp_dir().join(format!("koopman-edmd-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    m.save(&dir).unwrap();
    let cfg: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("config.json")).unwrap()).unwrap();
    assert_eq!(cfg["kind"], "edmd");
    let back = EdmdModel::load(&dir).unwrap();
    assert_eq!(back.a, m.a);
    assert_eq!(back.b, m.b);
    assert_eq!(
        back.lift(&[0.1, 0.2, 0.3, 0.4]),
        m.lift(&[0.1, 0.2, 0.3, 0.4])
    );
    // The generic loader dispatches on "kind".
    let any = crate::model::load_lifted(&dir).unwrap();
    assert_eq!(
        (any.nx(), any.nu(), any.latent_dim()),
        (4, 2, m.latent_dim())
    );
    assert_eq!(any.a(), m.a);
    // Corrupted weights and a wrong kind are format errors.
    let w = std::fs::read(dir.join("model.safetensors")).unwrap();
    std::fs::write(dir.join("model.safetensors"), &w[..w.len() / 2]).unwrap();
    assert!(matches!(EdmdModel::load(&dir), Err(Error::Format { .. })));
    let text = std::fs::read_to_string(dir.join("config.json")).unwrap();
    std::fs::write(
        dir.join("config.json"),
        text.replace("\"edmd\"", "\"koopman\""),
    )
    .unwrap();
    assert!(matches!(EdmdModel::load(&dir), Err(Error::Format { .. })));
    std::fs::remove_dir_all(&dir).unwrap();
    assert!(matches!(EdmdModel::load(&dir), Err(Error::Io { .. })));
}

#[test]
fn bad_inputs_are_errors() {
    let sys = by_name("damped").unwrap();
    let data = generate(sys.as_ref(), 10, 15, 1, Pairing::Aligned).unwrap();
    assert!(fit(
        &data,
        &EdmdConfig {
            ridge: -1.0,
            ..EdmdConfig::default()
        }
    )
    .is_err());
    assert!(fit(
        &data,
        &EdmdConfig {
            degree: Some(0),
            ..EdmdConfig::default()
        }
    )
    .is_err());
    assert!(fit(
        &data,
        &EdmdConfig {
            degree: Some(500),
            ..EdmdConfig::default()
        }
    )
    .is_err());
    let mut nan: Dataset = data.clone();
    nan.x[3] = f64::NAN;
    assert!(matches!(
        fit(&nan, &EdmdConfig::default()),
        Err(Error::NonFinite(_))
    ));
    let m = fit(
        &data,
        &EdmdConfig {
            degree: Some(3),
            ..EdmdConfig::default()
        },
    )
    .unwrap();
    let other = generate(
        by_name("double").unwrap().as_ref(),
        5,
        15,
        1,
        Pairing::Aligned,
    )
    .unwrap();
    assert!(matches!(
        m.prediction_error(&other, 0.8),
        Err(Error::Dimension { .. })
    ));
}

#[test]
fn degree_selection_keeps_the_lowest_degree_near_the_lowest_validation_error() {
    // The damped pendulum with few windows: the budget's degree (20) overfits, so the choice is
    // not simply the largest; every trial must equal a separate fit's validation error.
    let sys = by_name("damped").unwrap();
    let train = generate(sys.as_ref(), 40, 15, 11, Pairing::Aligned).unwrap();
    let val = generate(sys.as_ref(), 40, 15, 12, Pairing::Aligned).unwrap();
    let cfg = EdmdConfig {
        max_features: 45, // degrees 1..8 on a 2-D state
        ..EdmdConfig::default()
    };
    let (model, sel) = fit_by_validation(&train, &val, &cfg, 0.8).unwrap();
    assert!(sel.by_validation);
    assert_eq!(sel.trials.len(), 8);
    let mut best = f64::INFINITY;
    for t in &sel.trials {
        let alone = fit(
            &train,
            &EdmdConfig {
                degree: Some(t.degree),
                ..cfg.clone()
            },
        )
        .unwrap();
        let e = alone.prediction_error(&val, 0.8).unwrap();
        assert_eq!(t.features, alone.latent_dim());
        if e.is_finite() {
            assert!((t.validation_error.unwrap() - e).abs() <= 1e-12 * e.max(1.0));
            best = best.min(e);
        } else {
            assert_eq!(t.validation_error, None);
        }
    }
    // The lowest degree within the tolerance of the best error.
    let want = sel
        .trials
        .iter()
        .find(|t| {
            t.validation_error
                .is_some_and(|e| e <= best * (1.0 + select::TOLERANCE))
        })
        .unwrap()
        .degree;
    assert_eq!(sel.chosen, want);
    assert_eq!(model.config.degree, Some(want));
    assert_eq!(model.latent_dim(), dictionary::feature_count(2, want));
    // A linear system: degree 1 is exact, so nothing above it validates better.
    let lin_train = generate(&Linear { frozen: false }, 100, 4, 1, Pairing::Aligned).unwrap();
    let lin_val = generate(&Linear { frozen: false }, 50, 4, 2, Pairing::Aligned).unwrap();
    let (_, lin) = fit_by_validation(&lin_train, &lin_val, &cfg, 0.8).unwrap();
    assert_eq!(lin.chosen, 1, "{lin:?}");
}

#[test]
fn a_given_degree_is_the_only_trial() {
    let sys = by_name("damped").unwrap();
    let train = generate(sys.as_ref(), 30, 15, 1, Pairing::Aligned).unwrap();
    let val = generate(sys.as_ref(), 10, 15, 2, Pairing::Aligned).unwrap();
    let cfg = EdmdConfig {
        degree: Some(3),
        ..EdmdConfig::default()
    };
    let (model, sel) = fit_by_validation(&train, &val, &cfg, 0.8).unwrap();
    assert!(!sel.by_validation);
    assert_eq!((sel.chosen, sel.trials.len()), (3, 1));
    assert_eq!(model.latent_dim(), dictionary::feature_count(2, 3));
}

/// A nonlinear system's EDMD model: its per-state errors, against a rollout written out
/// here and against the closed form of `prediction_error` at γ = 1 (their mean square).
#[test]
fn state_errors_match_an_explicit_rollout_and_the_closed_form() {
    let sys = by_name("damped").unwrap();
    let data = generate(sys.as_ref(), 300, 15, 5, Pairing::Aligned).unwrap();
    let cfg = EdmdConfig {
        degree: Some(4),
        ..EdmdConfig::default()
    };
    let m = fit(&data, &cfg).unwrap();
    let test = generate(sys.as_ref(), 30, 15, 6, Pairing::Aligned).unwrap();
    let rms = crate::analysis::state_rms_errors(&m, &test).unwrap();
    let mut sq = [0.0; 2];
    for w in 0..test.n {
        let mut z = m.lift(test.state(w, 0));
        for i in 0..test.steps {
            let u = test.input(w, i)[0];
            z = (0..z.len())
                .map(|r| (0..z.len()).map(|c| m.a[(r, c)] * z[c]).sum::<f64>() + m.b[(r, 0)] * u)
                .collect();
            for (s, acc) in sq.iter_mut().enumerate() {
                *acc += (z[s] - test.state(w, i + 1)[s]).powi(2);
            }
        }
    }
    for s in 0..2 {
        let explicit = (sq[s] / (test.n * test.steps) as f64).sqrt();
        assert!(
            (rms[s] - explicit).abs() < 1e-10 * explicit,
            "state {s}: {} vs {explicit}",
            rms[s]
        );
        assert!(explicit > 1e-6, "the test needs a model with an error");
    }
    let mean_sq = (rms[0] * rms[0] + rms[1] * rms[1]) / 2.0;
    let closed = crate::analysis::prediction_error(&m, &test, 1.0).unwrap();
    assert!(
        (mean_sq - closed).abs() < 1e-9 * closed,
        "{mean_sq} vs {closed}"
    );
}

#[test]
fn state_errors_refuse_data_of_another_system() {
    let sys = by_name("damped").unwrap();
    let data = generate(sys.as_ref(), 50, 5, 1, Pairing::Aligned).unwrap();
    let m = fit(&data, &EdmdConfig::default()).unwrap();
    let other = generate(
        by_name("double").unwrap().as_ref(),
        5,
        5,
        1,
        Pairing::Aligned,
    )
    .unwrap();
    assert!(matches!(
        crate::analysis::state_rms_errors(&m, &other),
        Err(crate::Error::Dimension { .. })
    ));
}
