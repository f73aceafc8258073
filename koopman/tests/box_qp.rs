//! The dedicated box-QP solver against independent exact answers: enumeration of every active
//! set (small n), and the optimum certified by its KKT conditions after an LU solve of the
//! reduced system (faer) on the active set an interior-point solver (Clarabel) finds.

use faer::linalg::solvers::Solve;
use faer::{Col, Mat};
use koopman::model::matrix::MatrixModel;
use koopman::model::LiftedModel;
use koopman::mpc::boxqp::{BoxQp, WarmStart};
use koopman::mpc::clarabel_qp::ClarabelQp;
use koopman::mpc::{MpcConfig, MpcController, QpSolver, QpStatus, SolveStatus};
use koopman::rng::Rng;

/// `½uᵀHu + qᵀu`.
fn objective(h: &Mat<f64>, q: &[f64], u: &[f64]) -> f64 {
    let n = u.len();
    let mut f = 0.0;
    for i in 0..n {
        f += q[i] * u[i];
        for j in 0..n {
            f += 0.5 * u[i] * h[(i, j)] * u[j];
        }
    }
    f
}

/// The optimum of the QP with the variables in `fixed` held at `val` (LU solve of the free
/// block, faer): `None` if that point violates a bound or a multiplier has the wrong sign.
/// With `check_kkt` off only the bounds are checked (enumeration keeps the feasible points).
fn reduced_optimum(
    h: &Mat<f64>,
    q: &[f64],
    lo: &[f64],
    hi: &[f64],
    fixed: &[Option<f64>],
    check_kkt: bool,
) -> Option<Vec<f64>> {
    let n = q.len();
    let free: Vec<usize> = (0..n).filter(|&i| fixed[i].is_none()).collect();
    let mut u: Vec<f64> = (0..n).map(|i| fixed[i].unwrap_or(0.0)).collect();
    if !free.is_empty() {
        let hff = Mat::from_fn(free.len(), free.len(), |a, b| h[(free[a], free[b])]);
        let rhs = Col::from_fn(free.len(), |a| {
            let i = free[a];
            -q[i] - (0..n).map(|j| h[(i, j)] * u[j]).sum::<f64>()
        });
        let x = hff.partial_piv_lu().solve(&rhs);
        for (a, &i) in free.iter().enumerate() {
            u[i] = x[a];
        }
    }
    let scale = 1.0 + u.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if (0..n).any(|i| u[i] < lo[i] - 1e-12 * scale || u[i] > hi[i] + 1e-12 * scale) {
        return None;
    }
    if check_kkt {
        let gscale = 1.0 + q.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for i in 0..n {
            let g = q[i] + (0..n).map(|j| h[(i, j)] * u[j]).sum::<f64>();
            let ok = match fixed[i] {
                None => true,
                Some(_) if lo[i] == hi[i] => true,
                Some(v) if v == lo[i] => g >= -1e-9 * gscale,
                Some(_) => g <= 1e-9 * gscale,
            };
            if !ok {
                return None;
            }
        }
    }
    Some(u)
}

/// The exact optimum by enumerating every assignment free / lower / upper (n ≤ 8).
fn enumerate(h: &Mat<f64>, q: &[f64], lo: &[f64], hi: &[f64]) -> Vec<f64> {
    let n = q.len();
    let mut best: Option<(f64, Vec<f64>)> = None;
    for code in 0..3usize.pow(n as u32) {
        let mut c = code;
        let mut fixed = vec![None; n];
        let mut skip = false;
        for i in 0..n {
            let bound = match c % 3 {
                0 => None,
                1 => Some(lo[i]),
                _ => Some(hi[i]),
            };
            if bound.is_some_and(|b: f64| !b.is_finite()) {
                skip = true;
            }
            fixed[i] = bound;
            c /= 3;
        }
        if skip {
            continue;
        }
        if let Some(u) = reduced_optimum(h, q, lo, hi, &fixed, false) {
            let f = objective(h, q, &u);
            if best.as_ref().is_none_or(|(bf, _)| f < *bf) {
                best = Some((f, u));
            }
        }
    }
    best.expect("the box is not empty").1
}

