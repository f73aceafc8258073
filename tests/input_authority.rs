//! The input authority of the control diagnosis (bridge::orchestrator::authority): the
//! simulator's one-step input gain measured through a real adapter (`koopbridge sim`, the damped
//! pendulum) against the closed form of its linearisation, and the comparison that tells a
//! deliberately wrong model gain from a right one.

mod common;

use bridge::client::SimClient;
use bridge::orchestrator::authority::measure_sim_gain;
use koopman::analysis::{gain_agreement, InputGain};

/// The damped pendulum (g = 9.8, b = 1, m = l = 1, dt = 0.02) held at rest at `theta` by
/// `u0 = g tan θ`: its one-step gain is `∫₀^dt e^{J s} ds · [0, cos θ]ᵀ` with
/// `J = [[0, 1], [−g / cos θ, −b]]` (the exponential by its series).
fn closed_form(theta: f64) -> [f64; 2] {
    let (g, b, dt) = (9.8, 1.0, 0.02);
    let j = [[0.0, 1.0], [-g / theta.cos(), -b]];
    // Σ_k J^k dt^{k+1} / (k+1)! applied to B.
    let mut term = [0.0, theta.cos() * dt]; // J^0 B dt
    let mut sum = term;
    for k in 1..30 {
        let t = [
            j[0][0] * term[0] + j[0][1] * term[1],
            j[1][0] * term[0] + j[1][1] * term[1],
        ];
        let f = dt / (k as f64 + 1.0);
        term = [t[0] * f, t[1] * f];
        sum = [sum[0] + term[0], sum[1] + term[1]];
    }
    sum
}

#[test]
fn the_measured_gain_matches_the_closed_form_and_tells_a_wrong_model() {
    let (c, _opts, _s) = common::cluster("authority", &[("p", "damped-pendulum")], &[]);
    let mut sim = SimClient::connect(&c.client, "p", common::READY).unwrap();
    for theta in [0.3, 2.5] {
        let u0 = 9.8 * f64::tan(theta);
        let g = measure_sim_gain(&mut sim, &[theta, 0.0], &[u0], &[1e-3]).unwrap();
        let m = &g.gains[0];
        let want = closed_form(theta);
        for i in 0..2 {
            assert!(
                (m[(i, 0)] - want[i]).abs() <= 1e-6 * want[1].abs().max(1e-3),
                "θ = {theta}: state {i} gain {} vs closed form {}",
                m[(i, 0)],
                want[i]
            );
        }
        // The sign follows cos θ.
        assert_eq!(m[(1, 0)] > 0.0, theta.cos() > 0.0);
        // A model with the right gain agrees; one with −0.007× (rust-pend's over the full
        // circle) projects negative: what the diagnosis names as the wrong sign.
        let scaled = |k: f64| {
            let mut s: InputGain = g.clone();
            for r in 0..2 {
                s.gains[0][(r, 0)] *= k;
            }
            s
        };
        let right = gain_agreement(&scaled(1.0), &g).unwrap();
        assert!((right.projection - 1.0).abs() < 1e-12 && right.cosine > 0.999_999);
        let wrong = gain_agreement(&scaled(-0.007), &g).unwrap();
        assert!((wrong.projection + 0.007).abs() < 1e-12 && wrong.cosine < -0.999_999);
        assert!(wrong.projection < koopman::analysis::gain::WEAK_AUTHORITY);
    }
}

/// `e^{J dt}` of the damped pendulum held at rest at `theta` (the series; see [`closed_form`]).
fn state_transition(theta: f64) -> [[f64; 2]; 2] {
    let (g, b, dt) = (9.8, 1.0, 0.02);
    let j = [[0.0, 1.0], [-g / theta.cos(), -b]];
    let mul = |a: [[f64; 2]; 2], c: [[f64; 2]; 2]| {
        let mut m = [[0.0; 2]; 2];
        for (i, row) in m.iter_mut().enumerate() {
            for (k, v) in row.iter_mut().enumerate() {
                *v = a[i][0] * c[0][k] + a[i][1] * c[1][k];
            }
        }
        m
    };
    let mut term = [[1.0, 0.0], [0.0, 1.0]];
    let mut sum = term;
    for k in 1..30 {
        term = mul(term, j);
        let f = dt / k as f64;
        term = [
            [term[0][0] * f, term[0][1] * f],
            [term[1][0] * f, term[1][1] * f],
        ];
        for i in 0..2 {
            for c in 0..2 {
                sum[i][c] += term[i][c];
            }
        }
    }
    sum
}

#[test]
fn the_measured_state_jacobian_matches_the_closed_form_and_tells_an_unstable_goal() {
    use bridge::orchestrator::growth::{measure_state_jacobian, UNSTABLE_RADIUS};
    let (c, _opts, _s) = common::cluster("growth", &[("p", "damped-pendulum")], &[]);
    let mut sim = SimClient::connect(&c.client, "p", common::READY).unwrap();
    for theta in [0.3, std::f64::consts::PI] {
        let u0 = 9.8 * f64::tan(theta);
        let j = measure_state_jacobian(&mut sim, &[theta, 0.0], &[u0]).unwrap();
        let want = state_transition(theta);
        for (r, row) in want.iter().enumerate() {
            for (k, w) in row.iter().enumerate() {
                assert!(
                    (j[(r, k)] - w).abs() <= 1e-5,
                    "θ = {theta}: ∂x⁺_{r}/∂x_{k} {} vs closed form {w}",
                    j[(r, k)]
                );
            }
        }
        // Upright (θ = π) grows e^{2.67·0.02} = 1.055× per step; hanging at 0.3 rad it decays.
        let ev = koopman::analysis::conditioning::eigenvalues(j.as_ref()).unwrap();
        let rho = ev.iter().map(|z| z.norm()).fold(0.0, f64::max);
        assert_eq!(
            rho >= UNSTABLE_RADIUS,
            theta > 3.0,
            "θ = {theta}: ρ = {rho}"
        );
    }
}
