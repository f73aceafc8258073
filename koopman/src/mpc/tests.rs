//! Tests of the condensed MPC and its solvers against independent computations (rollouts,
//! finite differences, a second solver, the KKT conditions).
#![allow(clippy::needless_range_loop)] // index loops mirror the formulas being checked

use faer::linalg::solvers::Solve;
use faer::{Col, Mat};

use super::condensed::{Condensed, Weights};
use super::*;
use crate::model::matrix::MatrixModel;
use crate::model::LiftedModel;
use crate::rng::Rng;

/// Weights of a test cost: Q, terminal Q and R diagonals.
struct W<'a>(&'a [f64], &'a [f64], &'a [f64]);

fn rollout_cost(model: &MatrixModel, x: &[f64], u: &[f64], r: &[f64], w: &W<'_>, h: usize) -> f64 {
    let (q, qf, rw) = (w.0, w.1, w.2);
    let (nx, nu) = (model.nx(), model.nu());
    let mut z = model.lift(x);
    let mut c = 0.0;
    for t in 0..h {
        let mut zn = vec![0.0; z.len()];
        for i in 0..z.len() {
            for j in 0..z.len() {
                zn[i] += model.a[(i, j)] * z[j];
            }
            for k in 0..nu {
                zn[i] += model.b[(i, k)] * u[t * nu + k];
            }
        }
        z = zn;
        let w = if t + 1 == h { qf } else { q };
        for i in 0..nx {
            c += w[i] * (z[i] - r[t * nx + i]).powi(2);
        }
        for k in 0..nu {
            c += rw[k] * u[t * nu + k].powi(2);
        }
    }
    c
}

fn random_vec(rng: &mut Rng, n: usize, s: f64) -> Vec<f64> {
    (0..n).map(|_| rng.uniform(-s, s)).collect()
}

#[test]
fn condensed_predictions_and_cost_match_a_rollout() {
    let model = MatrixModel::random_stable(3, 12, 2, 0.97, 1).unwrap();
    let (q, qf, rw) = (vec![1.0, 2.0, 0.5], vec![3.0, 1.0, 1.0], vec![0.1, 0.2]);
    let w = Weights {
        q: &q,
        terminal: &qf,
        r: &rw,
        regularization: 0.0,
    };
    let h = 6;
    let c = Condensed::build(model.a.as_ref(), model.b.as_ref(), 3, h, &w).unwrap();
    let mut rng = Rng::new(5);
    let x = random_vec(&mut rng, 3, 1.0);
    let z0 = model.lift(&x);
    let r = random_vec(&mut rng, h * 3, 1.0);
    let mut lin = vec![0.0; h * 2];
    c.linear_term(&z0, &r, &mut lin);
    // ½UᵀHU + qᵀU must equal half the rollout cost up to a constant: compare differences.
    let quad = |u: &[f64]| {
        let mut hu = vec![0.0; u.len()];
        super::condensed::gemv_acc(c.hessian.as_ref(), u, &mut hu);
        0.5 * u.iter().zip(&hu).map(|(a, b)| a * b).sum::<f64>()
            + u.iter().zip(&lin).map(|(a, b)| a * b).sum::<f64>()
    };
    let u0 = vec![0.0; h * 2];
    let base = rollout_cost(&model, &x, &u0, &r, &W(&q, &qf, &rw), h);
    assert!((c.cost(&z0, &u0, &r, &w) - base).abs() < 1e-10 * (1.0 + base));
    for _ in 0..5 {
        let u = random_vec(&mut rng, h * 2, 2.0);
        let lhs = rollout_cost(&model, &x, &u, &r, &W(&q, &qf, &rw), h) - base;
        let rhs = 2.0 * (quad(&u) - quad(&u0));
        assert!(
            (lhs - rhs).abs() < 1e-9 * (1.0 + lhs.abs()),
            "{lhs} vs {rhs}"
        );
    }
}

