//! The double pendulum of SPEC.md: `θ̈ = M(θ)⁻¹ (τ − C(θ, θ̇) − G(θ))`, dt = 0.01, no damping.

use super::integrator::{dopri5, Tolerance};
use super::system::System;
use crate::rng::Rng;
use std::f64::consts::PI;

/// Double pendulum with g = 9.8 and all lengths and masses 1; state `[θ1, θ2, θ̇1, θ̇2]`, inputs
/// the joint torques `[τ1, τ2]`. Angles follow SPEC.md's convention (gravity terms in cos θ).
#[derive(Clone, Debug)]
pub struct DoublePendulum {
    /// Gravity g.
    pub g: f64,
    /// Link lengths l1, l2.
    pub l: [f64; 2],
    /// Link masses m1, m2.
    pub m: [f64; 2],
    /// Integrator tolerances.
    pub tol: Tolerance,
}

impl Default for DoublePendulum {
    fn default() -> Self {
        DoublePendulum {
            g: 9.8,
            l: [1.0, 1.0],
            m: [1.0, 1.0],
            tol: Tolerance::TIGHT,
        }
    }
}

impl DoublePendulum {
    /// The mass matrix `[M11, M12, M22]` (symmetric) at joint angle θ2.
    pub fn mass_matrix(&self, th2: f64) -> [f64; 3] {
        let ([l1, l2], [m1, m2]) = (self.l, self.m);
        let c2 = th2.cos();
        [
            m1 * l1 * l1 + m2 * (l1 * l1 + 2.0 * l1 * l2 * c2 + l2 * l2),
            m2 * (l1 * l2 * c2 + l2 * l2),
            m2 * l2 * l2,
        ]
    }

    /// The continuous-time vector field `ẋ = f(x, τ)`, solving the 2×2 system exactly (Cramer).
    pub fn rhs(&self, x: &[f64; 4], tau: [f64; 2]) -> [f64; 4] {
        let ([l1, l2], [m1, m2], g) = (self.l, self.m, self.g);
        let [th1, th2, d1, d2] = *x;
        let s2 = th2.sin();
        let [m11, m12, m22] = self.mass_matrix(th2);
        let c1 = -m2 * l1 * l2 * s2 * (2.0 * d1 * d2 + d2 * d2);
        let c2 = m2 * l1 * l2 * d1 * d1 * s2;
        let c12 = (th1 + th2).cos();
        let g1 = (m1 + m2) * l1 * g * th1.cos() + m2 * l2 * g * c12;
        let g2 = m2 * l2 * g * c12;
        let r1 = tau[0] - c1 - g1;
        let r2 = tau[1] - c2 - g2;
        // det = M11 M22 − M12² > 0 for any θ2 (the mass matrix is positive definite).
        let det = m11 * m22 - m12 * m12;
        [
            d1,
            d2,
            (m22 * r1 - m12 * r2) / det,
            (m11 * r2 - m12 * r1) / det,
        ]
    }

    /// Total energy `½ θ̇ᵀ M θ̇ + V` with the potential `V` whose gradient is SPEC's G.
    pub fn energy(&self, x: &[f64]) -> f64 {
        let ([l1, l2], [m1, m2], g) = (self.l, self.m, self.g);
        let [m11, m12, m22] = self.mass_matrix(x[1]);
        let kin = 0.5 * (m11 * x[2] * x[2] + 2.0 * m12 * x[2] * x[3] + m22 * x[3] * x[3]);
        let pot = (m1 + m2) * l1 * g * x[0].sin() + m2 * l2 * g * (x[0] + x[1]).sin();
        kin + pot
    }
}

