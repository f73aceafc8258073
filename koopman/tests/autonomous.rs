//! Autonomous systems (nu = 0, SPEC's polynomial map): a Koopman model trains without the
//! inverse-control loss (off by default there, refused when asked for), its open-loop rollout
//! follows the closed-form map, and an MPC on it is refused with the reason.

mod common;

use common::small_cfg;

use koopman::data::{generate, Dataset, Pairing};
use koopman::model::LiftedModel;
use koopman::mpc::{LoadedModel, MpcConfig};
use koopman::systems::polynomial::PolynomialSystem;
use koopman::systems::System;
use koopman::train::{train, TrainConfig};
use std::ops::ControlFlow;

const STEPS: usize = 5;

fn poly_data(windows: usize, seed: u64) -> Dataset {
    generate(
        &PolynomialSystem::new(5).unwrap(),
        windows,
        STEPS,
        seed,
        Pairing::Aligned,
    )
    .unwrap()
}

/// Mean squared error of `predict(x0, t)` against the closed-form map over `d`'s windows.
fn rollout_mse(d: &Dataset, predict: &dyn Fn(&[f64], usize) -> Vec<f64>) -> f64 {
    let sys = PolynomialSystem::new(5).unwrap();
    let mut sum = 0.0;
    for w in 0..d.n {
        let x0 = d.state(w, 0).to_vec();
        let mut x = x0.clone();
        for t in 1..=STEPS {
            let mut next = vec![0.0; 3];
            sys.step(&x, &[], &mut next);
            x = next;
            let p = predict(&x0, t);
            sum += x.iter().zip(&p).map(|(a, b)| (a - b).powi(2)).sum::<f64>();
        }
    }
    sum / (d.n * STEPS * 3) as f64
}

/// x_t of the model: lift x0 once, apply A t times, read the state coordinates.
fn model_rollout(model: &dyn LiftedModel, x0: &[f64], t: usize) -> Vec<f64> {
    let a = model.a();
    let mut z = model.lift(x0);
    let n = z.len();
    for _ in 0..t {
        z = (0..n)
            .map(|i| (0..n).map(|j| a[(i, j)] * z[j]).sum())
            .collect();
    }
    z[..model.nx()].to_vec()
}

#[test]
fn the_inverse_control_loss_is_off_by_default_and_refused_when_asked_for() {
    let (tr, va) = (poly_data(40, 1), poly_data(20, 2));
    assert_eq!(tr.nu, 0);
    // The library refuses ctrl on data without inputs, saying why.
    let e = train(&small_cfg(10), &tr, &va, None, &mut |_| {
        ControlFlow::Continue(())
    })
    .err()
    .expect("ctrl on an autonomous system must be refused");
    let msg = e.to_string();
    assert!(
        msg.contains("needs inputs") && msg.contains("nu = 0"),
        "{msg}"
    );
    // Settling: the default turns off (and says it did), an explicit request is an error.
    let mut cfg = TrainConfig::default();
    assert!(cfg.settle_ctrl_for(0, false).unwrap());
    assert!(!cfg.ctrl && cfg.cov);
    assert!(TrainConfig::default().settle_ctrl_for(0, true).is_err());
    let mut with_inputs = TrainConfig::default();
    assert!(!with_inputs.settle_ctrl_for(1, true).unwrap());
    assert!(with_inputs.ctrl);
}

#[test]
fn a_tiny_autonomous_model_follows_the_closed_form_map_and_cannot_be_controlled() {
    let (tr, va, te) = (poly_data(400, 11), poly_data(100, 12), poly_data(100, 13));
    let mut cfg = TrainConfig {
        n_mult: 2,
        ..small_cfg(1500)
    };
    cfg.settle_ctrl_for(tr.nu, false).unwrap();
    let out = train(
        &cfg,
        &tr,
        &va,
        Some(&te),
        &mut |_| ControlFlow::Continue(()),
    )
    .unwrap();
    let model = &out.model;
    assert_eq!((model.nx(), model.nu(), model.b().ncols()), (3, 0, 0));

    let learnt = rollout_mse(&te, &|x0, t| model_rollout(model, x0, t));
    // Two independent yardsticks: holding x0, and the linear part of the map alone (the best a
    // model without the x1^p terms can do).
    let hold = rollout_mse(&te, &|x0, _| x0.to_vec());
    let linear = rollout_mse(&te, &|x0, t| {
        let t = t as i32;
        vec![
            0.85f64.powi(t) * x0[0],
            0.9f64.powi(t) * x0[1],
            0.9f64.powi(t) * x0[2],
        ]
    });
    eprintln!("rollout MSE: learnt {learnt:.3e}, hold x0 {hold:.3e}, linear part {linear:.3e}");
    assert!(
        learnt.is_finite() && learnt < 0.05 * hold,
        "{learnt} vs {hold}"
    );
    assert!(learnt < 0.5 * linear, "{learnt} vs {linear}");

    // Saved and loaded as the MPC service would: controlling it is refused with the reason.
    let dir = std::env::temp_dir().join(format!("kb-autonomous-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    model.save(&dir).unwrap();
    let loaded = LoadedModel::load(&dir).unwrap();
    assert_eq!(loaded.nu(), 0);
    let e = loaded
        .controller(&MpcConfig::default(), None)
        .err()
        .expect("an MPC on an autonomous model must be refused");
    assert!(e.to_string().contains("no inputs to control"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}
