//! The offset-free correction of the bilinear MPC on a known plant: the plant is the model plus a
//! constant unmodelled acceleration, so without the correction the closed loop settles beside
//! the target, and with it (disturbance estimate or integral action) the offset goes to ~0. Also:
//! the correction is off (plans bit-identical to the plain MPC's) outside its radius, the
//! disturbance estimate converges to the true bias, the per-step (trajectory) correction is the
//! τ-step prediction errors computed here, and bad settings are typed errors.

use koopman::model::arch::Arch;
use koopman::model::bilinear::BilinearModel;
use koopman::model::koopman::KoopmanModel;
use koopman::mpc::{
    BilinearMpc, MpcConfig, OffsetFreeConfig, OffsetMode, OneStepModel, Policy, ScpOptions,
};
use koopman::Error;

const DT: f64 = 0.05;
/// The plant's unmodelled change of ω per step (a constant acceleration of 1): holding the target
/// takes u = −1, which the model does not know.
const BIAS: [f64; 2] = [0.0, 0.05];

/// A bilinear model whose state part is a damped oscillator with a state-dependent input gain,
/// independent of the encoder: `θ⁺ = θ + DT ω`, `ω⁺ = ω + DT (−θ − 0.5 ω + (1 + 0.5 θ) u)`.
fn known_model() -> BilinearModel {
    let arch = Arch::new(2, 1, &[8, 8], 2).unwrap();
    let lay = arch.layout();
    let nn = arch.latent_dim();
    let mut p = KoopmanModel::init(arch.clone(), 5)
        .unwrap()
        .params()
        .to_vec();
    p[lay.a..lay.a + nn * nn].fill(0.0);
    p[lay.b..lay.b + nn].fill(0.0);
    let a = |p: &mut Vec<f64>, r: usize, c: usize, v: f64| p[lay.a + r * nn + c] = v;
    a(&mut p, 0, 0, 1.0);
    a(&mut p, 0, 1, DT);
    a(&mut p, 1, 0, -DT);
    a(&mut p, 1, 1, 1.0 - 0.5 * DT);
    p[lay.b + 1] = DT; // B row 1 (ω), nu = 1.
    let mut n = vec![0.0; nn * nn];
    n[nn] = 0.5 * DT; // N_1 (1, 0): the gain grows with θ.
    BilinearModel::from_parts(KoopmanModel::from_params(arch, p).unwrap(), n).unwrap()
}

fn plant(model: &BilinearModel, x: &[f64], u: &[f64]) -> Vec<f64> {
    let mut next = vec![0.0; 2];
    model.predict(x, u, &mut next);
    next.iter().zip(BIAS).map(|(v, b)| v + b).collect()
}

fn mpc(model: &BilinearModel) -> BilinearMpc<'_> {
    let cfg = MpcConfig {
        // R = 0 (SPEC's setting): with the bias known, holding the target costs nothing.
        horizon: 10,
        ..MpcConfig::with_bounds(vec![-3.0], vec![3.0])
    };
    BilinearMpc::new(model, &cfg, ScpOptions::default()).unwrap()
}

/// The correction on both components (disturbance) or on the angle only (integral: integrating
/// the rate error would only integrate the angle's change).
fn offset(mode: OffsetMode, gain: f64) -> OffsetFreeConfig {
    let gain = match mode {
        OffsetMode::Disturbance | OffsetMode::Trajectory => vec![gain, gain],
        OffsetMode::Integral => vec![gain, 0.0],
    };
    OffsetFreeConfig {
        mode,
        radius: 0.5,
        gain,
        angles: vec![0],
    }
}

