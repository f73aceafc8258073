//! Training on z-scored data (SPEC.md, legged robots): an affine change of the data's units
//! changes nothing the model learns, and the saved model predicts in raw units exactly what it
//! learnt in normalised ones.

mod common;

use common::{data, small_cfg};

use koopman::data::Dataset;
use koopman::model::koopman::KoopmanModel;
use koopman::model::{load_lifted, LiftedModel};
use koopman::train::{train, Precision, TrainConfig};
use std::ops::ControlFlow;

const SX: [f64; 2] = [100.0, 0.01];
const OX: [f64; 2] = [5.0, -3.0];
const SU: f64 = 7.0;
const OU: f64 = 2.0;

/// `d` in other units: x ↦ SX·x + OX, u ↦ SU·u + OU.
fn rescaled(d: &Dataset) -> Dataset {
    let mut out = d.clone();
    for x in out.x.chunks_exact_mut(2) {
        for i in 0..2 {
            x[i] = SX[i] * x[i] + OX[i];
        }
    }
    out.u.iter_mut().for_each(|u| *u = SU * *u + OU);
    out
}

/// The first window's open-loop prediction of `model` (raw units): lift x_0 once, roll the
/// latent state with the window's inputs, read x = P z.
fn rollout(model: &dyn LiftedModel, d: &Dataset) -> Vec<Vec<f64>> {
    let (a, b) = (model.a(), model.b());
    let mut z = model.lift(d.state(0, 0));
    let n = z.len();
    let mut out = Vec::new();
    for t in 0..d.steps {
        let u = d.input(0, t);
        z = (0..n)
            .map(|i| {
                (0..n).map(|j| a[(i, j)] * z[j]).sum::<f64>()
                    + (0..u.len()).map(|k| b[(i, k)] * u[k]).sum::<f64>()
            })
            .collect();
        out.push(z[..model.nx()].to_vec());
    }
    out
}

fn temp_dir(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("kb-normalised-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

#[test]
fn a_model_trained_on_rescaled_data_learns_the_same_and_predicts_in_the_new_units() {
    let (tr, va, te) = (data(200, 11), data(100, 12), data(50, 13));
    let cfg = TrainConfig {
        normalise: true,
        precision: Precision::F64,
        ..small_cfg(60)
    };
    let mut quiet = |_: &koopman::train::Progress| ControlFlow::Continue(());
    let a = train(&cfg, &tr, &va, Some(&te), &mut quiet).unwrap();
    let (tr2, va2, te2) = (rescaled(&tr), rescaled(&va), rescaled(&te));
    let b = train(&cfg, &tr2, &va2, Some(&te2), &mut quiet).unwrap();

    // Both saw the same z-scored data (up to rounding): the same parameters and errors.
    let diff = a
        .model
        .params()
        .iter()
        .zip(b.model.params())
        .map(|(p, q)| (p - q).abs())
        .fold(0.0, f64::max);
    assert!(diff < 1e-6, "parameters differ by {diff}");
    let (ea, eb) = (
        a.metrics.test_prediction_error.unwrap(),
        b.metrics.test_prediction_error.unwrap(),
    );
    assert!((ea - eb).abs() < 1e-6 * ea, "{ea} vs {eb}");
    let (na, nb) = (
        a.model.normalisation().unwrap(),
        b.model.normalisation().unwrap(),
    );
    for i in 0..2 {
        assert!((nb.x_mean[i] - (SX[i] * na.x_mean[i] + OX[i])).abs() < 1e-9 * SX[i].max(1.0));
        assert!((nb.x_std[i] - SX[i] * na.x_std[i]).abs() < 1e-9 * SX[i]);
    }

    // Saved and loaded: the normalisation travels, and in raw units b predicts SX·(a's) + OX.
    let (dir_a, dir_b) = (temp_dir("a"), temp_dir("b"));
    a.model.save(&dir_a).unwrap();
    b.model.save(&dir_b).unwrap();
    assert_eq!(
        KoopmanModel::load(&dir_b).unwrap().normalisation(),
        Some(nb)
    );
    let (raw_a, raw_b) = (load_lifted(&dir_a).unwrap(), load_lifted(&dir_b).unwrap());
    assert_eq!(raw_b.latent_dim(), b.model.latent_dim() + 1);
    assert_eq!(raw_b.lift(te2.state(0, 0))[..2], te2.state(0, 0)[..]);
    let (pa, pb) = (rollout(raw_a.as_ref(), &te), rollout(raw_b.as_ref(), &te2));
    for (xa, xb) in pa.iter().zip(&pb) {
        for i in 0..2 {
            let want = SX[i] * xa[i] + OX[i];
            assert!(
                (xb[i] - want).abs() < 1e-6 * (1.0 + want.abs()),
                "{xb:?} vs {want}"
            );
        }
    }
    let _ = std::fs::remove_dir_all(&dir_a);
    let _ = std::fs::remove_dir_all(&dir_b);
}

#[test]
fn normalised_training_is_refused_for_the_bilinear_model() {
    let (tr, va) = (data(50, 1), data(20, 2));
    let cfg = TrainConfig {
        normalise: true,
        bilinear: true,
        ..small_cfg(5)
    };
    let err =
        koopman::train::train_bilinear(&cfg, &tr, &va, None, &mut |_| ControlFlow::Continue(()));
    assert!(
        matches!(&err, Err(koopman::Error::InvalidArgument(m)) if m.contains("linear Koopman model only")),
        "{:?}",
        err.err()
    );
}