/// Clarabel's answer polished: its active set, the reduced system solved exactly, certified by
/// the KKT conditions (panics if the certificate fails).
fn certified(h: &Mat<f64>, q: &[f64], lo: &[f64], hi: &[f64]) -> Vec<f64> {
    let n = q.len();
    let g = Mat::from_fn(2 * n, n, |r, c| {
        if r == c {
            1.0
        } else if r == c + n {
            -1.0
        } else {
            0.0
        }
    });
    let rhs: Vec<f64> = hi.iter().copied().chain(lo.iter().map(|v| -v)).collect();
    let mut cl = ClarabelQp::new(h.as_ref(), g.as_ref(), 200, None).unwrap();
    let mut uc = vec![0.0; n];
    let out = cl.solve(q, &rhs, &mut uc);
    assert!(matches!(
        out.status,
        QpStatus::Solved | QpStatus::Inaccurate
    ));
    let scale = 1.0
        + lo.iter()
            .chain(hi)
            .filter(|v| v.is_finite())
            .fold(0.0f64, |m, v| m.max(v.abs()));
    let fixed: Vec<Option<f64>> = (0..n)
        .map(|i| {
            if lo[i] == hi[i] || uc[i] <= lo[i] + 1e-7 * scale {
                Some(lo[i])
            } else if uc[i] >= hi[i] - 1e-7 * scale {
                Some(hi[i])
            } else {
                None
            }
        })
        .collect();
    reduced_optimum(h, q, lo, hi, &fixed, true).expect("the KKT certificate of the optimum")
}

fn random_spd(rng: &mut Rng, n: usize, cond_decades: f64) -> Mat<f64> {
    let w = Mat::from_fn(n, n, |_, _| rng.normal());
    let qr = w.qr();
    let qm = qr.compute_Q();
    let eig: Vec<f64> = (0..n)
        .map(|i| 10f64.powf(-cond_decades * i as f64 / (n.max(2) - 1) as f64))
        .collect();
    let mut h = Mat::from_fn(n, n, |i, j| {
        (0..n).map(|k| qm[(i, k)] * eig[k] * qm[(j, k)]).sum()
    });
    for i in 0..n {
        for j in 0..i {
            let v = 0.5 * (h[(i, j)] + h[(j, i)]);
            h[(i, j)] = v;
            h[(j, i)] = v;
        }
    }
    h
}

fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
}

fn solve(h: &Mat<f64>, q: &[f64], lo: &[f64], hi: &[f64], warm: &[f64]) -> (Vec<f64>, QpStatus) {
    let mut s = BoxQp::new(h.as_ref(), lo, hi, 1000, None).unwrap();
    let mut u = warm.to_vec();
    let out = s.solve(q, &[], &mut u);
    (u, out.status)
}

#[test]
fn small_random_problems_match_the_enumeration_of_every_active_set() {
    let mut rng = Rng::new(41);
    let mut active = 0;
    for case in 0..150 {
        let n = 1 + case % 7;
        let decades = rng.uniform(0.0, 4.0);
        let h = random_spd(&mut rng, n, decades);
        let q: Vec<f64> = (0..n).map(|_| 2.0 * rng.normal()).collect();
        let mut lo: Vec<f64> = (0..n).map(|_| rng.uniform(-1.5, 0.0)).collect();
        let mut hi: Vec<f64> = (0..n).map(|_| rng.uniform(0.0, 1.5)).collect();
        // Unbounded sides and fixed variables now and then.
        if case % 5 == 1 {
            lo[0] = f64::NEG_INFINITY;
        }
        if case % 7 == 3 {
            hi[n - 1] = f64::INFINITY;
        }
        if case % 6 == 2 && n > 1 {
            hi[1] = lo[1];
        }
        let exact = enumerate(&h, &q, &lo, &hi);
        // Cold, warm at the answer, and warm from a wrong working set (all upper bounds).
        let warm_wrong: Vec<f64> = hi.iter().map(|v| v.min(9.0)).collect();
        for warm in [vec![0.0; n], exact.clone(), warm_wrong] {
            let (u, status) = solve(&h, &q, &lo, &hi, &warm);
            assert_eq!(status, QpStatus::Solved, "case {case}");
            let d = max_diff(&u, &exact);
            assert!(d <= 1e-9, "case {case}: |Δu| {d}: {u:?} vs {exact:?}");
            assert!(
                (0..n).all(|i| u[i] >= lo[i] && u[i] <= hi[i]),
                "bounds, case {case}"
            );
        }
        active += (0..n)
            .filter(|&i| exact[i] == lo[i] || exact[i] == hi[i])
            .count();
    }
    assert!(
        active > 150,
        "too few active bounds to test anything ({active})"
    );
}