#[test]
fn unconstrained_solution_is_the_closed_form_and_zeroes_the_fd_gradient() {
    let model = MatrixModel::random_stable(2, 10, 2, 0.95, 2).unwrap();
    let cfg = MpcConfig {
        horizon: 8,
        r: Some(vec![0.01, 0.02]),
        ..MpcConfig::default()
    };
    let mut rng = Rng::new(3);
    let x = random_vec(&mut rng, 2, 1.0);
    let reference = vec![0.3, -0.2];
    let mut ded = MpcController::new(&model, &cfg).unwrap();
    let sol = ded.solve(&x, &reference).unwrap();
    assert_eq!(sol.status, SolveStatus::Solved);
    // Closed form with an LU solve (a different factorisation than the solver's Cholesky).
    let c = ded.condensed();
    let z0 = model.lift(&x);
    let r: Vec<f64> = (0..8).flat_map(|_| reference.clone()).collect();
    let mut lin = vec![0.0; 16];
    c.linear_term(&z0, &r, &mut lin);
    let rhs = Col::from_fn(16, |i| -lin[i]);
    let u_cf = c.hessian.partial_piv_lu().solve(&rhs);
    for i in 0..16 {
        assert!(
            (sol.u[i] - u_cf[i]).abs() < 1e-9,
            "u[{i}] {} vs {}",
            sol.u[i],
            u_cf[i]
        );
    }
    // Central finite differences of the rollout cost vanish at the optimum.
    let (q, rw) = (vec![1.0, 1.0], vec![0.01, 0.02]);
    let g0: f64 = (0..16)
        .map(|i| {
            let mut up = sol.u.clone();
            let mut um = sol.u.clone();
            up[i] += 1e-5;
            um[i] -= 1e-5;
            let d = (rollout_cost(&model, &x, &up, &r, &W(&q, &q, &rw), 8)
                - rollout_cost(&model, &x, &um, &r, &W(&q, &q, &rw), 8))
                / 2e-5;
            d.abs()
        })
        .fold(0.0, f64::max);
    assert!(g0 < 1e-6, "finite-difference gradient {g0}");
    // The closed-form baseline gives the same plan when no bound is active.
    let mut cf = MpcController::new(
        &model,
        &MpcConfig {
            solver: SolverKind::ClosedForm,
            ..cfg.clone()
        },
    )
    .unwrap();
    let s2 = cf.solve(&x, &reference).unwrap();
    for i in 0..16 {
        assert!((s2.u[i] - sol.u[i]).abs() < 1e-9);
    }
}

/// KKT of the box QP: free variables have zero gradient, bound ones push outwards.
fn assert_box_kkt(c: &Condensed, lin: &[f64], u: &[f64], lo: f64, hi: f64) {
    let mut g = lin.to_vec();
    super::condensed::gemv_acc(c.hessian.as_ref(), u, &mut g);
    let scale = 1.0 + lin.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for i in 0..u.len() {
        assert!(u[i] >= lo - 1e-12 && u[i] <= hi + 1e-12, "bound violated");
        if u[i] <= lo + 1e-9 {
            assert!(
                g[i] >= -1e-7 * scale,
                "lower-bound multiplier sign, g={}",
                g[i]
            );
        } else if u[i] >= hi - 1e-9 {
            assert!(
                g[i] <= 1e-7 * scale,
                "upper-bound multiplier sign, g={}",
                g[i]
            );
        } else {
            assert!(g[i].abs() <= 1e-7 * scale, "free gradient {}", g[i]);
        }
    }
}

