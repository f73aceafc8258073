//! Tests of the error-state MPC with the offset-free `disturbance` correction
//! ([`MpcController::solve_about_plan`], [`crate::mpc::OffsetFree::update_about_plan`]) against
//! an independent computation: a plant written out as the model plus a constant state
//! disturbance, the deviation cost with that disturbance written out and its finite-difference
//! gradient, and the closed loop's deviation with and without the correction.
#![allow(clippy::needless_range_loop)] // index loops mirror the formulas being checked

use super::tests_error_state::random_vec;
use super::*;
use crate::model::matrix::MatrixModel;
use crate::model::LiftedModel;
use crate::rng::Rng;

/// One lifted step `z⁺ = A z + B u (+ E d)` written out (`d` on the first nx components).
fn step(model: &MatrixModel, z: &[f64], u: &[f64], d: &[f64]) -> Vec<f64> {
    let mut zn = vec![0.0; z.len()];
    for i in 0..z.len() {
        for j in 0..z.len() {
            zn[i] += model.a[(i, j)] * z[j];
        }
        for k in 0..u.len() {
            zn[i] += model.b[(i, k)] * u[k];
        }
    }
    for (zi, di) in zn.iter_mut().zip(d) {
        *zi += di;
    }
    zn
}

/// The plant: the model's one-step prediction of the state plus the constant `d`.
fn plant(model: &MatrixModel, x: &[f64], u: &[f64], d: &[f64]) -> Vec<f64> {
    step(model, &model.lift(x), u, d)[..x.len()].to_vec()
}

fn disturbance(nx: usize, alpha: f64) -> OffsetFreeConfig {
    OffsetFreeConfig {
        mode: OffsetMode::Disturbance,
        radius: f64::INFINITY,
        gain: vec![alpha; nx],
        angles: Vec::new(),
    }
}

/// The error-state MPC of `model` (horizon `h`, R = `r`·I) with the disturbance estimate at α = 1.
fn estimating(model: &MatrixModel, h: usize, r: f64) -> MpcController<'_> {
    let cfg = MpcConfig {
        horizon: h,
        r: Some(vec![r; model.nu()]),
        ..MpcConfig::default()
    };
    let mut c = MpcController::new(model, &cfg).unwrap();
    c.set_offset_free(Some(disturbance(model.nx(), 1.0)))
        .unwrap();
    c
}

/// A plan the model reproduces: `r_{k+1} = P f(Φ(r_k), u_ff,k)` from `r_0`.
fn model_plan(model: &MatrixModel, r0: &[f64], u_ff: &[f64]) -> Vec<Vec<f64>> {
    let nu = model.nu();
    let mut plan = vec![r0.to_vec()];
    for u in u_ff.chunks_exact(nu) {
        let next = plant(model, plan.last().unwrap(), u, &[]);
        plan.push(next);
    }
    plan
}

#[test]
fn about_a_plan_the_estimate_is_the_plants_constant_disturbance() {
    let (nx, nu, h) = (3, 2, 6);
    let model = MatrixModel::random_stable(nx, 14, nu, 0.95, 3).unwrap();
    let mut c = estimating(&model, h, 0.1);
    let mut rng = Rng::new(5);
    let (steps, d) = (12, vec![0.03, -0.02, 0.05]);
    let u_ff = random_vec(&mut rng, (steps + h) * nu, 0.5);
    let plan = model_plan(&model, &random_vec(&mut rng, nx, 0.5), &u_ff);
    // The plant starts off the plan: the estimate must not take the deviation for a disturbance.
    let mut x: Vec<f64> = plan[0].iter().map(|v| v + 0.2).collect();
    for k in 0..steps {
        let s = c
            .solve_about_plan(&x, &plan[k], &u_ff[k * nu..(k + h) * nu])
            .unwrap();
        let est = c.offset_free().unwrap().estimate().to_vec();
        if k >= 1 {
            for i in 0..nx {
                assert!(
                    (est[i] - d[i]).abs() < 1e-10,
                    "step {k}: d̂ {est:?}, d {d:?}"
                );
            }
        } else {
            assert!(est.iter().all(|v| *v == 0.0), "no decision yet: {est:?}");
        }
        x = plant(&model, &x, &s.u[..nu], &d);
    }
}

#[test]
fn the_models_own_error_along_the_plan_is_not_taken_for_a_disturbance() {
    // The plant is another system; the plan is one the *plant* follows from its first state.
    // On the plan the error-state MPC applies the feed-forward and the plant stays on it: the
    // model's error there is the same at x and at the plan's state, so it estimates nothing.
    let (nx, nu, h) = (3, 2, 6);
    let model = MatrixModel::random_stable(nx, 12, nu, 0.95, 7).unwrap();
    let truth = MatrixModel::random_stable(nx, 12, nu, 0.95, 8).unwrap();
    let mut c = estimating(&model, h, 0.1);
    let mut rng = Rng::new(9);
    let steps = 10;
    let u_ff = random_vec(&mut rng, (steps + h) * nu, 0.5);
    let plan = model_plan(&truth, &random_vec(&mut rng, nx, 0.5), &u_ff);
    let mut x = plan[0].clone();
    for k in 0..steps {
        let s = c
            .solve_about_plan(&x, &plan[k], &u_ff[k * nu..(k + h) * nu])
            .unwrap();
        let est = c.offset_free().unwrap().estimate();
        assert!(est.iter().all(|v| v.abs() < 1e-9), "step {k}: d̂ {est:?}");
        x = plant(&truth, &x, &s.u[..nu], &[]);
        let off = (0..nx)
            .map(|i| (x[i] - plan[k + 1][i]).abs())
            .fold(0.0, f64::max);
        assert!(off < 1e-7, "step {k}: {off} off the plan");
    }
}