/// Sequences of QPs with one H (small n, infinite bounds, fixed variables): every warm start
/// from the previous solve's working set, as is or shifted (so that a bound lands on a
/// variable whose side is infinite or fixed), reaches the exact optimum.
#[test]
fn small_sequences_from_previous_or_shifted_working_sets_match_the_enumeration() {
    let mut rng = Rng::new(43);
    for case in 0..60 {
        let n = 2 + case % 6;
        let decades = rng.uniform(0.0, 3.0);
        let h = random_spd(&mut rng, n, decades);
        let lo: Vec<f64> = (0..n)
            .map(|i| {
                if i == 1 {
                    f64::NEG_INFINITY
                } else {
                    rng.uniform(-1.0, 0.0)
                }
            })
            .collect();
        let mut hi: Vec<f64> = (0..n)
            .map(|i| {
                if i == 0 {
                    f64::INFINITY
                } else {
                    rng.uniform(0.0, 1.0)
                }
            })
            .collect();
        if case % 3 == 0 && n > 2 {
            hi[n - 1] = lo[n - 1];
        }
        for mode in [
            WarmStart::Previous,
            WarmStart::Shifted(1),
            WarmStart::Shifted(n - 1),
        ] {
            let mut s = BoxQp::new(h.as_ref(), &lo, &hi, 1000, None).unwrap();
            s.set_warm_start(mode);
            for step in 0..4 {
                let q: Vec<f64> = (0..n).map(|_| 3.0 * rng.normal()).collect();
                let exact = enumerate(&h, &q, &lo, &hi);
                let mut u = vec![0.0; n];
                let out = s.solve(&q, &[], &mut u);
                assert_eq!(
                    out.status,
                    QpStatus::Solved,
                    "case {case} {mode:?} step {step}"
                );
                let d = max_diff(&u, &exact);
                assert!(d <= 1e-9, "case {case} {mode:?} step {step}: |Δu| {d}");
            }
        }
    }
}

/// The warm start from the previous working set is really taken (the same QP again needs no
/// change; `reset` forgets it), and from wrong previous sets — all bounds active before an
/// interior optimum, none before all active, shifted sets — every plan is the certified one.
#[test]
fn warm_starts_from_previous_or_shifted_working_sets_reach_the_certified_optimum() {
    let mut rng = Rng::new(17);
    let (nu, horizon) = (6, 10);
    let n = nu * horizon;
    let h = random_spd(&mut rng, n, 2.0);
    let bound = 0.4;
    let (lo, hi) = (vec![-bound; n], vec![bound; n]);
    let hq = |u: &[f64]| -> Vec<f64> {
        (0..n)
            .map(|i| -(0..n).map(|j| h[(i, j)] * u[j]).sum::<f64>())
            .collect()
    };
    let base: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
    let mut qs: Vec<Vec<f64>> = (0..12)
        .map(|k| {
            let t = 0.3 * k as f64;
            base.iter()
                .enumerate()
                .map(|(i, b)| b * (t + 0.1 * i as f64).cos())
                .collect()
        })
        .collect();
    // Wrong previous sets: everything on a bound, then an interior optimum, then the reverse.
    let far: Vec<f64> = (0..n)
        .map(|i| if i % 3 == 0 { 40.0 } else { -40.0 })
        .collect();
    let inner: Vec<f64> = (0..n).map(|_| rng.uniform(-0.5, 0.5) * bound).collect();
    qs.insert(4, hq(&far));
    qs.insert(5, hq(&inner));
    qs.insert(6, hq(&far));
    qs.insert(9, qs[8].iter().map(|v| -v).collect());
    let exact: Vec<Vec<f64>> = qs.iter().map(|q| certified(&h, q, &lo, &hi)).collect();
    for mode in [
        WarmStart::Previous,
        WarmStart::Shifted(nu),
        WarmStart::Point,
    ] {
        let mut s = BoxQp::new(h.as_ref(), &lo, &hi, 1000, None).unwrap();
        s.set_warm_start(mode);
        let mut u = vec![0.0; n];
        for (k, (q, want)) in qs.iter().zip(&exact).enumerate() {
            // The caller's point is a poor one (all zero) every time.
            u.fill(0.0);
            let out = s.solve(q, &[], &mut u);
            assert_eq!(out.status, QpStatus::Solved, "{mode:?} step {k}");
            let d = max_diff(&u, want);
            assert!(d <= 1e-8 * bound, "{mode:?} step {k}: |Δu| {d}");
        }
    }
    // The same QP twice: from the previous working set no change is needed at all, while the
    // caller's (zero) point needs many; after `reset` the point is used again.
    let q = &qs[2];
    let mut s = BoxQp::new(h.as_ref(), &lo, &hi, 1000, None).unwrap();
    s.set_warm_start(WarmStart::Previous);
    let first = s.solve(q, &[], &mut vec![0.0; n]).iterations;
    assert!(first > 2, "a weak test: {first} changes from the point");
    assert_eq!(
        s.working_set().count(),
        exact[2].iter().filter(|v| v.abs() == bound).count()
    );
    let mut u = vec![0.0; n];
    assert_eq!(s.solve(q, &[], &mut u).iterations, 0);
    assert!(max_diff(&u, &exact[2]) <= 1e-8 * bound);
    s.reset();
    assert_eq!(s.solve(q, &[], &mut vec![0.0; n]).iterations, first);
}

