//! Tests of the MPC service's LQR law ([`lqr_law::LqrLaw`], `MpcConfig::law = lqr`) against an
//! independent computation: the unconstrained error-state MPC over a long horizon, whose first
//! input about a plan is the LQR law's; the clamp to the bounds; what it refuses.

use std::sync::Arc;

use super::*;
use crate::model::matrix::MatrixModel;
use crate::model::LiftedModel;

fn setup() -> (Arc<dyn LiftedModel>, MpcConfig) {
    let model = MatrixModel::random_stable(2, 8, 2, 0.97, 21).unwrap();
    let cfg = MpcConfig {
        horizon: 4,
        q: Some(vec![1.0, 2.0]),
        r: Some(vec![0.1, 0.05]),
        regularization: 0.0,
        law: ControlLaw::Lqr,
        ..MpcConfig::default()
    };
    (Arc::new(model), cfg)
}

#[test]
fn about_a_plan_it_is_the_long_horizon_error_state_mpc_plus_its_feed_forward() {
    let (model, cfg) = setup();
    let loaded = LoadedModel::Lifted(model.clone());
    let mut lqr = loaded.controller(&cfg, None).unwrap();
    assert_eq!(lqr.kind(), "lifted-linear (LQR law)");
    assert!(lqr.takes_feedforward());
    let (x, r_now) = ([0.7, -0.4], [0.2, 0.1]);
    let ff = [0.3, -0.6, 0.1, 0.2, 0.0, 0.0, -0.1, 0.4];
    let plan = lqr.solve_about_plan(&x, &r_now, &ff).unwrap();
    assert_eq!(plan.u.len(), 8);
    assert_eq!(
        &plan.u[2..],
        &ff[2..],
        "the plan's later inputs are the feed-forward's"
    );
    // Independent: the unconstrained error-state MPC over 300 steps with a zero feed-forward
    // after the first (a plan that rests): its first deviation input is −K δz.
    let long = MpcConfig {
        horizon: 300,
        law: ControlLaw::Mpc,
        ..cfg.clone()
    };
    let mut mpc = loaded.controller(&long, None).unwrap();
    let mut ff_long = vec![0.0; 600];
    ff_long[..2].copy_from_slice(&ff[..2]);
    let batch = mpc.solve_about_plan(&x, &r_now, &ff_long).unwrap();
    for i in 0..2 {
        assert!(
            (plan.u[i] - batch.u[i]).abs() < 1e-7,
            "u[{i}]: LQR law {} vs long-horizon error-state MPC {}",
            plan.u[i],
            batch.u[i]
        );
    }
    // The gain is computed once: the same state gives the same input.
    assert_eq!(lqr.solve_about_plan(&x, &r_now, &ff).unwrap().u, plan.u);
}

#[test]
fn its_inputs_are_clamped_and_bad_requests_refused() {
    let (model, mut cfg) = setup();
    cfg.u_min = Some(vec![-0.01, -0.01]);
    cfg.u_max = Some(vec![0.01, 0.01]);
    let mut lqr = LoadedModel::Lifted(model).controller(&cfg, None).unwrap();
    let plan = lqr.solve(&[3.0, -2.0], &[0.0, 0.0]).unwrap();
    assert_eq!(plan.u.len(), 8);
    assert!(plan.u.iter().all(|u| u.abs() <= 0.01), "{:?}", plan.u);
    assert!(
        plan.u.iter().any(|u| u.abs() == 0.01),
        "far from the reference it saturates"
    );
    assert!(lqr.solve(&[f64::NAN, 0.0], &[0.0, 0.0]).is_err());
    assert!(lqr.solve(&[0.0, 0.0], &[0.0; 3]).is_err());
    assert!(lqr
        .solve_about_plan(&[0.0, 0.0], &[0.0, 0.0], &[0.0; 3])
        .is_err());
    // The MPC itself refuses the law it does not implement (no silent MPC in its place).
    let (model, cfg) = setup();
    assert!(MpcController::from_shared(model, &cfg).is_err());
    // Only a lifted-linear model, and no offset-free correction.
    let (model, cfg) = setup();
    let loaded = LoadedModel::Lifted(model);
    let of = OffsetFreeConfig::defaults(super::offset_free::OffsetMode::Integral, 2, vec![]);
    assert!(loaded.controller(&cfg, Some(&of)).is_err());
}