#[test]
fn dedicated_and_clarabel_agree_on_random_box_problems_and_satisfy_kkt() {
    let mut active_seen = 0;
    for seed in 0..12u64 {
        let mut rng = Rng::new(100 + seed);
        let nx = 1 + rng.below(3);
        let latent = nx + rng.below(20);
        let nu = 1 + rng.below(3);
        let horizon = 3 + rng.below(10);
        let model = MatrixModel::random_stable(nx, latent, nu, 0.99, seed).unwrap();
        let bound = 0.3 + rng.uniform01();
        let base = MpcConfig {
            horizon,
            r: Some((0..nu).map(|_| rng.uniform(1e-3, 0.1)).collect()),
            u_min: Some(vec![-bound; nu]),
            u_max: Some(vec![bound; nu]),
            ..MpcConfig::default()
        };
        let mut ded = MpcController::new(&model, &base).unwrap();
        let mut cla = MpcController::new(
            &model,
            &MpcConfig {
                solver: SolverKind::Clarabel,
                ..base.clone()
            },
        )
        .unwrap();
        for _ in 0..4 {
            let x = random_vec(&mut rng, nx, 3.0);
            let reference = random_vec(&mut rng, nx * horizon, 2.0);
            let a = ded.solve(&x, &reference).unwrap();
            let b = cla.solve(&x, &reference).unwrap();
            assert_eq!(a.status, SolveStatus::Solved);
            assert_eq!(b.status, SolveStatus::Solved);
            let diff =
                a.u.iter()
                    .zip(&b.u)
                    .map(|(p, q)| (p - q).abs())
                    .fold(0.0, f64::max);
            assert!(diff < 1e-6, "seed {seed}: max |Δu| = {diff}");
            active_seen += a.u.iter().filter(|v| v.abs() >= bound - 1e-12).count();
            let c = ded.condensed();
            let mut lin = vec![0.0; c.n_vars()];
            c.linear_term(&model.lift(&x), &reference, &mut lin);
            assert_box_kkt(c, &lin, &a.u, -bound, bound);
        }
    }
    assert!(
        active_seen > 20,
        "the test problems must have active bounds ({active_seen})"
    );
}

#[test]
fn paper_setting_r_zero_is_regularised_and_solvers_still_agree() {
    // R = 0, Q = I: the Hessian is rank deficient (H·nu > H·nx) before the Tikhonov term.
    let model = MatrixModel::random_stable(1, 8, 3, 0.98, 9).unwrap();
    let cfg = MpcConfig {
        horizon: 6,
        regularization: 1e-6,
        u_min: Some(vec![-0.5; 3]),
        u_max: Some(vec![0.5; 3]),
        ..MpcConfig::default()
    };
    let mut ded = MpcController::new(&model, &cfg).unwrap();
    let c = ded.condensed();
    assert!(c.tikhonov > 0.0);
    let eig = c
        .hessian
        .self_adjoint_eigenvalues(faer::Side::Lower)
        .unwrap();
    assert!(
        eig[0] > 0.0 && eig[0] <= 1.01 * c.tikhonov,
        "smallest eigenvalue {} vs δ {}",
        eig[0],
        c.tikhonov
    );
    let mut cla = MpcController::new(
        &model,
        &MpcConfig {
            solver: SolverKind::Clarabel,
            ..cfg.clone()
        },
    )
    .unwrap();
    let a = ded.solve(&[2.0], &[0.0]).unwrap();
    let b = cla.solve(&[2.0], &[0.0]).unwrap();
    let diff =
        a.u.iter()
            .zip(&b.u)
            .map(|(p, q)| (p - q).abs())
            .fold(0.0, f64::max);
    assert!(diff < 1e-5, "max |Δu| = {diff}");
}

