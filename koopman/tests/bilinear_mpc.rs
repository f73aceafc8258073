//! Sequential convex MPC on the bilinear model, checked against independent computations: the
//! linear MPC (every N_i = 0), Clarabel on the same linearised QP, finite differences of the
//! exact bilinear cost, and the KKT conditions of the bilinear problem at a converged plan.

use faer::Mat;
use koopman::model::arch::Arch;
use koopman::model::bilinear::BilinearModel;
use koopman::model::koopman::KoopmanModel;
use koopman::mpc::boxqp::BoxQp;
use koopman::mpc::clarabel_qp::ClarabelQp;
use koopman::mpc::{BilinearMpc, MpcConfig, MpcController, QpSolver, ScpOptions, ScpStatus};
use koopman::rng::Rng;
use koopman::Error;

fn model(scale_n: f64, seed: u64) -> BilinearModel {
    let arch = Arch::new(2, 1, &[16, 16], 4).unwrap();
    let lin = KoopmanModel::init(arch.clone(), seed).unwrap();
    let mut rng = Rng::new(seed + 100);
    let nn = arch.latent_dim();
    let n = (0..nn * nn)
        .map(|_| scale_n * rng.normal() / nn as f64)
        .collect();
    BilinearModel::from_parts(lin, n).unwrap()
}

fn cfg(bound: f64, r: f64) -> MpcConfig {
    MpcConfig {
        r: Some(vec![r]),
        ..MpcConfig::with_bounds(vec![-bound], vec![bound])
    }
}

#[test]
fn with_n_zero_it_equals_the_linear_mpc() {
    let m = model(0.0, 3);
    let c = cfg(0.5, 0.0);
    let mut lin = MpcController::new(m.linear(), &c).unwrap();
    let mut bil = BilinearMpc::new(&m, &c, ScpOptions::default()).unwrap();
    let mut rng = Rng::new(4);
    let reference = [0.0, 0.0];
    for _ in 0..6 {
        let x = [rng.uniform(-2.0, 2.0), rng.uniform(-2.0, 2.0)];
        let a = lin.solve(&x, &reference).unwrap();
        let b = bil.solve(&x, &reference).unwrap();
        assert_eq!(b.status, ScpStatus::Converged);
        assert!(b.linearisations <= 2, "{b:?}");
        let d =
            a.u.iter()
                .zip(&b.u)
                .fold(0.0f64, |m, (p, q)| m.max((p - q).abs()));
        assert!(d <= 1e-8, "plans differ by {d}");
    }
}

#[test]
fn linearised_qp_matches_finite_differences_and_clarabel() {
    let m = model(3.0, 5);
    let c = MpcConfig {
        regularization: 0.0,
        ..cfg(1.0, 0.05)
    };
    let mut mpc = BilinearMpc::new(&m, &c, ScpOptions::default()).unwrap();
    let hz = mpc.horizon();
    let mut rng = Rng::new(6);
    let z0 = m.lift(&[1.1, -0.4]);
    let ubar: Vec<f64> = (0..hz).map(|_| rng.uniform(-1.0, 1.0)).collect();
    let reference = [0.3, 0.0];
    let (h, q) = mpc.linearised_qp(&z0, &ubar, &reference).unwrap();
    // ∇J(ū) = 2 (H ū + q) for the exact bilinear cost J (first-order exactness).
    let step = 1e-6;
    let mut num = 0.0;
    let mut den = 0.0;
    for k in 0..hz {
        let mut up = ubar.clone();
        up[k] += step;
        let jp = mpc.cost(&z0, &up, &reference).unwrap();
        up[k] -= 2.0 * step;
        let jm = mpc.cost(&z0, &up, &reference).unwrap();
        let fd = (jp - jm) / (2.0 * step);
        let g: f64 = 2.0 * ((0..hz).map(|j| h[(k, j)] * ubar[j]).sum::<f64>() + q[k]);
        num += (g - fd).powi(2);
        den += fd * fd;
    }
    assert!(den > 0.0);
    assert!(
        (num / den).sqrt() < 1e-6,
        "gradient rel. error {}",
        (num / den).sqrt()
    );
    // The dedicated solver and Clarabel agree on this QP.
    let (lo, hi) = (vec![-1.0; hz], vec![1.0; hz]);
    let mut boxqp = BoxQp::new(h.as_ref(), &lo, &hi, 200, None).unwrap();
    let mut u1 = vec![0.0; hz];
    boxqp.solve(&q, &[], &mut u1);
    let g = Mat::from_fn(2 * hz, hz, |r, col| {
        if r == col {
            1.0
        } else if r == col + hz {
            -1.0
        } else {
            0.0
        }
    });
    // G u ≤ h with G = [I; −I], h = [hi; −lo].
    let hb: Vec<f64> = hi.iter().copied().chain(lo.iter().map(|v| -v)).collect();
    let mut cl = ClarabelQp::new(h.as_ref(), g.as_ref(), 200, None).unwrap();
    let mut u2 = vec![0.0; hz];
    cl.solve(&q, &hb, &mut u2);
    let d = u1
        .iter()
        .zip(&u2)
        .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
    assert!(d < 1e-6, "dedicated vs Clarabel {d}: {u1:?} {u2:?}");
    assert!(
        u1.iter().any(|v| v.abs() > 1.0 - 1e-9),
        "no bound active: weak test"
    );
}

