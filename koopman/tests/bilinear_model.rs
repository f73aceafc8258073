//! The bilinear Koopman model's files (`kind: bilinear`): round trip, typed errors for a bad `N`
//! tensor, one-step prediction, and a short training run whose saved model evaluates to the
//! reported figure.

mod common;

use koopman::fsutil::write_atomic;
use koopman::model::arch::Arch;
use koopman::model::bilinear::BilinearModel;
use koopman::model::koopman::KoopmanModel;
use koopman::model::store::{to_safetensors, Tensor};
use koopman::mpc::OneStepModel;
use koopman::rng::Rng;
use koopman::train::{bilinear_prediction_error, train_bilinear, TrainConfig};
use koopman::Error;
use std::path::{Path, PathBuf};

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("kb-bilinear-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn random_model(nu: usize, seed: u64) -> BilinearModel {
    let arch = Arch::new(2, nu, &[8, 8], 2).unwrap();
    let lin = KoopmanModel::init(arch.clone(), seed).unwrap();
    let mut rng = Rng::new(seed + 1);
    let nn = arch.latent_dim();
    let n = (0..nu * nn * nn).map(|_| 0.1 * rng.normal()).collect();
    let mut m = BilinearModel::from_parts(lin, n).unwrap();
    m.metadata = serde_json::json!({"note": "test"});
    m
}

/// Rewrites `dir/model.safetensors`, letting `edit` change or drop each tensor.
fn rewrite(
    dir: &Path,
    edit: impl Fn(&str, Vec<usize>, Vec<f64>) -> Option<(Vec<usize>, Vec<f64>)>,
) {
    let path = dir.join("model.safetensors");
    let bytes = std::fs::read(&path).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let mut out = Vec::new();
    for (name, view) in st.tensors() {
        let data: Vec<f64> = view
            .data()
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect();
        if let Some((shape, data)) = edit(&name, view.shape().to_vec(), data) {
            out.push(Tensor { name, shape, data });
        }
    }
    write_atomic(&path, &to_safetensors(&out).unwrap()).unwrap();
}

#[test]
fn save_load_round_trip_is_exact_for_one_and_two_inputs() {
    for nu in [1, 2] {
        let m = random_model(nu, 40 + nu as u64);
        let dir = tmp(&format!("rt{nu}"));
        m.save(&dir).unwrap();
        let back = BilinearModel::load(&dir).unwrap();
        assert_eq!(back, m);
        // The kind keeps the two loaders apart.
        assert!(matches!(
            KoopmanModel::load(&dir),
            Err(Error::Format { .. })
        ));
        let lin_dir = tmp(&format!("lin{nu}"));
        m.linear().save(&lin_dir).unwrap();
        assert!(matches!(
            BilinearModel::load(&lin_dir),
            Err(Error::Format { .. })
        ));
        let _ = std::fs::remove_dir_all(&dir);
        let _ = std::fs::remove_dir_all(&lin_dir);
    }
}