#[test]
fn receding_horizon_warm_starts_track_clarabel_along_a_closed_loop() {
    let model = MatrixModel::random_stable(3, 20, 2, 0.99, 4).unwrap();
    let cfg = MpcConfig {
        horizon: 10,
        r: Some(vec![1e-3; 2]),
        u_min: Some(vec![-0.4; 2]),
        u_max: Some(vec![0.4; 2]),
        ..MpcConfig::default()
    };
    let mut ded = MpcController::new(&model, &cfg).unwrap();
    let mut cla = MpcController::new(
        &model,
        &MpcConfig {
            solver: SolverKind::Clarabel,
            ..cfg.clone()
        },
    )
    .unwrap();
    let mut x = vec![2.0, -1.5, 1.0];
    let mut total_iters = 0;
    for k in 0..30 {
        let reference = vec![(k as f64 * 0.2).sin(), 0.0, 0.5];
        let a = ded.solve(&x, &reference).unwrap();
        let b = cla.solve(&x, &reference).unwrap();
        let diff =
            a.u.iter()
                .zip(&b.u)
                .map(|(p, q)| (p - q).abs())
                .fold(0.0, f64::max);
        assert!(diff < 1e-6, "step {k}: {diff}");
        total_iters += a.iterations;
        // Advance with the model itself (its first nx latent coordinates).
        let z = model.lift(&x);
        let mut zn = vec![0.0; z.len()];
        for i in 0..z.len() {
            zn[i] = (0..z.len()).map(|j| model.a[(i, j)] * z[j]).sum::<f64>()
                + (0..2).map(|j| model.b[(i, j)] * a.u[j]).sum::<f64>();
        }
        x = zn[..3].to_vec();
    }
    assert!(
        total_iters < 30 * 10,
        "warm starts should keep iterations low ({total_iters})"
    );
}

#[test]
fn rate_and_state_bounds_hold_with_clarabel() {
    let model = MatrixModel::random_stable(2, 10, 1, 0.98, 6).unwrap();
    let free_cfg = MpcConfig {
        horizon: 10,
        r: Some(vec![1e-2]),
        u_min: Some(vec![-5.0]),
        u_max: Some(vec![5.0]),
        ..MpcConfig::default()
    };
    let x = [1.0, -1.0];
    let reference = [3.0, 0.0];
    let mut free = MpcController::new(&model, &free_cfg).unwrap();
    let unconstrained = free.solve(&x, &reference).unwrap();
    let du = 0.05;
    let xmax = 1.2;
    let cfg = MpcConfig {
        solver: SolverKind::Clarabel,
        du_max: Some(vec![du]),
        x_max: Some(vec![xmax, 10.0]),
        ..free_cfg.clone()
    };
    let mut ctl = MpcController::new(&model, &cfg).unwrap();
    let sol = ctl.solve(&x, &reference).unwrap();
    assert_eq!(sol.status, SolveStatus::Solved);
    let mut prev = 0.0;
    for &u in &sol.u {
        assert!((u - prev).abs() <= du + 1e-7, "rate bound");
        prev = u;
    }
    let pred = ctl.condensed().predict(&model.lift(&x), &sol.u);
    for t in 0..10 {
        assert!(
            pred[t * 2] <= xmax + 1e-7,
            "state bound at {t}: {}",
            pred[t * 2]
        );
    }
    // The constraints bind: the free optimum violates them, and the constrained cost is higher.
    let pred_free = ctl.condensed().predict(&model.lift(&x), &unconstrained.u);
    let free_viol = (0..10).any(|t| pred_free[t * 2] > xmax + 1e-3)
        || unconstrained.u.iter().any(|u| u.abs() > du * 10.0);
    assert!(free_viol);
    // Loose general bounds leave the optimum of the dedicated solver unchanged.
    let loose = MpcConfig {
        solver: SolverKind::Clarabel,
        du_max: Some(vec![100.0]),
        x_max: Some(vec![100.0, 100.0]),
        x_min: Some(vec![-100.0, -100.0]),
        ..free_cfg.clone()
    };
    let mut l = MpcController::new(&model, &loose).unwrap();
    let s = l.solve(&x, &reference).unwrap();
    let diff =
        s.u.iter()
            .zip(&unconstrained.u)
            .map(|(p, q)| (p - q).abs())
            .fold(0.0, f64::max);
    assert!(diff < 1e-6, "{diff}");
}

struct NanLift(MatrixModel);
impl LiftedModel for NanLift {
    fn nx(&self) -> usize {
        self.0.nx()
    }
    fn nu(&self) -> usize {
        self.0.nu()
    }
    fn latent_dim(&self) -> usize {
        self.0.latent_dim()
    }
    fn a(&self) -> Mat<f64> {
        self.0.a()
    }
    fn b(&self) -> Mat<f64> {
        self.0.b()
    }
    fn lift(&self, x: &[f64]) -> Vec<f64> {
        let mut z = self.0.lift(x);
        if x[0] > 100.0 {
            z[1] = f64::NAN;
        }
        z
    }
}