#[test]
fn a_converged_plan_satisfies_the_kkt_conditions_of_the_bilinear_problem() {
    let m = model(2.0, 7);
    let c = cfg(0.2, 0.01);
    let opts = ScpOptions {
        max_linearisations: 30,
        tol: 1e-10,
    };
    let mut mpc = BilinearMpc::new(&m, &c, opts).unwrap();
    let x = [1.5, 0.5];
    let reference = [0.0, 0.0];
    let s = mpc.solve(&x, &reference).unwrap();
    assert_eq!(s.status, ScpStatus::Converged, "{s:?}");
    assert!(s.linearisations >= 2);
    let z0 = m.lift(&x);
    let hz = mpc.horizon();
    let step = 1e-6;
    let mut worst = 0.0f64;
    let mut scale = 0.0f64;
    for k in 0..hz {
        let mut up = s.u.clone();
        up[k] += step;
        let jp = mpc.cost(&z0, &up, &reference).unwrap();
        up[k] -= 2.0 * step;
        let jm = mpc.cost(&z0, &up, &reference).unwrap();
        let g = (jp - jm) / (2.0 * step);
        scale = scale.max(g.abs());
        // Projected gradient: zero inside the box, pointing outwards on an active bound.
        let p = s.u[k] - (s.u[k] - g).clamp(-0.2, 0.2);
        worst = worst.max(p.abs());
    }
    assert!(
        scale > 1e-3 && s.u.iter().any(|v| v.abs() > 0.2 - 1e-9),
        "no bound active, gradient ~0 (scale {scale}): weak test"
    );
    assert!(
        worst <= 1e-5 * (1.0 + scale),
        "projected gradient {worst} (scale {scale})"
    );
    assert!((mpc.cost(&z0, &s.u, &reference).unwrap() - s.cost).abs() <= 1e-12 * s.cost);
}

#[test]
fn a_capped_iteration_reports_not_converged_with_the_best_finite_plan() {
    let m = model(6.0, 9);
    let c = cfg(2.0, 0.0);
    let opts = ScpOptions {
        max_linearisations: 1,
        tol: 0.0,
    };
    let mut mpc = BilinearMpc::new(&m, &c, opts).unwrap();
    let x = [2.0, -1.0];
    let s = mpc.solve(&x, &[0.0, 0.0]).unwrap();
    assert_eq!(s.status, ScpStatus::NotConverged);
    assert_eq!(s.linearisations, 1);
    assert!(s.u.iter().all(|v| v.is_finite() && v.abs() <= 2.0));
    let z0 = m.lift(&x);
    let zero = mpc
        .cost(&z0, &vec![0.0; mpc.horizon()], &[0.0, 0.0])
        .unwrap();
    assert!(
        s.cost <= zero,
        "best plan {} worse than the start {zero}",
        s.cost
    );
    assert!(s.cost.is_finite());
}

#[test]
fn bad_input_is_a_typed_error_and_the_controller_keeps_working() {
    let m = model(1.0, 11);
    let c = cfg(1.0, 0.0);
    let mut mpc = BilinearMpc::new(&m, &c, ScpOptions::default()).unwrap();
    assert!(matches!(
        mpc.solve(&[f64::NAN, 0.0], &[0.0, 0.0]),
        Err(Error::NonFinite(_))
    ));
    assert!(matches!(
        mpc.solve(&[0.0], &[0.0, 0.0]),
        Err(Error::Dimension { .. })
    ));
    assert!(matches!(
        mpc.solve(&[0.0, 0.0], &[0.0, 0.0, 0.0]),
        Err(Error::InvalidArgument(_))
    ));
    assert!(mpc.solve(&[0.5, 0.0], &[0.0, 0.0]).is_ok());
    let with_state_bounds = MpcConfig {
        x_max: Some(vec![1.0, 1.0]),
        ..c.clone()
    };
    assert!(matches!(
        BilinearMpc::new(&m, &with_state_bounds, ScpOptions::default()),
        Err(Error::InvalidArgument(_))
    ));
    let no_its = ScpOptions {
        max_linearisations: 0,
        tol: 1e-6,
    };
    assert!(BilinearMpc::new(&m, &c, no_its).is_err());
}

