//! The offset-free correction of the linear Koopman MPC on a known plant: the plant is the
//! model plus a constant input bias, so without the correction the closed loop settles at the
//! offset the MPC's linear law gives in closed form, and with it (disturbance estimate, integral
//! action or the per-step trajectory correction) the offset goes to ~0. Also: the disturbance
//! estimate converges to the true bias, the correction is off (plans bit-identical to the plain
//! MPC's) outside its radius, and the error-state MPC refuses it.

use faer::linalg::solvers::DenseSolveCore;
use faer::Mat;
use koopman::model::matrix::MatrixModel;
use koopman::mpc::{MpcConfig, MpcController, OffsetFreeConfig, OffsetMode, Policy};
use koopman::Error;

/// The plant's unmodelled input: it applies `u + BIAS` (holding the origin takes `u = −BIAS`).
const BIAS: f64 = 0.3;

/// A cart with friction, `p⁺ = p + 0.1 v + 0.005 u`, `v⁺ = 0.95 v + 0.1 u`: the model, lift-free.
fn matrices() -> (Mat<f64>, Mat<f64>) {
    let a = Mat::from_fn(2, 2, |i, j| [[1.0, 0.1], [0.0, 0.95]][i][j]);
    let b = Mat::from_fn(2, 1, |i, _| [0.005, 0.1][i]);
    (a, b)
}

fn model() -> MatrixModel {
    let (a, b) = matrices();
    MatrixModel::linear(a, b).unwrap()
}

fn plant(x: &[f64], u: f64) -> Vec<f64> {
    let (a, b) = matrices();
    (0..2)
        .map(|i| a[(i, 0)] * x[0] + a[(i, 1)] * x[1] + b[(i, 0)] * (u + BIAS))
        .collect()
}

fn mpc(model: &MatrixModel) -> MpcController<'_> {
    let cfg = MpcConfig {
        horizon: 20,
        // R = 0 (SPEC's setting): with the bias known, holding the target costs nothing (an input
        // weight would trade a small offset for a smaller input).
        q: Some(vec![10.0, 1.0]),
        ..MpcConfig::with_bounds(vec![-3.0], vec![3.0])
    };
    MpcController::new(model, &cfg).unwrap()
}

fn offset(mode: OffsetMode) -> OffsetFreeConfig {
    let gain = match mode {
        OffsetMode::Disturbance | OffsetMode::Trajectory => vec![0.5, 0.5],
        // Integral action on the position only (integrating v would integrate p's change).
        OffsetMode::Integral => vec![0.05, 0.0],
    };
    OffsetFreeConfig {
        mode,
        radius: f64::INFINITY,
        gain,
        angles: Vec::new(),
    }
}

/// The closed loop on the plant from (0.2, 0) to the origin through [`Policy::act`]; the states.
fn closed_loop(c: &mut MpcController<'_>, steps: usize) -> Vec<Vec<f64>> {
    let mut xs = vec![vec![0.2, 0.0]];
    for _ in 0..steps {
        let x = xs.last().unwrap().clone();
        let a = c.act(&x, &[0.0, 0.0], &[0.0, 0.0]).unwrap();
        assert!(!a.fallback, "step {}: the fallback plan", xs.len());
        xs.push(plant(&x, a.u[0]));
    }
    xs
}

/// The offset of the uncorrected loop in closed form: away from the bounds the MPC is the linear
/// law `u = K x` (K = the first row of `−H⁻¹ M1`), and the plant settles where
/// `x = A x + B (K x + BIAS)`, i.e. `x = (I − A − B K)⁻¹ B BIAS`.
fn closed_form_offset(c: &MpcController<'_>) -> Vec<f64> {
    let cd = c.condensed();
    let k = -(cd.hessian.partial_piv_lu().inverse() * &cd.m1);
    let (a, b) = matrices();
    let m = Mat::<f64>::identity(2, 2) - &a - &b * k.subrows(0, 1);
    let x = m.partial_piv_lu().inverse() * &b * faer::Scale(BIAS);
    vec![x[(0, 0)], x[(1, 0)]]
}