#[test]
fn larger_random_problems_match_the_kkt_certified_optimum_to_1e_8() {
    let mut rng = Rng::new(7);
    for case in 0..16 {
        let n = 20 + 8 * case;
        let h = random_spd(&mut rng, n, 1.0 + (case % 4) as f64);
        let q: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
        let bound = 0.3 + rng.uniform01();
        let (lo, hi) = (vec![-bound; n], vec![bound; n]);
        let exact = certified(&h, &q, &lo, &hi);
        let (u, status) = solve(&h, &q, &lo, &hi, &vec![0.0; n]);
        assert_eq!(status, QpStatus::Solved);
        let d = max_diff(&u, &exact);
        assert!(d <= 1e-8 * bound, "case {case} (n = {n}): |Δu| {d}");
        let on = exact.iter().filter(|v| v.abs() == bound).count();
        assert!(
            on > 0 && on < n,
            "case {case}: {on} of {n} active: weak test"
        );
    }
}

#[test]
fn degenerate_problems_all_active_none_active_ties_and_weakly_active_bounds() {
    let mut rng = Rng::new(3);
    let n = 12;
    let h = random_spd(&mut rng, n, 2.0);
    let hq = |u: &[f64]| -> Vec<f64> {
        (0..n)
            .map(|i| -(0..n).map(|j| h[(i, j)] * u[j]).sum::<f64>())
            .collect()
    };
    // All active: the unconstrained optimum far outside the box in every coordinate.
    let target: Vec<f64> = (0..n)
        .map(|i| if i % 2 == 0 { 50.0 } else { -50.0 })
        .collect();
    let (lo, hi) = (vec![-1.0; n], vec![1.0; n]);
    let exact = certified(&h, &hq(&target), &lo, &hi);
    let (u, s) = solve(&h, &hq(&target), &lo, &hi, &vec![0.0; n]);
    assert_eq!(s, QpStatus::Solved);
    assert!(max_diff(&u, &exact) <= 1e-10);
    assert!(u.iter().all(|v| v.abs() == 1.0), "all bounds active: {u:?}");
    // None active: the unconstrained optimum well inside, from a warm start on the bounds.
    let inner: Vec<f64> = (0..n).map(|_| rng.uniform(-0.5, 0.5)).collect();
    let (u, s) = solve(&h, &hq(&inner), &lo, &hi, &vec![1.0; n]);
    assert_eq!(s, QpStatus::Solved);
    assert!(max_diff(&u, &inner) <= 1e-12, "{u:?} vs {inner:?}");
    // Weakly active: the unconstrained optimum exactly on bounds (zero multipliers), from the
    // warm starts that hold them and that do not.
    let mut edge = inner.clone();
    edge[0] = 1.0;
    edge[3] = -1.0;
    edge[7] = 1.0;
    for warm in [edge.clone(), vec![0.0; n], vec![-1.0; n]] {
        let (u, s) = solve(&h, &hq(&edge), &lo, &hi, &warm);
        assert_eq!(s, QpStatus::Solved);
        assert!(max_diff(&u, &edge) <= 1e-12, "{u:?} vs {edge:?}");
    }
    // Ties: lo == hi on some variables (held there, multiplier of either sign), the same
    // bounds on many variables, and a target symmetric about zero.
    let mut lo2 = vec![-0.25; n];
    let mut hi2 = vec![0.25; n];
    for i in [2, 5, 9] {
        lo2[i] = 0.1 * i as f64;
        hi2[i] = lo2[i];
    }
    let sym: Vec<f64> = (0..n).map(|i| if i < n / 2 { 3.0 } else { -3.0 }).collect();
    let q = hq(&sym);
    let exact = certified(&h, &q, &lo2, &hi2);
    for warm in [vec![0.0; n], vec![0.25; n], exact.clone()] {
        let (u, s) = solve(&h, &q, &lo2, &hi2, &warm);
        assert_eq!(s, QpStatus::Solved);
        assert!(max_diff(&u, &exact) <= 1e-10);
        for i in [2, 5, 9] {
            assert_eq!(u[i], lo2[i]);
        }
    }
    // Bad warm starts (NaN, far outside) are sanitised, not propagated.
    let (u, s) = solve(&h, &q, &lo2, &hi2, &[f64::NAN; 12]);
    assert_eq!(s, QpStatus::Solved);
    assert!(max_diff(&u, &exact) <= 1e-10);
    let (u, _) = solve(&h, &q, &lo2, &hi2, &[1e300; 12]);
    assert!(max_diff(&u, &exact) <= 1e-10);
}

