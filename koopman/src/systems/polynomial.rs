//! The polynomial system of SPEC.md, a discrete map with no input:
//! `x1⁺ = 0.85 x1`, `x2⁺ = 0.9 x2`, `x3⁺ = 0.9 x3 + Σ_{p=1}^{n_poly−2} b_p x1^p`,
//! `b = linspace(0.9, 0.1, n_poly − 2)`.

use super::system::System;
use crate::rng::Rng;
use crate::{Error, Result};

/// The default `n_poly` when none is given (the paper sweeps 3, 5, 10, 20, 50).
pub const DEFAULT_N_POLY: usize = 5;

/// The 3-D polynomial map; `n_poly ≥ 3`. Windows have T = 1.
#[derive(Clone, Debug)]
pub struct PolynomialSystem {
    n_poly: usize,
    coeffs: Vec<f64>,
}

impl PolynomialSystem {
    /// The system with polynomial degree parameter `n_poly` (at least 3).
    pub fn new(n_poly: usize) -> Result<Self> {
        if n_poly < 3 {
            return Err(Error::InvalidArgument(format!(
                "n_poly must be at least 3 (got {n_poly})"
            )));
        }
        let k = n_poly - 2;
        // numpy.linspace(0.9, 0.1, k): a single point is the start value.
        let coeffs = if k == 1 {
            vec![0.9]
        } else {
            (0..k)
                .map(|i| 0.9 + (0.1 - 0.9) * i as f64 / (k - 1) as f64)
                .collect()
        };
        Ok(PolynomialSystem { n_poly, coeffs })
    }

    /// The parameter `n_poly`.
    pub fn n_poly(&self) -> usize {
        self.n_poly
    }

    /// The coefficients `b_1..b_{n_poly−2}`.
    pub fn coefficients(&self) -> &[f64] {
        &self.coeffs
    }
}

impl Default for PolynomialSystem {
    fn default() -> Self {
        PolynomialSystem::new(DEFAULT_N_POLY).expect("default n_poly is valid")
    }
}

impl System for PolynomialSystem {
    fn name(&self) -> &str {
        "polynomial"
    }
    fn nx(&self) -> usize {
        3
    }
    fn nu(&self) -> usize {
        0
    }
    fn dt(&self) -> f64 {
        1.0
    }
    fn state_names(&self) -> Vec<String> {
        vec!["x1".into(), "x2".into(), "x3".into()]
    }
    fn input_names(&self) -> Vec<String> {
        Vec::new()
    }
    fn input_bounds(&self) -> (Vec<f64>, Vec<f64>) {
        (Vec::new(), Vec::new())
    }
    fn angle_indices(&self) -> Vec<usize> {
        Vec::new()
    }
    fn window_steps(&self) -> usize {
        1
    }
    fn sample_initial_state(&self, rng: &mut Rng) -> Vec<f64> {
        (0..3).map(|_| rng.uniform(-1.0, 1.0)).collect()
    }
    fn parameters(&self) -> String {
        format!("n_poly={}", self.n_poly)
    }
    fn step(&self, x: &[f64], _u: &[f64], x_next: &mut [f64]) {
        // Horner: Σ_{p=1}^{k} b_p x1^p = x1 (b_1 + x1 (b_2 + ...)).
        let x1 = x[0];
        let mut acc = 0.0;
        for &b in self.coeffs.iter().rev() {
            acc = acc * x1 + b;
        }
        x_next[0] = 0.85 * x1;
        x_next[1] = 0.9 * x[1];
        x_next[2] = 0.9 * x[2] + acc * x1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn map_matches_closed_form_sum_of_powers() {
        for n_poly in [3, 5, 10, 20, 50] {
            let s = PolynomialSystem::new(n_poly).unwrap();
            let k = n_poly - 2;
            assert_eq!(s.coefficients().len(), k);
            assert!((s.coefficients()[0] - 0.9).abs() < 1e-15);
            assert!((s.coefficients()[k - 1] - if k == 1 { 0.9 } else { 0.1 }).abs() < 1e-15);
            let mut rng = Rng::new(n_poly as u64);
            for _ in 0..20 {
                let x = s.sample_initial_state(&mut rng);
                let mut y = [0.0; 3];
                s.step(&x, &[], &mut y);
                let sum: f64 = (1..=k)
                    .map(|p| {
                        let b = if k == 1 {
                            0.9
                        } else {
                            0.9 - 0.8 * (p - 1) as f64 / (k - 1) as f64
                        };
                        b * x[0].powi(p as i32)
                    })
                    .sum();
                assert!((y[0] - 0.85 * x[0]).abs() < 1e-15);
                assert!((y[1] - 0.9 * x[1]).abs() < 1e-15);
                assert!((y[2] - (0.9 * x[2] + sum)).abs() < 1e-13, "{y:?}");
            }
        }
        // n_poly = 3: x3⁺ = 0.9 x3 + 0.9 x1 exactly.
        let s = PolynomialSystem::new(3).unwrap();
        let mut y = [0.0; 3];
        s.step(&[0.5, 0.2, -0.4], &[], &mut y);
        assert!((y[2] - (0.9 * -0.4 + 0.9 * 0.5)).abs() < 1e-15);
    }

    #[test]
    fn too_small_n_poly_is_an_error() {
        assert!(matches!(
            PolynomialSystem::new(2),
            Err(Error::InvalidArgument(_))
        ));
    }
}