/// Runs the closed loop on the plant from `x0` to 0; returns the states and the inputs.
fn closed_loop(mpc: &mut BilinearMpc<'_>, steps: usize) -> (Vec<Vec<f64>>, Vec<Vec<f64>>) {
    let model = known_model();
    let (mut xs, mut us) = (vec![vec![1.0, 0.0]], Vec::new());
    let r = [0.0, 0.0];
    for _ in 0..steps {
        let x = xs.last().unwrap().clone();
        let a = mpc.act(&x, &r, &r).unwrap();
        assert!(a.u.iter().all(|v| v.is_finite() && v.abs() <= 3.0));
        xs.push(plant(&model, &x, &a.u));
        us.push(a.u);
    }
    (xs, us)
}

fn norm(x: &[f64]) -> f64 {
    x.iter().map(|v| v * v).sum::<f64>().sqrt()
}

#[test]
fn without_the_correction_the_bias_leaves_an_offset_and_with_it_the_offset_goes_to_zero() {
    let model = known_model();
    let mut plain = mpc(&model);
    let (xs, _) = closed_loop(&mut plain, 600);
    let plain_end = norm(xs.last().unwrap());
    // The offset is steady: the same at 500 and 600 steps.
    assert!(
        plain_end > 0.01,
        "no offset without the correction: {plain_end}"
    );
    assert!((norm(&xs[500]) - plain_end).abs() < 1e-3 * plain_end);
    // The integrator's loop is as slow as the closed loop it wraps (time constant ~1 s = 20
    // steps here), so it gets more steps; the disturbance estimate is exact for this plant.
    let cases = [
        (OffsetMode::Disturbance, 0.3, 600),
        (OffsetMode::Integral, 0.05, 2000),
        (OffsetMode::Trajectory, 0.5, 600),
    ];
    for (mode, gain, steps) in cases {
        let mut m = mpc(&model);
        m.set_offset_free(Some(offset(mode, gain))).unwrap();
        let (xs, us) = closed_loop(&mut m, steps);
        let end = norm(xs.last().unwrap());
        assert!(end < 1e-4, "{mode:?}: offset {end} (plain {plain_end})");
        // It holds the target with the input that cancels the bias: (1 + 0.5·0) u DT = −0.05.
        let u = us.last().unwrap()[0];
        assert!(
            (u + BIAS[1] / DT).abs() < 1e-3,
            "{mode:?}: holding input {u}"
        );
        if mode == OffsetMode::Disturbance {
            // The estimate is the true bias (the plant is the model plus it).
            let d = m.offset_free().unwrap().estimate();
            assert!(
                (d[0] - BIAS[0]).abs() < 1e-6 && (d[1] - BIAS[1]).abs() < 1e-6,
                "{d:?}"
            );
        }
    }
}

#[test]
fn outside_the_radius_the_correction_is_off_and_the_plans_are_the_plain_ones() {
    let model = known_model();
    let mut plain = mpc(&model);
    let mut corrected = mpc(&model);
    corrected
        .set_offset_free(Some(OffsetFreeConfig {
            radius: 0.2,
            ..offset(OffsetMode::Integral, 0.05)
        }))
        .unwrap();
    let r = [0.0, 0.0];
    let mut x = vec![1.0, 0.0];
    let (mut inside, mut entered) = (0, false);
    for k in 0..600 {
        let a = plain.act(&x, &r, &r).unwrap();
        let b = corrected.act(&x, &r, &r).unwrap();
        let on = corrected.offset_free().unwrap().active();
        assert_eq!(on, norm(&x) <= 0.2, "step {k}");
        if !on {
            assert!(corrected
                .offset_free()
                .unwrap()
                .estimate()
                .iter()
                .all(|&v| v == 0.0));
        }
        entered |= on;
        if !entered {
            // Until the first entry both controllers see the same states and warm starts.
            assert_eq!(
                a.u, b.u,
                "step {k}: the correction acted outside its radius"
            );
        }
        inside += usize::from(on);
        x = plant(&model, &x, &b.u);
    }
    assert!(inside > 20, "the state never came within the radius");
    assert!(
        norm(&x) < 1e-3,
        "the corrected loop did not settle at the target: {x:?}"
    );
}