#[test]
fn hessian_changes_limits_and_bad_input() {
    let mut rng = Rng::new(9);
    let n = 30;
    let (lo, hi) = (vec![-0.2; n], vec![0.2; n]);
    let h1 = random_spd(&mut rng, n, 2.0);
    let h2 = random_spd(&mut rng, n, 3.0);
    let q: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
    let mut s = BoxQp::new(h1.as_ref(), &lo, &hi, 1000, None).unwrap();
    let mut u = vec![0.0; n];
    assert_eq!(s.solve(&q, &[], &mut u).status, QpStatus::Solved);
    assert!(max_diff(&u, &certified(&h1, &q, &lo, &hi)) <= 1e-9);
    // A new Hessian: the cached working-set factor must not be reused.
    s.set_hessian(h2.as_ref()).unwrap();
    assert_eq!(s.solve(&q, &[], &mut u).status, QpStatus::Solved);
    assert!(max_diff(&u, &certified(&h2, &q, &lo, &hi)) <= 1e-9);
    // Not positive definite: typed status, no panic; a good Hessian afterwards works again.
    let mut bad = h2.clone();
    bad[(4, 4)] = -1.0;
    s.set_hessian(bad.as_ref()).unwrap();
    assert_eq!(s.solve(&q, &[], &mut u).status, QpStatus::Numerical);
    assert!(s.set_hessian(Mat::<f64>::identity(3, 3).as_ref()).is_err());
    s.set_hessian(h1.as_ref()).unwrap();
    assert_eq!(s.solve(&q, &[], &mut u).status, QpStatus::Solved);
    assert!(BoxQp::new(bad.as_ref(), &lo, &hi, 10, None).is_err());
    assert!(BoxQp::new(h1.as_ref(), &hi, &lo, 10, None).is_err());
    // NaN in q: Numerical, never a NaN plan.
    let mut qn = q.clone();
    qn[3] = f64::NAN;
    let mut u2 = vec![0.0; n];
    assert_eq!(s.solve(&qn, &[], &mut u2).status, QpStatus::Numerical);
    // From the unconstrained optimum u* = −H⁻¹q instead of q: the same plan; bad u* is
    // Numerical.
    let hinv = s.hessian_inverse().to_vec();
    let ustar: Vec<f64> = (0..n)
        .map(|i| -(0..n).map(|j| hinv[j * n + i] * q[j]).sum::<f64>())
        .collect();
    let mut u4 = vec![0.0; n];
    assert_eq!(
        s.solve_unconstrained(&ustar, &mut u4).status,
        QpStatus::Solved
    );
    assert!(max_diff(&u4, &certified(&h1, &q, &lo, &hi)) <= 1e-9);
    let mut bad_star = ustar.clone();
    bad_star[0] = f64::INFINITY;
    assert_eq!(
        s.solve_unconstrained(&bad_star, &mut u4).status,
        QpStatus::Numerical
    );
    assert_eq!(
        s.solve_unconstrained(&ustar[1..], &mut u4).status,
        QpStatus::Numerical
    );
    // One working-set change allowed: a feasible point no worse than the warm start.
    let mut one = BoxQp::new(h1.as_ref(), &lo, &hi, 1, None).unwrap();
    let mut u3 = vec![0.0; n];
    let out = one.solve(&q, &[], &mut u3);
    assert_eq!(out.status, QpStatus::MaxIterations);
    assert!(out.feasible_iterate);
    assert!(u3.iter().all(|v| v.abs() <= 0.2));
    assert!(objective(&h1, &q, &u3) < objective(&h1, &q, &vec![0.0; n]));
}

