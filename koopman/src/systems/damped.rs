//! The damped pendulum of SPEC.md: `θ̈ = −(g/l) sin θ − (b l/m) θ̇ + cos θ · u/(m l)`, dt = 0.02.

use super::integrator::{dopri5, Tolerance};
use super::system::System;
use crate::rng::Rng;
use std::f64::consts::PI;

/// Damped pendulum with g = 9.8 and l = m = b = 1; state `[θ, θ̇]`, input `[u]`.
#[derive(Clone, Debug)]
pub struct DampedPendulum {
    /// Gravity g.
    pub g: f64,
    /// Length l.
    pub l: f64,
    /// Mass m.
    pub m: f64,
    /// Damping b.
    pub b: f64,
    /// Integrator tolerances.
    pub tol: Tolerance,
}

impl Default for DampedPendulum {
    fn default() -> Self {
        DampedPendulum {
            g: 9.8,
            l: 1.0,
            m: 1.0,
            b: 1.0,
            tol: Tolerance::TIGHT,
        }
    }
}

impl DampedPendulum {
    /// The continuous-time vector field `ẋ = f(x, u)`.
    pub fn rhs(&self, x: &[f64; 2], u: f64) -> [f64; 2] {
        let (th, om) = (x[0], x[1]);
        [
            om,
            -self.g / self.l * th.sin() - self.b * self.l / self.m * om
                + th.cos() * u / (self.m * self.l),
        ]
    }

    /// Mechanical energy per unit of `m l²` scaling: `½ m l² θ̇² + m g l (1 − cos θ)`.
    pub fn energy(&self, x: &[f64]) -> f64 {
        0.5 * self.m * self.l * self.l * x[1] * x[1] + self.m * self.g * self.l * (1.0 - x[0].cos())
    }
}

impl System for DampedPendulum {
    fn name(&self) -> &str {
        "damped-pendulum"
    }
    fn nx(&self) -> usize {
        2
    }
    fn nu(&self) -> usize {
        1
    }
    fn dt(&self) -> f64 {
        0.02
    }
    fn state_names(&self) -> Vec<String> {
        vec!["theta".into(), "theta_dot".into()]
    }
    fn input_names(&self) -> Vec<String> {
        vec!["u".into()]
    }
    fn input_bounds(&self) -> (Vec<f64>, Vec<f64>) {
        (vec![-8.0], vec![8.0])
    }
    fn angle_indices(&self) -> Vec<usize> {
        vec![0]
    }
    fn window_steps(&self) -> usize {
        15
    }
    fn sample_initial_state(&self, rng: &mut Rng) -> Vec<f64> {
        vec![rng.uniform(-2.0 * PI, 2.0 * PI), rng.uniform(-8.0, 8.0)]
    }
    fn step(&self, x: &[f64], u: &[f64], x_next: &mut [f64]) {
        let u0 = u[0];
        let (y, _) = dopri5(|s| self.rhs(s, u0), [x[0], x[1]], self.dt(), self.tol);
        x_next.copy_from_slice(&y);
    }
}

#[cfg(test)]
mod tests {
    use super::super::integrator::rk4_fixed;
    use super::*;

    #[test]
    fn one_step_matches_fine_rk4_and_tighter_dopri() {
        let p = DampedPendulum::default();
        let mut rng = Rng::new(3);
        for _ in 0..50 {
            let x = p.sample_initial_state(&mut rng);
            let u = p.sample_input(&mut rng);
            let mut y = [0.0; 2];
            p.step(&x, &u, &mut y);
            let fine = rk4_fixed(|s| p.rhs(s, u[0]), [x[0], x[1]], 0.02, 4000);
            let tighter = dopri5(
                |s| p.rhs(s, u[0]),
                [x[0], x[1]],
                0.02,
                Tolerance {
                    rtol: 1e-14,
                    atol: 1e-15,
                },
            )
            .0;
            for i in 0..2 {
                assert!((y[i] - fine[i]).abs() < 1e-10, "{y:?} vs rk4 {fine:?}");
                assert!((y[i] - tighter[i]).abs() < 1e-10, "{y:?} vs {tighter:?}");
            }
            // And the step really moved the state (the test is not comparing x with itself).
            assert!((y[1] - x[1]).abs() > 1e-6);
        }
    }

    #[test]
    fn unforced_energy_decays_by_the_damping_work() {
        // dE/dt = −b l² θ̇² (m = 1): E(t+dt) − E(t) = −b l² ∫ θ̇² dt, checked step by step with
        // Simpson's rule on a midpoint from a half step.
        let p = DampedPendulum::default();
        let mut x = vec![2.5, 3.0];
        let mut e = p.energy(&x);
        for _ in 0..300 {
            let mut y = vec![0.0; 2];
            p.step(&x, &[0.0], &mut y);
            let mid = dopri5(|s| p.rhs(s, 0.0), [x[0], x[1]], 0.01, Tolerance::TIGHT).0;
            let work =
                p.b * p.l * p.l * 0.02 / 6.0 * (x[1] * x[1] + 4.0 * mid[1] * mid[1] + y[1] * y[1]);
            let e1 = p.energy(&y);
            assert!(e1 <= e + 1e-12, "energy grew: {e} → {e1}");
            assert!(
                (e - e1 - work).abs() < 1e-5 * work.max(1e-3),
                "ΔE {} vs work {work}",
                e - e1
            );
            x = y;
            e = e1;
        }
        assert!(e < 0.2, "damped pendulum did not settle: E = {e}");
    }

    #[test]
    fn hanging_equilibrium_is_fixed_and_input_pushes_the_right_way() {
        let p = DampedPendulum::default();
        let mut y = [0.0; 2];
        p.step(&[0.0, 0.0], &[0.0], &mut y);
        assert!(y[0].abs() < 1e-15 && y[1].abs() < 1e-15);
        p.step(&[0.0, 0.0], &[8.0], &mut y);
        // For small times θ̇ ≈ u t (cos 0 = 1).
        assert!(y[1] > 0.14 && y[1] < 0.16, "{y:?}");
    }
}