#[test]
fn reset_forgets_the_estimate() {
    let model = known_model();
    let mut m = mpc(&model);
    m.set_offset_free(Some(offset(OffsetMode::Integral, 0.2)))
        .unwrap();
    closed_loop(&mut m, 60);
    assert!(m.offset_free().unwrap().estimate()[0] != 0.0);
    m.reset();
    assert!(m
        .offset_free()
        .unwrap()
        .estimate()
        .iter()
        .all(|&v| v == 0.0));
    assert!(!m.offset_free().unwrap().active());
}

#[test]
fn bad_offset_free_settings_are_typed_errors() {
    let model = known_model();
    let mut m = mpc(&model);
    let bad = [
        OffsetFreeConfig {
            gain: vec![0.1],
            ..offset(OffsetMode::Integral, 0.1)
        },
        OffsetFreeConfig {
            radius: 0.0,
            ..offset(OffsetMode::Integral, 0.1)
        },
        OffsetFreeConfig {
            radius: f64::NAN,
            ..offset(OffsetMode::Integral, 0.1)
        },
        offset(OffsetMode::Disturbance, 1.5),
        offset(OffsetMode::Integral, -0.1),
        offset(OffsetMode::Integral, f64::INFINITY),
        OffsetFreeConfig {
            angles: vec![2],
            ..offset(OffsetMode::Integral, 0.1)
        },
    ];
    for cfg in bad {
        let e = m.set_offset_free(Some(cfg.clone()));
        assert!(
            matches!(
                e,
                Err(Error::Dimension { .. }) | Err(Error::InvalidArgument(_))
            ),
            "{cfg:?}: {e:?}"
        );
    }
    // A good one is accepted, and a bad state is still a typed error with it on.
    m.set_offset_free(Some(offset(OffsetMode::Disturbance, 0.2)))
        .unwrap();
    assert!(matches!(
        m.act(&[f64::NAN, 0.0], &[0.0, 0.0], &[0.0, 0.0]),
        Err(Error::NonFinite(_))
    ));
    assert!(m.act(&[0.1, 0.0], &[0.0, 0.0], &[0.0, 0.0]).is_ok());
}

/// With α = 1 the trajectory correction is exactly the error of each τ-step prediction of the
/// last H decisions, recomputed here by stepping the model's one-step prediction τ times from
/// the state measured τ steps ago with the inputs applied since (the known model ignores its
/// encoder, so a latent rollout and repeated one-step predictions agree).
#[test]
fn the_trajectory_correction_is_the_error_of_each_tau_step_prediction() {
    let model = known_model();
    let mut m = mpc(&model);
    m.set_offset_free(Some(OffsetFreeConfig {
        radius: f64::INFINITY,
        ..offset(OffsetMode::Trajectory, 1.0)
    }))
    .unwrap();
    let (xs, us) = closed_loop(&mut m, 30);
    // The last `act` observed xs[29] (the state it acted on) with the decisions 19..28 recorded.
    let k = 29;
    let hz = m.horizon();
    let e = m.offset_free().unwrap().estimate().to_vec();
    assert_eq!(e.len(), hz * 2);
    for tau in 1..=hz {
        let mut x = xs[k - tau].clone();
        for u in &us[k - tau..k] {
            let mut next = vec![0.0; 2];
            model.predict(&x, u, &mut next);
            x = next;
        }
        for i in 0..2 {
            let want = xs[k][i] - x[i];
            let got = e[(tau - 1) * 2 + i];
            assert!(
                (got - want).abs() < 1e-12,
                "tau {tau}, component {i}: {got} vs {want}"
            );
        }
    }
    // A bias of 0.05 per step on ω: the τ-step error grows with τ (it is not one constant).
    assert!(e[(hz - 1) * 2 + 1].abs() > 2.0 * e[1].abs(), "{e:?}");
}