#[test]
fn bad_input_gives_typed_errors_never_a_panic() {
    use crate::Error;
    let model = MatrixModel::random_stable(2, 6, 1, 0.9, 7).unwrap();
    let cfg = MpcConfig {
        horizon: 5,
        u_min: Some(vec![-1.0]),
        u_max: Some(vec![1.0]),
        ..MpcConfig::default()
    };
    let mut ctl = MpcController::new(&model, &cfg).unwrap();
    assert!(matches!(
        ctl.solve(&[f64::NAN, 0.0], &[0.0, 0.0]),
        Err(Error::NonFinite(_))
    ));
    assert!(matches!(
        ctl.solve(&[f64::INFINITY, 0.0], &[0.0, 0.0]),
        Err(Error::NonFinite(_))
    ));
    assert!(matches!(
        ctl.solve(&[0.0], &[0.0, 0.0]),
        Err(Error::Dimension { .. })
    ));
    assert!(matches!(
        ctl.solve(&[0.0, 0.0], &[0.0, 0.0, 0.0]),
        Err(Error::InvalidArgument(_))
    ));
    assert!(matches!(
        ctl.solve(&[0.0, 0.0], &[f64::NAN, 0.0]),
        Err(Error::NonFinite(_))
    ));
    let nan = NanLift(model.clone());
    let mut c2 = MpcController::new(&nan, &cfg).unwrap();
    assert!(matches!(
        c2.solve(&[200.0, 0.0], &[0.0, 0.0]),
        Err(Error::NonFinite(_))
    ));
    // Inconsistent configurations.
    let bad = MpcConfig {
        u_min: Some(vec![1.0]),
        u_max: Some(vec![-1.0]),
        ..cfg.clone()
    };
    assert!(matches!(
        MpcController::new(&model, &bad),
        Err(Error::InvalidArgument(_))
    ));
    let rate_on_dedicated = MpcConfig {
        du_max: Some(vec![0.1]),
        ..cfg.clone()
    };
    assert!(matches!(
        MpcController::new(&model, &rate_on_dedicated),
        Err(Error::InvalidArgument(_))
    ));
    let zero_h = MpcConfig {
        horizon: 0,
        ..cfg.clone()
    };
    assert!(MpcController::new(&model, &zero_h).is_err());
    // The solvers themselves reject mismatched vectors instead of indexing out of bounds.
    let h = Mat::<f64>::identity(3, 3);
    let mut bq = boxqp::BoxQp::new(h.as_ref(), &[-1.0; 3], &[1.0; 3], 10, None).unwrap();
    assert_eq!(
        bq.solve(&[0.0; 2], &[], &mut [0.0; 3]).status,
        QpStatus::Numerical
    );
    let mut cf = closed_form::ClampedClosedForm::new(h.as_ref(), &[-1.0; 3], &[1.0; 3]).unwrap();
    assert_eq!(
        cf.solve(&[0.0; 3], &[], &mut [0.0; 4]).status,
        QpStatus::Numerical
    );
    let wrong_q = MpcConfig {
        q: Some(vec![1.0]),
        ..cfg.clone()
    };
    assert!(matches!(
        MpcController::new(&model, &wrong_q),
        Err(Error::Dimension { .. })
    ));
}

