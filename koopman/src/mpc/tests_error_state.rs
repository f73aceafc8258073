//! Tests of the error-state MPC ([`MpcController::solve_about_plan`]) against an independent
//! computation: the deviation cost written out as explicit rollouts of the plant and of the
//! plan, its finite-difference gradient and the box KKT conditions, and a second QP solver.
#![allow(clippy::needless_range_loop)] // index loops mirror the formulas being checked

use super::*;
use crate::model::matrix::MatrixModel;
use crate::model::LiftedModel;
use crate::rng::Rng;

/// One step `z⁺ = A z + B u` written out.
fn step(model: &MatrixModel, z: &[f64], u: &[f64]) -> Vec<f64> {
    let mut zn = vec![0.0; z.len()];
    for i in 0..z.len() {
        for j in 0..z.len() {
            zn[i] += model.a[(i, j)] * z[j];
        }
        for k in 0..u.len() {
            zn[i] += model.b[(i, k)] * u[k];
        }
    }
    zn
}

/// One error-state problem: the model, the state, the plan's state now and its feed-forward,
/// the input weights R and the horizon.
struct Deviation<'a> {
    model: &'a MatrixModel,
    x: &'a [f64],
    r_now: &'a [f64],
    u_ff: &'a [f64],
    r: &'a [f64],
    h: usize,
}

impl Deviation<'_> {
    /// `Σ ‖P(z_{τ+1} − ž_{τ+1})‖²_Q + (u_τ − u_ff,τ)ᵀ R (u_τ − u_ff,τ)` with `z` rolled out
    /// from `Φ(x)` under `u` and `ž` from `Φ(r_now)` under `u_ff` (Q is the identity).
    fn cost(&self, u: &[f64]) -> f64 {
        let (nx, nu) = (self.model.nx(), self.model.nu());
        let (mut z, mut zp) = (self.model.lift(self.x), self.model.lift(self.r_now));
        let mut c = 0.0;
        for t in 0..self.h {
            z = step(self.model, &z, &u[t * nu..(t + 1) * nu]);
            zp = step(self.model, &zp, &self.u_ff[t * nu..(t + 1) * nu]);
            for i in 0..nx {
                c += (z[i] - zp[i]).powi(2);
            }
            for k in 0..nu {
                c += self.r[k] * (u[t * nu + k] - self.u_ff[t * nu + k]).powi(2);
            }
        }
        c
    }

    /// Central differences of [`Deviation::cost`] at `u`.
    fn fd_gradient(&self, u: &[f64]) -> Vec<f64> {
        (0..u.len())
            .map(|i| {
                let (mut up, mut um) = (u.to_vec(), u.to_vec());
                up[i] += 1e-5;
                um[i] -= 1e-5;
                (self.cost(&up) - self.cost(&um)) / 2e-5
            })
            .collect()
    }
}

pub(super) fn random_vec(rng: &mut Rng, n: usize, s: f64) -> Vec<f64> {
    (0..n).map(|_| rng.uniform(-s, s)).collect()
}

#[test]
fn on_the_plan_the_error_state_mpc_applies_the_feedforward_exactly() {
    // The plant is the model and the state is the plan's: nothing to correct, whatever R.
    let model = MatrixModel::random_stable(3, 14, 2, 0.97, 4).unwrap();
    let h = 7;
    for r in [None, Some(vec![0.05, 0.2])] {
        let cfg = MpcConfig {
            horizon: h,
            r,
            ..MpcConfig::default()
        };
        let mut c = MpcController::new(&model, &cfg).unwrap();
        let mut rng = Rng::new(8);
        let x = random_vec(&mut rng, 3, 1.0);
        let u_ff = random_vec(&mut rng, h * 2, 0.5);
        let s = c.solve_about_plan(&x, &x, &u_ff).unwrap();
        let worst =
            s.u.iter()
                .zip(&u_ff)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
        assert!(worst < 1e-7, "max |u − u_ff| = {worst}");
    }
}

