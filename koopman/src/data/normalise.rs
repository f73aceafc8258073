//! Per-dimension z-scoring of states and inputs (SPEC.md, "Data": legged robots train on z-scored
//! data, statistics over the train pool, standard deviations floored at 1e-8).

use super::Dataset;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// The smallest standard deviation a dimension is divided by (SPEC.md).
pub const STD_FLOOR: f64 = 1e-8;

/// Means and standard deviations of every state and input dimension: `x_n = (x − x_mean) / x_std`,
/// `u_n = (u − u_mean) / u_std`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Normalisation {
    /// Mean of each state dimension.
    pub x_mean: Vec<f64>,
    /// Standard deviation of each state dimension (≥ [`STD_FLOOR`]).
    pub x_std: Vec<f64>,
    /// Mean of each input dimension.
    pub u_mean: Vec<f64>,
    /// Standard deviation of each input dimension (≥ [`STD_FLOOR`]).
    pub u_std: Vec<f64>,
}

/// Mean and population standard deviation (floored) of each of `dim` interleaved columns.
fn column_stats(values: &[f64], dim: usize) -> (Vec<f64>, Vec<f64>) {
    let rows = values.len().checked_div(dim).unwrap_or(0);
    let mut mean = vec![0.0; dim];
    let mut var = vec![0.0; dim];
    if rows == 0 {
        return (mean, vec![1.0; dim]);
    }
    for row in values.chunks_exact(dim) {
        for (m, v) in mean.iter_mut().zip(row) {
            *m += v;
        }
    }
    mean.iter_mut().for_each(|m| *m /= rows as f64);
    for row in values.chunks_exact(dim) {
        for ((s, v), m) in var.iter_mut().zip(row).zip(&mean) {
            *s += (v - m) * (v - m);
        }
    }
    let std = var
        .iter()
        .map(|s| (s / rows as f64).sqrt().max(STD_FLOOR))
        .collect();
    (mean, std)
}

impl Normalisation {
    /// Statistics over every state (all `T + 1` of every window) and every input of `data`.
    pub fn fit(data: &Dataset) -> Result<Self> {
        if data.n == 0 {
            return Err(Error::InvalidArgument(
                "cannot fit a normalisation on an empty dataset".into(),
            ));
        }
        let (x_mean, x_std) = column_stats(&data.x, data.nx);
        let (u_mean, u_std) = column_stats(&data.u, data.nu);
        let norm = Normalisation {
            x_mean,
            x_std,
            u_mean,
            u_std,
        };
        norm.check(data.nx, data.nu)?;
        Ok(norm)
    }

    /// State dimension.
    pub fn nx(&self) -> usize {
        self.x_mean.len()
    }

    /// Input dimension.
    pub fn nu(&self) -> usize {
        self.u_mean.len()
    }

    /// Checks the dimensions against `nx`/`nu`, finiteness and the floor of the deviations.
    pub fn check(&self, nx: usize, nu: usize) -> Result<()> {
        for (what, v, want) in [
            ("normalisation x_mean", &self.x_mean, nx),
            ("normalisation x_std", &self.x_std, nx),
            ("normalisation u_mean", &self.u_mean, nu),
            ("normalisation u_std", &self.u_std, nu),
        ] {
            if v.len() != want {
                return Err(Error::dimension(what, want, v.len()));
            }
            crate::error::ensure_finite(what, v)?;
        }
        if self.x_std.iter().chain(&self.u_std).any(|s| *s < STD_FLOOR) {
            return Err(Error::InvalidArgument(format!(
                "normalisation: every standard deviation must be ≥ {STD_FLOOR}"
            )));
        }
        Ok(())
    }

    /// Normalises one state in place.
    pub fn state_in_place(&self, x: &mut [f64]) {
        for ((v, m), s) in x.iter_mut().zip(&self.x_mean).zip(&self.x_std) {
            *v = (*v - m) / s;
        }
    }

    /// Maps one normalised state back to raw units in place.
    pub fn raw_state_in_place(&self, x: &mut [f64]) {
        for ((v, m), s) in x.iter_mut().zip(&self.x_mean).zip(&self.x_std) {
            *v = *v * s + m;
        }
    }

