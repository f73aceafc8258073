//! Tests of the Riccati terminal cost (`MpcConfig::terminal_riccati`) against independent
//! computations: LQR's gain (Bellman: with the cost-to-go as terminal cost, the first planned
//! input is LQR's at any horizon) and the finite-difference gradient of the rollout cost.
#![allow(clippy::needless_range_loop)]

use faer::Mat;

use super::*;
use crate::model::matrix::MatrixModel;
use crate::model::LiftedModel;

/// An unstable lifted model with `lift(0) = 0` (features through tanh without offsets).
fn unstable(seed: u64) -> MatrixModel {
    let m = MatrixModel::random_stable(2, 6, 1, 1.4, seed).unwrap();
    let offsets = vec![0.0; m.features.nrows()];
    MatrixModel::new(m.a.clone(), m.b.clone(), m.features.clone(), offsets).unwrap()
}

fn spectral_radius(a: &Mat<f64>) -> f64 {
    crate::analysis::conditioning::eigenvalues(a.as_ref())
        .unwrap()
        .iter()
        .map(|z| z.norm())
        .fold(0.0, f64::max)
}

fn cfg(h: usize, solver: SolverKind, riccati: bool) -> MpcConfig {
    MpcConfig {
        horizon: h,
        q: Some(vec![2.0, 1.0]),
        r: Some(vec![0.3]),
        terminal_riccati: riccati,
        solver,
        regularization: 0.0,
        ..MpcConfig::default()
    }
}

#[test]
fn the_first_input_is_lqr_at_every_horizon() {
    let model = unstable(3);
    assert!(
        spectral_radius(&model.a) > 1.05,
        "{}",
        spectral_radius(&model.a)
    );
    let lqr = Lqr::new(&model, &[2.0, 1.0], &[0.3], 100_000, 1e-13).unwrap();
    assert!(lqr.converged);
    let x = [0.4, -0.3];
    let z = model.lift(&x);
    let zero = vec![0.0; 6];
    let want = lqr.control(&z, &zero, &zero).unwrap()[0];
    for solver in [SolverKind::Dedicated, SolverKind::Clarabel] {
        for h in [1, 2, 5, 12] {
            let mut mpc = MpcController::new(&model, &cfg(h, solver, true)).unwrap();
            let got = mpc.solve(&x, &[0.0, 0.0]).unwrap().u[0];
            assert!(
                (got - want).abs() <= 1e-7 * want.abs().max(1.0),
                "{solver:?} H = {h}: MPC {got} vs LQR {want}"
            );
        }
    }
    // Without it a short horizon plans something else: the check above is not vacuous.
    let mut short = MpcController::new(&model, &cfg(2, SolverKind::Dedicated, false)).unwrap();
    let plain = short.solve(&x, &[0.0, 0.0]).unwrap().u[0];
    assert!((plain - want).abs() > 1e-3, "{plain} vs {want}");
}

#[test]
fn the_plan_minimises_the_rollout_cost_with_the_lifted_terminal() {
    let model = unstable(3);
    let (q, r) = ([2.0, 1.0], 0.3);
    let lqr = Lqr::new(&model, &q, &[r], 100_000, 1e-13).unwrap();
    let (a, b) = (model.a(), model.b());
    let n = 6;
    let x = [0.4, -0.3];
    let reference = [0.25, 0.1];
    let z_ref = model.lift(&reference);
    let h = 4;
    // The cost, by rollout: stage costs on x_1..x_{H−1}, inputs, and (z_H − z_ref)ᵀP(z_H − z_ref).
    let cost = |u: &[f64]| -> f64 {
        let mut z = model.lift(&x);
        let mut c = 0.0;
        for t in 0..h {
            let zn: Vec<f64> = (0..n)
                .map(|i| (0..n).map(|j| a[(i, j)] * z[j]).sum::<f64>() + b[(i, 0)] * u[t])
                .collect();
            z = zn;
            c += r * u[t] * u[t];
            if t + 1 < h {
                c += (0..2)
                    .map(|i| q[i] * (z[i] - reference[i]).powi(2))
                    .sum::<f64>();
            }
        }
        let d: Vec<f64> = (0..n).map(|i| z[i] - z_ref[i]).collect();
        c + (0..n)
            .map(|i| (0..n).map(|j| d[i] * lqr.p[(i, j)] * d[j]).sum::<f64>())
            .sum::<f64>()
    };
    for solver in [SolverKind::Dedicated, SolverKind::Clarabel] {
        let mut mpc = MpcController::new(&model, &cfg(h, solver, true)).unwrap();
        let plan = mpc.solve(&x, &reference).unwrap().u;
        let base = cost(&plan);
        for t in 0..h {
            let eps = 1e-5;
            let (mut up, mut dn) = (plan.clone(), plan.clone());
            up[t] += eps;
            dn[t] -= eps;
            let grad = (cost(&up) - cost(&dn)) / (2.0 * eps);
            assert!(
                grad.abs() <= 1e-5 * base.max(1.0),
                "{solver:?}: ∂J/∂u_{t} = {grad} at the plan (J = {base})"
            );
        }
    }
}

#[test]
fn what_it_does_not_combine_with_is_refused() {
    let model = unstable(3);
    let both = MpcConfig {
        terminal: Some(vec![1.0, 1.0]),
        ..cfg(3, SolverKind::Dedicated, true)
    };
    let e = MpcController::new(&model, &both).err().unwrap().to_string();
    assert!(e.contains("terminal_riccati"), "{e}");
    let mut mpc = MpcController::new(&model, &cfg(3, SolverKind::Dedicated, true)).unwrap();
    let e = mpc
        .solve_about_plan(&[0.1, 0.0], &[0.0, 0.0], &[0.0; 3])
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("terminal_riccati"), "{e}");
    let e = mpc
        .set_offset_free(Some(offset_free::OffsetFreeConfig::defaults(
            offset_free::OffsetMode::Disturbance,
            2,
            vec![],
        )))
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("terminal_riccati"), "{e}");
}