#[test]
fn unconstrained_error_state_plan_zeroes_the_gradient_of_the_written_out_cost() {
    let model = MatrixModel::random_stable(2, 11, 2, 0.96, 6).unwrap();
    let (h, r) = (8, vec![0.03, 0.1]);
    let cfg = MpcConfig {
        horizon: h,
        r: Some(r.clone()),
        regularization: 0.0,
        ..MpcConfig::default()
    };
    let mut c = MpcController::new(&model, &cfg).unwrap();
    let mut rng = Rng::new(21);
    for _ in 0..4 {
        let x = random_vec(&mut rng, 2, 1.0);
        let r_now = random_vec(&mut rng, 2, 1.0);
        let u_ff = random_vec(&mut rng, h * 2, 1.0);
        let s = c.solve_about_plan(&x, &r_now, &u_ff).unwrap();
        assert_eq!(s.status, SolveStatus::Solved);
        let p = Deviation {
            model: &model,
            x: &x,
            r_now: &r_now,
            u_ff: &u_ff,
            r: &r,
            h,
        };
        let g = p.fd_gradient(&s.u);
        let worst = g.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(worst < 1e-6, "finite-difference gradient {worst}");
        // The QP's linear term is half the cost's gradient at U = 0 (`½UᵀHU + qᵀU = ½J + c`).
        let zero = vec![0.0; h * 2];
        let g0 = p.fd_gradient(&zero);
        let q = c.linear_term().to_vec();
        for i in 0..q.len() {
            assert!(
                (q[i] - 0.5 * g0[i]).abs() < 1e-6 * (1.0 + g0[i].abs()),
                "q[{i}] {} vs ½∇J {}",
                q[i],
                0.5 * g0[i]
            );
        }
    }
}