#[test]
fn more_linearisations_never_give_a_worse_plan_than_fewer() {
    // The iterates of a 3-QP solve include the 1-QP solve's plan (same start), and the returned
    // plan is the best of them on the exact bilinear cost.
    let m = model(6.0, 9);
    let c = cfg(2.0, 0.0);
    let x = [2.0, -1.0];
    let z0 = m.lift(&x);
    let solve = |cap: usize| {
        let opts = ScpOptions {
            max_linearisations: cap,
            tol: 0.0,
        };
        let mut mpc = BilinearMpc::new(&m, &c, opts).unwrap();
        let s = mpc.solve(&x, &[0.0, 0.0]).unwrap();
        let exact = mpc.cost(&z0, &s.u, &[0.0, 0.0]).unwrap();
        assert!(
            (exact - s.cost).abs() <= 1e-12 * exact.max(1.0),
            "{exact} vs {}",
            s.cost
        );
        s
    };
    let (one, three) = (solve(1), solve(3));
    assert_eq!(three.status, ScpStatus::NotConverged);
    assert_eq!(three.linearisations, 3);
    assert!(three.cost <= one.cost, "{} > {}", three.cost, one.cost);
    assert!(three.u.iter().all(|v| v.is_finite() && v.abs() <= 2.0));
}

/// A model whose rollout overflows to ±∞/NaN within the horizon (A = 1e40·I).
fn overflowing_model() -> BilinearModel {
    let arch = Arch::new(2, 1, &[16, 16], 4).unwrap();
    let lay = arch.layout();
    let nn = arch.latent_dim();
    let mut p = KoopmanModel::init(arch.clone(), 3)
        .unwrap()
        .params()
        .to_vec();
    for i in 0..nn {
        p[lay.a + i * nn + i] = 1e40;
    }
    let n = vec![1e-3; nn * nn];
    BilinearModel::from_parts(KoopmanModel::from_params(arch, p).unwrap(), n).unwrap()
}

#[test]
fn a_linearisation_that_overflows_falls_back_to_a_finite_plan_and_never_sends_nan() {
    use koopman::mpc::{FallbackReason, Policy};
    let m = overflowing_model();
    let c = cfg(1.5, 0.0);
    let mut mpc = BilinearMpc::new(&m, &c, ScpOptions::default()).unwrap();
    // The linearised QP itself is refused with a typed error.
    let z0 = m.lift(&[0.3, 0.1]);
    assert!(matches!(
        mpc.linearised_qp(&z0, &vec![0.5; mpc.horizon()], &[0.0, 0.0]),
        Err(Error::NonFinite(_))
    ));
    let s = mpc.solve(&[0.3, 0.1], &[0.0, 0.0]).unwrap();
    assert_eq!(s.status, ScpStatus::Fallback(FallbackReason::Numerical));
    assert!(
        s.u.iter().all(|v| v.is_finite() && v.abs() <= 1.5),
        "{:?}",
        s.u
    );
    // In a loop, every input sent on is finite, in bounds and flagged as a fallback.
    for k in 0..5 {
        let a = mpc
            .act(&[0.3 - 0.1 * k as f64, 0.1], &[0.0, 0.0], &[0.0, 0.0])
            .unwrap();
        assert!(a.fallback);
        assert!(
            a.u.iter().all(|v| v.is_finite() && v.abs() <= 1.5),
            "{:?}",
            a.u
        );
    }
    // Without the fallback it is a typed error, not a NaN plan.
    let strict = MpcConfig {
        fallback: false,
        ..c
    };
    let mut mpc = BilinearMpc::new(&m, &strict, ScpOptions::default()).unwrap();
    assert!(matches!(
        mpc.solve(&[0.3, 0.1], &[0.0, 0.0]),
        Err(Error::Numerical(_))
    ));
}