/// A closed loop of the controller at the size of the bench's N = 34, nu = 7, H = 10 case:
/// every plan, warm-started as the controller does (the previous working set) or cold, equals the
/// certified optimum of its QP.
#[test]
fn closed_loop_plans_equal_the_certified_optimum_warm_or_cold() {
    let (nx, latent, nu, horizon) = (2, 34, 7, 10);
    let model = MatrixModel::random_stable(nx, latent, nu, 0.995, 5).unwrap();
    let bound = 0.3;
    let cfg = MpcConfig {
        horizon,
        r: Some(vec![1e-3; nu]),
        u_min: Some(vec![-bound; nu]),
        u_max: Some(vec![bound; nu]),
        ..MpcConfig::default()
    };
    let mut ctl = MpcController::new(&model, &cfg).unwrap();
    let h = ctl.condensed().hessian.clone();
    let n = horizon * nu;
    let (lo, hi) = (vec![-bound; n], vec![bound; n]);
    let mut x = vec![1.5, -1.0];
    let (mut its, mut its_cold, mut active) = (0, 0, 0);
    let steps = 40;
    for k in 0..steps {
        let reference = vec![0.5 * (0.1 * k as f64).sin(), 0.0];
        let s = ctl.solve(&x, &reference).unwrap();
        assert_eq!(s.status, SolveStatus::Solved);
        let exact = certified(&h, ctl.linear_term(), &lo, &hi);
        let d = max_diff(&s.u, &exact);
        assert!(d <= 1e-8 * bound, "step {k}: |Δu| {d}");
        if k > 0 {
            // The same QP from a cold start (fresh solver, no plan on a bound).
            let mut cold = BoxQp::new(h.as_ref(), &lo, &hi, 1000, None).unwrap();
            let mut uc = vec![0.0; n];
            let out = cold.solve(ctl.linear_term(), &[], &mut uc);
            assert_eq!(out.status, QpStatus::Solved);
            assert!(max_diff(&uc, &exact) <= 1e-8 * bound);
            its += s.iterations;
            its_cold += out.iterations;
        }
        active += s.u.iter().filter(|v| v.abs() == bound).count();
        let z = model.lift(&x);
        let (a, b) = (model.a(), model.b());
        x = (0..nx)
            .map(|i| {
                (0..latent).map(|j| a[(i, j)] * z[j]).sum::<f64>()
                    + (0..nu).map(|j| b[(i, j)] * s.u[j]).sum::<f64>()
            })
            .collect();
    }
    let frac = active as f64 / (steps * n) as f64;
    assert!(
        frac > 0.05 && frac < 0.95,
        "active fraction {frac}: weak test"
    );
    // Recorded, not asserted: on this loop (7 inputs acting on 2 states, R = 1e-3) the optimal
    // plan chatters from step to step, so the shifted previous plan's bounds are a poor first
    // working set and the unshifted previous working set a good one
    // (docs/decisions/0001-box-qp-solver.md).
    eprintln!(
        "working-set changes over {} steps: warm {its}, cold {its_cold}",
        steps - 1
    );
}