#[test]
fn without_the_correction_the_loop_settles_at_the_closed_form_offset() {
    let m = model();
    let mut c = mpc(&m);
    let xs = closed_loop(&mut c, 600);
    let expected = closed_form_offset(&c);
    let last = xs.last().unwrap();
    assert!(
        expected[0].abs() > 0.01,
        "no offset to correct: {expected:?}"
    );
    for i in 0..2 {
        assert!(
            (last[i] - expected[i]).abs() < 1e-6 * (1.0 + expected[i].abs()),
            "{last:?} vs the closed form {expected:?}"
        );
    }
    assert_eq!(c.name(), "koopman-mpc/dedicated");
}

#[test]
fn every_correction_removes_the_offset() {
    let m = model();
    let plain = closed_form_offset(&mpc(&m));
    for mode in [
        OffsetMode::Disturbance,
        OffsetMode::Integral,
        OffsetMode::Trajectory,
    ] {
        let mut c = mpc(&m);
        c.set_offset_free(Some(offset(mode))).unwrap();
        let xs = closed_loop(&mut c, 600);
        let last = xs.last().unwrap();
        assert!(
            last[0].abs() < 1e-6 && last[0].abs() < 1e-4 * plain[0].abs(),
            "{mode:?}: position {} (without the correction {})",
            last[0],
            plain[0]
        );
        assert!(last[1].abs() < 1e-6, "{mode:?}: velocity {}", last[1]);
        assert!(
            c.name().starts_with("koopman-mpc/dedicated+"),
            "{}",
            c.name()
        );
    }
}

#[test]
fn the_disturbance_estimate_is_the_bias_and_state_bounds_see_it() {
    let m = model();
    // Clarabel with state bounds that do not bind: the same loop as the dedicated solver's.
    let cfg = MpcConfig {
        solver: koopman::mpc::SolverKind::Clarabel,
        x_min: Some(vec![-5.0, -5.0]),
        x_max: Some(vec![5.0, 5.0]),
        // Clarabel fails numerically on the nearly singular Hessian of R = 0 (at R = 1e-6 too).
        r: Some(vec![1e-3]),
        ..mpc(&m).config().clone()
    };
    for cfg in [mpc(&m).config().clone(), cfg] {
        let mut c = MpcController::new(&m, &cfg).unwrap();
        c.set_offset_free(Some(offset(OffsetMode::Disturbance)))
            .unwrap();
        let xs = closed_loop(&mut c, 600);
        assert!(xs.last().unwrap()[0].abs() < 1e-6, "{:?}", cfg.solver);
        let d = c.offset_free().unwrap().estimate();
        // The plant is the model plus B·BIAS on the state: the one-step error.
        assert!((d[0] - 0.005 * BIAS).abs() < 1e-9, "{d:?}");
        assert!((d[1] - 0.1 * BIAS).abs() < 1e-9, "{d:?}");
    }
}

#[test]
fn outside_the_radius_the_plans_are_the_plain_mpcs() {
    let m = model();
    let (mut plain, mut corrected) = (mpc(&m), mpc(&m));
    let mut cfg = offset(OffsetMode::Disturbance);
    cfg.radius = 0.01;
    corrected.set_offset_free(Some(cfg)).unwrap();
    let mut x = vec![0.2, 0.0];
    for _ in 0..5 {
        let a = plain.act(&x, &[0.0, 0.0], &[0.0, 0.0]).unwrap();
        let b = corrected.act(&x, &[0.0, 0.0], &[0.0, 0.0]).unwrap();
        assert_eq!(a.u, b.u);
        assert!(!corrected.offset_free().unwrap().active());
        x = plant(&x, a.u[0]);
    }
}

#[test]
fn bad_settings_and_the_error_state_mpc_are_typed_errors() {
    let m = model();
    let mut c = mpc(&m);
    let mut bad = offset(OffsetMode::Disturbance);
    bad.gain = vec![0.5];
    assert!(matches!(
        c.set_offset_free(Some(bad)),
        Err(Error::Dimension { .. })
    ));
    c.set_offset_free(Some(offset(OffsetMode::Integral)))
        .unwrap();
    let ff = vec![0.0; c.horizon()];
    assert!(matches!(
        c.solve_about_plan(&[0.0, 0.0], &[0.0, 0.0], &ff),
        Err(Error::InvalidArgument(_))
    ));
    c.set_offset_free(None).unwrap();
    c.solve_about_plan(&[0.0, 0.0], &[0.0, 0.0], &ff).unwrap();
}