#[test]
fn infeasible_and_limited_solves_fall_back_to_the_shifted_clamped_plan() {
    use crate::Error;
    let model = MatrixModel::random_stable(2, 6, 1, 0.9, 8).unwrap();
    let cfg = MpcConfig {
        horizon: 5,
        solver: SolverKind::Clarabel,
        u_min: Some(vec![-1.0]),
        u_max: Some(vec![1.0]),
        du_max: Some(vec![0.1]),
        ..MpcConfig::default()
    };
    let mut ctl = MpcController::new(&model, &cfg).unwrap();
    let first = ctl.solve(&[1.0, 0.0], &[0.0, 0.0]).unwrap();
    assert_eq!(first.status, SolveStatus::Solved);
    // u_prev far outside the box with a small rate bound: no feasible plan.
    ctl.set_previous_input(&[5.0]).unwrap();
    let fb = ctl.solve(&[1.0, 0.0], &[0.0, 0.0]).unwrap();
    assert_eq!(fb.status, SolveStatus::Fallback(FallbackReason::Infeasible));
    let mut expected: Vec<f64> = first.u[1..].to_vec();
    expected.push(first.u[4]);
    assert_eq!(fb.u, expected);
    assert!(fb.u.iter().all(|v| v.is_finite() && v.abs() <= 1.0));
    // Without fallback the same situation is an error.
    let mut strict = MpcController::new(
        &model,
        &MpcConfig {
            fallback: false,
            ..cfg.clone()
        },
    )
    .unwrap();
    strict.set_previous_input(&[5.0]).unwrap();
    assert!(matches!(
        strict.solve(&[1.0, 0.0], &[0.0, 0.0]),
        Err(Error::Numerical(_))
    ));
    // Clarabel stopped after one iteration: fallback (no previous plan → inputs closest to 0).
    let mut one = MpcController::new(
        &model,
        &MpcConfig {
            max_iterations: 1,
            du_max: None,
            ..cfg.clone()
        },
    )
    .unwrap();
    let s = one.solve(&[3.0, -2.0], &[0.0, 0.0]).unwrap();
    assert_eq!(
        s.status,
        SolveStatus::Fallback(FallbackReason::MaxIterations)
    );
    assert_eq!(s.u, vec![0.0; 5]);
    // Time limit.
    let mut tl = MpcController::new(
        &model,
        &MpcConfig {
            time_limit: Some(1e-12),
            du_max: None,
            ..cfg.clone()
        },
    )
    .unwrap();
    let s = tl.solve(&[3.0, -2.0], &[0.0, 0.0]).unwrap();
    assert_eq!(s.status, SolveStatus::Fallback(FallbackReason::TimeLimit));
    // The dedicated solver stopped early still returns a feasible, improved plan.
    let big = MatrixModel::random_stable(2, 12, 2, 0.99, 10).unwrap();
    let dcfg = MpcConfig {
        horizon: 10,
        r: Some(vec![1e-3; 2]),
        u_min: Some(vec![-0.05; 2]),
        u_max: Some(vec![0.05; 2]),
        max_iterations: 1,
        ..MpcConfig::default()
    };
    let mut d1 = MpcController::new(&big, &dcfg).unwrap();
    let s = d1.solve(&[3.0, -2.0], &[0.0, 0.0]).unwrap();
    assert_eq!(s.status, SolveStatus::Suboptimal);
    assert!(s.u.iter().all(|v| v.abs() <= 0.05 + 1e-15));
    let mut dfull = MpcController::new(
        &big,
        &MpcConfig {
            max_iterations: 100,
            ..dcfg.clone()
        },
    )
    .unwrap();
    let opt = dfull.solve(&[3.0, -2.0], &[0.0, 0.0]).unwrap();
    assert_eq!(opt.status, SolveStatus::Solved);
    let w = Weights {
        q: &[1.0, 1.0],
        terminal: &[1.0, 1.0],
        r: &[1e-3, 1e-3],
        regularization: 0.0,
    };
    let z0 = big.lift(&[3.0, -2.0]);
    let r = vec![0.0; 20];
    let c = dfull.condensed();
    assert!(c.cost(&z0, &opt.u, &r, &w) <= c.cost(&z0, &s.u, &r, &w) + 1e-12);
    assert!(c.cost(&z0, &s.u, &r, &w) < c.cost(&z0, &[0.0; 20], &r, &w));
}