impl System for DoublePendulum {
    fn name(&self) -> &str {
        "double-pendulum"
    }
    fn nx(&self) -> usize {
        4
    }
    fn nu(&self) -> usize {
        2
    }
    fn dt(&self) -> f64 {
        0.01
    }
    fn state_names(&self) -> Vec<String> {
        ["theta1", "theta2", "theta1_dot", "theta2_dot"]
            .map(String::from)
            .to_vec()
    }
    fn input_names(&self) -> Vec<String> {
        vec!["tau1".into(), "tau2".into()]
    }
    fn input_bounds(&self) -> (Vec<f64>, Vec<f64>) {
        (vec![-6.0, -6.0], vec![6.0, 6.0])
    }
    fn angle_indices(&self) -> Vec<usize> {
        vec![0, 1]
    }
    fn window_steps(&self) -> usize {
        15
    }
    fn sample_initial_state(&self, rng: &mut Rng) -> Vec<f64> {
        vec![
            rng.uniform(-0.1 * PI, 0.1 * PI),
            rng.uniform(-0.1 * PI, 0.1 * PI),
            rng.uniform(-1.0, 1.0),
            rng.uniform(-1.0, 1.0),
        ]
    }
    fn step(&self, x: &[f64], u: &[f64], x_next: &mut [f64]) {
        let tau = [u[0], u[1]];
        let (y, _) = dopri5(
            |s| self.rhs(s, tau),
            [x[0], x[1], x[2], x[3]],
            self.dt(),
            self.tol,
        );
        x_next.copy_from_slice(&y);
    }
}

#[cfg(test)]
mod tests {
    use super::super::integrator::rk4_fixed;
    use super::*;

    #[test]
    fn rhs_solves_the_mass_matrix_system() {
        // M θ̈ + C + G = τ must hold for the returned accelerations (residual check).
        let p = DoublePendulum::default();
        let x = [0.3, -1.1, 0.7, -2.0];
        let tau = [1.5, -4.0];
        let f = p.rhs(&x, tau);
        let [m11, m12, m22] = p.mass_matrix(x[1]);
        let s2 = x[1].sin();
        let c = [-s2 * (2.0 * x[2] * x[3] + x[3] * x[3]), x[2] * x[2] * s2];
        let gg = [
            2.0 * 9.8 * x[0].cos() + 9.8 * (x[0] + x[1]).cos(),
            9.8 * (x[0] + x[1]).cos(),
        ];
        let r0 = m11 * f[2] + m12 * f[3] + c[0] + gg[0] - tau[0];
        let r1 = m12 * f[2] + m22 * f[3] + c[1] + gg[1] - tau[1];
        assert!(r0.abs() < 1e-12 && r1.abs() < 1e-12, "{r0} {r1}");
        assert_eq!([f[0], f[1]], [x[2], x[3]]);
    }

    #[test]
    fn one_step_matches_fine_rk4() {
        let p = DoublePendulum::default();
        let mut rng = Rng::new(11);
        for _ in 0..30 {
            let x = p.sample_initial_state(&mut rng);
            let u = p.sample_input(&mut rng);
            let mut y = [0.0; 4];
            p.step(&x, &u, &mut y);
            let fine = rk4_fixed(
                |s| p.rhs(s, [u[0], u[1]]),
                [x[0], x[1], x[2], x[3]],
                0.01,
                2000,
            );
            for i in 0..4 {
                assert!((y[i] - fine[i]).abs() < 1e-10, "{y:?} vs {fine:?}");
            }
            assert!((y[2] - x[2]).abs() > 1e-6);
        }
    }

    #[test]
    fn unforced_motion_conserves_energy() {
        let p = DoublePendulum::default();
        let mut x = vec![1.0, -0.5, 0.5, 1.0];
        let e0 = p.energy(&x);
        let mut moved = 0.0f64;
        for _ in 0..500 {
            let mut y = vec![0.0; 4];
            p.step(&x, &[0.0, 0.0], &mut y);
            moved = moved.max((y[0] - 1.0).abs());
            x = y;
        }
        let e1 = p.energy(&x);
        assert!((e1 - e0).abs() < 1e-7 * e0.abs().max(1.0), "{e0} → {e1}");
        assert!(moved > 0.1, "pendulum did not move");
    }
}