#[test]
fn bounded_error_state_plans_agree_across_solvers_and_satisfy_kkt() {
    let mut active = 0;
    for seed in 0..6u64 {
        let mut rng = Rng::new(300 + seed);
        let (nx, nu, h) = (1 + rng.below(3), 1 + rng.below(3), 4 + rng.below(8));
        let latent = nx + 2 + rng.below(12);
        let model = MatrixModel::random_stable(nx, latent, nu, 0.98, seed).unwrap();
        let r: Vec<f64> = (0..nu).map(|_| rng.uniform(1e-3, 0.05)).collect();
        let bound = 0.4;
        let cfg = MpcConfig {
            horizon: h,
            r: Some(r.clone()),
            regularization: 0.0,
            u_min: Some(vec![-bound; nu]),
            u_max: Some(vec![bound; nu]),
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
        for _ in 0..3 {
            let x = random_vec(&mut rng, nx, 2.0);
            let r_now = random_vec(&mut rng, nx, 2.0);
            let u_ff = random_vec(&mut rng, h * nu, 0.3);
            let a = ded.solve_about_plan(&x, &r_now, &u_ff).unwrap();
            let b = cla.solve_about_plan(&x, &r_now, &u_ff).unwrap();
            let diff =
                a.u.iter()
                    .zip(&b.u)
                    .map(|(p, q)| (p - q).abs())
                    .fold(0.0, f64::max);
            assert!(
                diff < 1e-6,
                "seed {seed}: dedicated vs clarabel max |Δu| = {diff}"
            );
            // KKT from the written-out cost: free inputs have zero gradient, bound ones push out.
            let p = Deviation {
                model: &model,
                x: &x,
                r_now: &r_now,
                u_ff: &u_ff,
                r: &r,
                h,
            };
            let g = p.fd_gradient(&a.u);
            let scale = 1.0 + g.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for (i, (&u, &gi)) in a.u.iter().zip(&g).enumerate() {
                assert!(u.abs() <= bound + 1e-12, "bound violated at {i}");
                if u <= -bound + 1e-9 {
                    assert!(gi >= -1e-5 * scale, "lower multiplier sign at {i}: {gi}");
                    active += 1;
                } else if u >= bound - 1e-9 {
                    assert!(gi <= 1e-5 * scale, "upper multiplier sign at {i}: {gi}");
                    active += 1;
                } else {
                    assert!(gi.abs() <= 1e-5 * scale, "free gradient at {i}: {gi}");
                }
            }
        }
    }
    assert!(
        active > 5,
        "the problems must have active bounds ({active})"
    );
}

#[test]
fn bad_error_state_input_gives_typed_errors() {
    let model = MatrixModel::random_stable(2, 6, 1, 0.9, 1).unwrap();
    let cfg = MpcConfig {
        horizon: 4,
        ..MpcConfig::default()
    };
    let mut c = MpcController::new(&model, &cfg).unwrap();
    let (x, ff) = (vec![0.1, 0.2], vec![0.0; 4]);
    assert!(matches!(
        c.solve_about_plan(&x, &x, &[0.0; 3]),
        Err(crate::Error::InvalidArgument(_))
    ));
    assert!(matches!(
        c.solve_about_plan(&x, &[0.0; 3], &ff),
        Err(crate::Error::Dimension { .. })
    ));
    assert!(matches!(
        c.solve_about_plan(&x, &x, &[0.0, f64::NAN, 0.0, 0.0]),
        Err(crate::Error::NonFinite(_))
    ));
    assert!(matches!(
        c.solve_about_plan(&[f64::INFINITY, 0.0], &x, &ff),
        Err(crate::Error::NonFinite(_))
    ));
    // The controller still serves afterwards.
    assert!(c.solve_about_plan(&x, &x, &ff).is_ok());
}

/// The dedicated solver folds the plan's rollout into a precomputed map and forms the QP's
/// linear term only on demand: interleaved with plain solves, `linear_term` after each solve is
/// the one Clarabel's controller (which forms it every solve) solved with, and so are the plans.
#[test]
fn the_folded_rollout_gives_the_linear_term_and_plan_of_each_solve_interleaved() {
    let model = MatrixModel::random_stable(2, 9, 2, 0.97, 12).unwrap();
    let h = 6;
    let cfg = MpcConfig {
        horizon: h,
        r: Some(vec![0.02, 0.05]),
        u_min: Some(vec![-0.5; 2]),
        u_max: Some(vec![0.5; 2]),
        ..MpcConfig::default()
    };
    let mut ded = MpcController::new(&model, &cfg).unwrap();
    let clarabel = MpcConfig {
        solver: SolverKind::Clarabel,
        ..cfg.clone()
    };
    let mut cla = MpcController::new(&model, &clarabel).unwrap();
    let mut rng = Rng::new(77);
    for step in 0..6 {
        let x = random_vec(&mut rng, 2, 1.0);
        let r_now = random_vec(&mut rng, 2, 1.0);
        let u_ff = random_vec(&mut rng, h * 2, 0.4);
        let (a, b) = if step % 2 == 0 {
            (
                ded.solve_about_plan(&x, &r_now, &u_ff).unwrap(),
                cla.solve_about_plan(&x, &r_now, &u_ff).unwrap(),
            )
        } else {
            (
                ded.solve(&x, &r_now).unwrap(),
                cla.solve(&x, &r_now).unwrap(),
            )
        };
        // Asked after plain solves that follow an unasked error-state solve, and after one
        // error-state solve.
        if step % 2 == 1 || step == 4 {
            let (qa, qb) = (ded.linear_term().to_vec(), cla.linear_term().to_vec());
            for (i, (p, q)) in qa.iter().zip(&qb).enumerate() {
                assert!(
                    (p - q).abs() < 1e-9 * (1.0 + q.abs()),
                    "step {step}, q[{i}]: {p} vs {q}"
                );
            }
        }
        for (p, q) in a.u.iter().zip(&b.u) {
            assert!((p - q).abs() < 1e-5, "step {step}: {:?} vs {:?}", a.u, b.u);
        }
    }
}