#[test]
fn mismatched_n_shapes_are_format_errors() {
    let m = random_model(2, 7);
    let nn = m.latent_dim();
    let cases: Vec<(&str, Vec<usize>)> = vec![
        ("one-input", vec![1, nn, nn]),
        ("not-square", vec![2, nn, nn - 1]),
        ("flat", vec![2 * nn * nn]),
    ];
    for (label, shape) in cases {
        let dir = tmp(&format!("shape-{label}"));
        m.save(&dir).unwrap();
        rewrite(&dir, |name, s, d| {
            if name == "N" {
                let len: usize = shape.iter().product();
                let mut d = d;
                d.resize(len, 0.5);
                Some((shape.clone(), d))
            } else {
                Some((s, d))
            }
        });
        match BilinearModel::load(&dir) {
            Err(Error::Format { message, .. }) => {
                assert!(message.contains("'N'"), "{label}: {message}")
            }
            other => panic!("{label}: expected a format error, got {other:?}"),
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
    let dir = tmp("missing");
    m.save(&dir).unwrap();
    rewrite(&dir, |name, s, d| (name != "N").then_some((s, d)));
    assert!(matches!(
        BilinearModel::load(&dir),
        Err(Error::Format { .. })
    ));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn nan_in_n_is_a_non_finite_error() {
    let m = random_model(1, 9);
    let dir = tmp("nan");
    m.save(&dir).unwrap();
    rewrite(&dir, |name, s, mut d| {
        if name == "N" {
            d[3] = f64::NAN;
        }
        Some((s, d))
    });
    assert!(matches!(
        BilinearModel::load(&dir),
        Err(Error::NonFinite(_))
    ));
    let _ = std::fs::remove_dir_all(&dir);
    // The constructor refuses it too, and a wrong number of values.
    let nn = m.latent_dim();
    let mut n = m.n_flat().to_vec();
    n[0] = f64::INFINITY;
    assert!(matches!(
        BilinearModel::from_parts(m.linear().clone(), n),
        Err(Error::NonFinite(_))
    ));
    assert!(matches!(
        BilinearModel::from_parts(m.linear().clone(), vec![0.0; nn * nn + 1]),
        Err(Error::Dimension { .. })
    ));
}

#[test]
fn one_step_prediction_uses_the_state_dependent_input_gain() {
    let m = random_model(2, 11);
    let x = [0.4, -0.9];
    let u = [1.5, -0.7];
    let z = m.lift(&x);
    let nn = z.len();
    let (a, b) = (m.linear().a_ref(), m.linear().b_ref());
    // Independent: (A + Σ u_i N_i) z + B u written out.
    let mut want = vec![0.0; nn];
    for r in 0..nn {
        for c in 0..nn {
            let mut arc = a[(r, c)];
            for (i, &ui) in u.iter().enumerate() {
                arc += ui * m.n_mat(i)[(r, c)];
            }
            want[r] += arc * z[c];
        }
        for (i, &ui) in u.iter().enumerate() {
            want[r] += b[(r, i)] * ui;
        }
    }
    let mut got = vec![0.0; nn];
    m.step(&z, &u, &mut got);
    for r in 0..nn {
        assert!((got[r] - want[r]).abs() <= 1e-12 * (1.0 + want[r].abs()));
    }
    // B(z) u + A z is the same step.
    let bz = m.input_matrix(&z);
    for r in 0..nn {
        let az: f64 = (0..nn).map(|c| a[(r, c)] * z[c]).sum();
        let v = az + bz[(r, 0)] * u[0] + bz[(r, 1)] * u[1];
        assert!((v - want[r]).abs() <= 1e-12 * (1.0 + v.abs()));
    }
    let mut next = [0.0; 2];
    m.predict(&x, &u, &mut next);
    assert_eq!(next, [got[0], got[1]]);
}

#[test]
fn short_bilinear_training_learns_n_and_its_saved_model_evaluates_to_the_reported_error() {
    let train = common::data(400, 1);
    let val = common::data(100, 2);
    let test = common::data(100, 3);
    let cfg = TrainConfig {
        bilinear: true,
        ..common::small_cfg(150)
    };
    let out = train_bilinear(&cfg, &train, &val, Some(&test), &mut |_| {
        std::ops::ControlFlow::Continue(())
    })
    .unwrap();
    assert!(out.model.n_flat().iter().any(|v| *v != 0.0));
    let dir = tmp("trained");
    out.model.save(&dir).unwrap();
    let back = BilinearModel::load(&dir).unwrap();
    let err = bilinear_prediction_error(&back, &test, cfg.gamma).unwrap();
    assert_eq!(Some(err), out.metrics.test_prediction_error);
    assert_eq!(
        out.metrics.num_params,
        back.arch().num_params() + koopman::train::bilinear::bilinear_len(back.arch())
    );
    // The linear trainer refuses a bilinear configuration (and vice versa).
    assert!(koopman::train::train(&cfg, &train, &val, None, &mut |_| {
        std::ops::ControlFlow::Continue(())
    })
    .is_err());
    let _ = std::fs::remove_dir_all(&dir);
}