#[test]
fn with_the_estimate_the_plan_zeroes_the_gradient_of_the_cost_with_the_disturbance() {
    let (nx, nu, h) = (2, 2, 7);
    let model = MatrixModel::random_stable(nx, 11, nu, 0.96, 6).unwrap();
    let r = vec![0.03, 0.1];
    let cfg = MpcConfig {
        horizon: h,
        r: Some(r.clone()),
        regularization: 0.0,
        ..MpcConfig::default()
    };
    let mut c = MpcController::new(&model, &cfg).unwrap();
    c.set_offset_free(Some(disturbance(nx, 1.0))).unwrap();
    let mut rng = Rng::new(21);
    let d = vec![0.04, -0.06];
    let steps = 5;
    let u_ff = random_vec(&mut rng, (steps + h) * nu, 0.6);
    let plan = model_plan(&model, &random_vec(&mut rng, nx, 0.5), &u_ff);
    let mut x = plan[0].clone();
    for k in 0..steps {
        let ff = &u_ff[k * nu..(k + h) * nu];
        let s = c.solve_about_plan(&x, &plan[k], ff).unwrap();
        assert_eq!(s.status, SolveStatus::Solved);
        let est = c.offset_free().unwrap().estimate().to_vec();
        // J(u) = Σ ‖P z_{τ+1} − P ž_{τ+1}‖² + (u − u_ff)ᵀR(u − u_ff): z from Φ(x) with the
        // estimate added at every step, ž from Φ(r_k) without it.
        let cost = |u: &[f64]| {
            let (mut z, mut zp) = (model.lift(&x), model.lift(&plan[k]));
            let mut j = 0.0;
            for t in 0..h {
                z = step(&model, &z, &u[t * nu..(t + 1) * nu], &est);
                zp = step(&model, &zp, &ff[t * nu..(t + 1) * nu], &[]);
                j += (0..nx).map(|i| (z[i] - zp[i]).powi(2)).sum::<f64>();
                j += (0..nu)
                    .map(|i| r[i] * (u[t * nu + i] - ff[t * nu + i]).powi(2))
                    .sum::<f64>();
            }
            j
        };
        let worst = (0..s.u.len())
            .map(|i| {
                let (mut up, mut um) = (s.u.clone(), s.u.clone());
                up[i] += 1e-5;
                um[i] -= 1e-5;
                ((cost(&up) - cost(&um)) / 2e-5).abs()
            })
            .fold(0.0, f64::max);
        assert!(worst < 1e-6, "step {k}: finite-difference gradient {worst}");
        x = plant(&model, &x, &s.u[..nu], &d);
    }
}

#[test]
fn the_correction_removes_the_deviation_a_constant_disturbance_leaves() {
    // A linear model (Φ = identity), one input per state: with d known the MPC can cancel it.
    let (nx, h) = (2, 10);
    let a = faer::mat![[0.9, 0.2], [-0.1, 0.95]];
    let b = faer::mat![[1.0, 0.0], [0.3, 1.0]];
    let model = MatrixModel::linear(a, b).unwrap();
    let cfg = MpcConfig {
        horizon: h,
        r: Some(vec![1e-6; nx]),
        ..MpcConfig::default()
    };
    let d = vec![0.05, -0.03];
    let mut rng = Rng::new(2);
    let steps = 60;
    let u_ff = random_vec(&mut rng, (steps + h) * nx, 0.3);
    let plan = model_plan(&model, &[0.1, -0.2], &u_ff);
    let tail_deviation = |offset: Option<OffsetFreeConfig>| {
        let mut c = MpcController::new(&model, &cfg).unwrap();
        c.set_offset_free(offset).unwrap();
        let mut x = plan[0].clone();
        let mut worst = 0.0f64;
        for k in 0..steps {
            let s = c
                .solve_about_plan(&x, &plan[k], &u_ff[k * nx..(k + h) * nx])
                .unwrap();
            x = plant(&model, &x, &s.u[..nx], &d);
            if k >= steps - 20 {
                let dev = (0..nx)
                    .map(|i| (x[i] - plan[k + 1][i]).powi(2))
                    .sum::<f64>();
                worst = worst.max(dev.sqrt());
            }
        }
        worst
    };
    let without = tail_deviation(None);
    let with = tail_deviation(Some(disturbance(nx, 0.5)));
    assert!(
        without > 0.01,
        "the disturbance moves the plant off the plan: {without}"
    );
    assert!(
        with < 1e-4,
        "with the correction {with} (without {without})"
    );
}

#[test]
fn about_a_plan_only_the_disturbance_correction_is_taken() {
    let model = MatrixModel::random_stable(2, 6, 1, 0.9, 1).unwrap();
    let cfg = MpcConfig {
        horizon: 4,
        ..MpcConfig::default()
    };
    for mode in [OffsetMode::Integral, OffsetMode::Trajectory] {
        let mut c = MpcController::new(&model, &cfg).unwrap();
        let mut o = disturbance(2, 0.5);
        o.mode = mode;
        c.set_offset_free(Some(o)).unwrap();
        let e = c
            .solve_about_plan(&[0.1, 0.2], &[0.0, 0.0], &[0.0; 4])
            .unwrap_err()
            .to_string();
        assert!(e.contains("`disturbance` only"), "{mode:?}: {e}");
    }
}