    /// Normalises one input in place.
    pub fn input_in_place(&self, u: &mut [f64]) {
        for ((v, m), s) in u.iter_mut().zip(&self.u_mean).zip(&self.u_std) {
            *v = (*v - m) / s;
        }
    }

    /// A copy of `data` in normalised units (its metadata unchanged).
    pub fn apply(&self, data: &Dataset) -> Result<Dataset> {
        if data.nx != self.nx() || data.nu != self.nu() {
            return Err(Error::InvalidArgument(format!(
                "normalisation for nx = {}, nu = {} applied to a dataset with nx = {}, nu = {}",
                self.nx(),
                self.nu(),
                data.nx,
                data.nu
            )));
        }
        let mut out = data.clone();
        if self.nx() > 0 {
            out.x
                .chunks_exact_mut(self.nx())
                .for_each(|x| self.state_in_place(x));
        }
        if self.nu() > 0 {
            out.u
                .chunks_exact_mut(self.nu())
                .for_each(|u| self.input_in_place(u));
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::{DatasetMeta, Pairing};

    fn dataset(x: Vec<f64>, u: Vec<f64>, n: usize, steps: usize, nx: usize, nu: usize) -> Dataset {
        Dataset {
            n,
            steps,
            nx,
            nu,
            x,
            u,
            meta: DatasetMeta {
                env: "test".into(),
                dt: 0.1,
                state_names: (0..nx).map(|i| format!("x{i}")).collect(),
                input_names: (0..nu).map(|i| format!("u{i}")).collect(),
                pairing: Pairing::Aligned,
                seed: 0,
                source: "test".into(),
                policy: "test".into(),
                region: None,
                window_flags: None,
            },
        }
    }

    #[test]
    fn fit_matches_the_closed_form_and_apply_gives_zero_mean_unit_std() {
        // 2 windows, T = 1, nx = 2, nu = 1: states (1,10) (3,10) (5,10) (7,10).
        let d = dataset(
            vec![1.0, 10.0, 3.0, 10.0, 5.0, 10.0, 7.0, 10.0],
            vec![2.0, -2.0],
            2,
            1,
            2,
            1,
        );
        let n = Normalisation::fit(&d).unwrap();
        assert_eq!(n.x_mean, vec![4.0, 10.0]);
        // Population std of 1,3,5,7 is sqrt(5); the constant column is floored.
        assert!((n.x_std[0] - 5f64.sqrt()).abs() < 1e-15);
        assert_eq!(n.x_std[1], STD_FLOOR);
        assert_eq!((n.u_mean[0], n.u_std[0]), (0.0, 2.0));
        let z = n.apply(&d).unwrap();
        let col0: Vec<f64> = z.x.iter().step_by(2).copied().collect();
        let mean: f64 = col0.iter().sum::<f64>() / 4.0;
        let var: f64 = col0.iter().map(|v| v * v).sum::<f64>() / 4.0;
        assert!(mean.abs() < 1e-15 && (var - 1.0).abs() < 1e-12);
        assert!(z.x.iter().skip(1).step_by(2).all(|v| *v == 0.0));
        assert_eq!(z.u, vec![1.0, -1.0]);
        let mut back = z.state(1, 1).to_vec();
        n.raw_state_in_place(&mut back);
        assert!((back[0] - 7.0).abs() < 1e-14 && (back[1] - 10.0).abs() < 1e-14);
    }

    #[test]
    fn wrong_dimensions_and_bad_values_are_refused() {
        let d = dataset(vec![0.0; 4], vec![0.0; 1], 1, 1, 2, 1);
        let n = Normalisation::fit(&d).unwrap();
        let other = dataset(vec![0.0; 6], vec![0.0; 1], 1, 1, 3, 1);
        assert!(matches!(n.apply(&other), Err(Error::InvalidArgument(_))));
        assert!(matches!(n.check(3, 1), Err(Error::Dimension { .. })));
        let mut bad = n.clone();
        bad.x_std[0] = 0.0;
        assert!(matches!(bad.check(2, 1), Err(Error::InvalidArgument(_))));
        bad.x_std[0] = f64::NAN;
        assert!(matches!(bad.check(2, 1), Err(Error::NonFinite(_))));
        let empty = dataset(vec![], vec![], 0, 1, 2, 1);
        assert!(Normalisation::fit(&empty).is_err());
    }
}
