//! Datasets of windows (`x_0..x_T`, `u_0..u_{T−1}`): generation, splits and `.npz` I/O.
//!
//! # Storage convention
//! A [`Dataset`] holds `x [n, T+1, nx]` and `u [n, T, nu]`. Stored input `u_t` is the input that
//! the training losses pair with the transition `x_t → x_{t+1}`. What it *physically* did depends
//! on [`Pairing`]:
//! - `aligned` (default): `x_{t+1} = f(x_t, u_t)` for every `t = 0..T−1`.
//! - `reference` (the public reference code's collectors): `u_0` is drawn but never applied, and
//!   for `t = 1..T−1` the stored `u_t` is the input that drove `x_{t−1} → x_t`, i.e.
//!   `x_t = f(x_{t−1}, u_t)`. The input that drove the last transition `x_{T−1} → x_T` is not
//!   stored. Training on such data therefore pairs every transition with the previous step's
//!   (independent) input, exactly as the reference training loop does.
//!
//! # Files
//! `.npz` archives (stored, uncompressed members) with `x.npy`, `u.npy` (`<f8`, C order, `.npy`
//! v1.0) and `meta.json` ([`DatasetMeta`] plus the dimensions), and a sidecar `<stem>.json` with
//! the same metadata; see [`npz`].

pub mod generate;
pub mod normalise;
pub mod npy;
pub mod npz;
pub mod region;
pub mod splits;
pub mod trajectory;

pub use generate::{
    builtin_source, builtin_source_parameters, generate, generate_with_progress, worker_threads,
};
pub use normalise::Normalisation;
pub use region::{DataRegion, InRegion};
pub use splits::{generate_splits, generate_splits_with_progress, SplitSpec, Splits};

use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// How inputs are paired with transitions (SPEC.md, "Pairing of inputs and transitions").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Pairing {
    /// `u_t` drives `x_t → x_{t+1}` (the method's definition; koopbridge's default).
    #[default]
    Aligned,
    /// The public reference code's pairing: row t's input drove `x_{t−1} → x_t`.
    Reference,
}

/// Metadata stored next to every dataset (JSON inside the `.npz` and beside it).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DatasetMeta {
    /// Environment or simulator name.
    pub env: String,
    /// Sampling period in seconds.
    pub dt: f64,
    /// Names of the state components.
    pub state_names: Vec<String>,
    /// Names of the input components.
    pub input_names: Vec<String>,
    /// Input/transition pairing.
    pub pairing: Pairing,
    /// Data seed.
    pub seed: u64,
    /// Where the data came from (e.g. `koopman::systems`, `zenoh:sim/fmu0`).
    pub source: String,
    /// How inputs were chosen (e.g. `uniform`).
    pub policy: String,
    /// The region the windows were drawn from when it is not the system's SPEC distribution
    /// (`koopbridge data gen --x0-low …`); absent from the JSON otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub region: Option<DataRegion>,
    /// How many windows the simulator flagged while they were collected (lockstep collection
    /// over the bridge); absent when nobody counted (in-process data, windows the simulator
    /// ran itself).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub window_flags: Option<WindowFlags>,
}

/// The windows of a collection in which the simulator reported a step status at least once.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct WindowFlags {
    /// Windows with a step the simulator's task ended (`terminated`: a fall, a stop).
    pub terminated: usize,
    /// Windows cut by a limit outside the task (`truncated`).
    pub truncated: usize,
    /// Windows with an input the simulator clipped into its bounds (`clipped`).
    pub clipped: usize,
}

/// A set of windows. `x` is `[n, T+1, nx]` and `u` is `[n, T, nu]`, row-major, f64.
#[derive(Clone, Debug, PartialEq)]
pub struct Dataset {
    /// Number of windows.
    pub n: usize,
    /// Transitions per window T.
    pub steps: usize,
    /// State dimension.
    pub nx: usize,
    /// Input dimension.
    pub nu: usize,
    /// States, `n * (steps + 1) * nx` values.
    pub x: Vec<f64>,
    /// Inputs, `n * steps * nu` values.
    pub u: Vec<f64>,
    /// Metadata.
    pub meta: DatasetMeta,
}

impl Dataset {
    /// State `t` of window `i`.
    pub fn state(&self, i: usize, t: usize) -> &[f64] {
        let o = (i * (self.steps + 1) + t) * self.nx;
        &self.x[o..o + self.nx]
    }

    /// Input `t` of window `i`.
    pub fn input(&self, i: usize, t: usize) -> &[f64] {
        let o = (i * self.steps + t) * self.nu;
        &self.u[o..o + self.nu]
    }

    /// Number of (x_t, u_t, x_{t+1}) transitions, `n · T`.
    pub fn transitions(&self) -> usize {
        self.n * self.steps
    }

    /// The first `m` windows (a run with `m` training samples). `m` must be in `1..=n`.
    pub fn head(&self, m: usize) -> Result<Dataset> {
        if m == 0 || m > self.n {
            return Err(Error::InvalidArgument(format!(
                "cannot take the first {m} windows of a pool of {} (m must be between 1 and {})",
                self.n, self.n
            )));
        }
        let sx = (self.steps + 1) * self.nx;
        let su = self.steps * self.nu;
        Ok(Dataset {
            n: m,
            steps: self.steps,
            nx: self.nx,
            nu: self.nu,
            x: self.x[..m * sx].to_vec(),
            u: self.u[..m * su].to_vec(),
            meta: self.meta.clone(),
        })
    }

    /// The windows at `indices`, in that order (indices must be `< n`).
    pub fn select(&self, indices: &[usize]) -> Result<Dataset> {
        let sx = (self.steps + 1) * self.nx;
        let su = self.steps * self.nu;
        let mut x = Vec::with_capacity(indices.len() * sx);
        let mut u = Vec::with_capacity(indices.len() * su);
        for &i in indices {
            if i >= self.n {
                return Err(Error::InvalidArgument(format!(
                    "window index {i} out of range (n = {})",
                    self.n
                )));
            }
            x.extend_from_slice(&self.x[i * sx..(i + 1) * sx]);
            u.extend_from_slice(&self.u[i * su..(i + 1) * su]);
        }
        Ok(Dataset {
            n: indices.len(),
            steps: self.steps,
            nx: self.nx,
            nu: self.nu,
            x,
            u,
            meta: self.meta.clone(),
        })
    }

    /// Checks consistent dimensions (array lengths, metadata names) and finite values.
    pub fn validate(&self) -> Result<()> {
        if self.nx == 0 {
            return Err(Error::InvalidArgument("dataset has nx = 0".into()));
        }
        if self.steps == 0 {
            return Err(Error::InvalidArgument(
                "dataset windows have no transition (T = 0)".into(),
            ));
        }
        let ex = self.n * (self.steps + 1) * self.nx;
        if self.x.len() != ex {
            return Err(Error::dimension(
                "dataset x values (n·(T+1)·nx)",
                ex,
                self.x.len(),
            ));
        }
        let eu = self.n * self.steps * self.nu;
        if self.u.len() != eu {
            return Err(Error::dimension(
                "dataset u values (n·T·nu)",
                eu,
                self.u.len(),
            ));
        }
        if self.meta.state_names.len() != self.nx {
            return Err(Error::dimension(
                "metadata state_names",
                self.nx,
                self.meta.state_names.len(),
            ));
        }
        if self.meta.input_names.len() != self.nu {
            return Err(Error::dimension(
                "metadata input_names",
                self.nu,
                self.meta.input_names.len(),
            ));
        }
        if let Some(i) = self.x.iter().position(|v| !v.is_finite()) {
            let w = i / ((self.steps + 1) * self.nx);
            return Err(Error::NonFinite(format!("dataset states (window {w})")));
        }
        if let Some(i) = self.u.iter().position(|v| !v.is_finite()) {
            let w = i / (self.steps * self.nu).max(1);
            return Err(Error::NonFinite(format!("dataset inputs (window {w})")));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn tiny(n: usize, steps: usize, nx: usize, nu: usize) -> Dataset {
        Dataset {
            n,
            steps,
            nx,
            nu,
            x: (0..n * (steps + 1) * nx).map(|v| v as f64).collect(),
            u: (0..n * steps * nu).map(|v| -(v as f64)).collect(),
            meta: DatasetMeta {
                env: "test".into(),
                dt: 0.1,
                state_names: (0..nx).map(|i| format!("x{i}")).collect(),
                input_names: (0..nu).map(|i| format!("u{i}")).collect(),
                pairing: Pairing::Aligned,
                seed: 0,
                source: "test".into(),
                policy: "none".into(),
                region: None,
                window_flags: None,
            },
        }
    }

    #[test]
    fn head_select_and_validate() {
        let d = tiny(5, 3, 2, 1);
        d.validate().unwrap();
        let h = d.head(2).unwrap();
        assert_eq!(h.n, 2);
        assert_eq!(h.state(1, 3), d.state(1, 3));
        assert_eq!(h.input(1, 2), d.input(1, 2));
        assert!(matches!(d.head(6), Err(Error::InvalidArgument(_))));
        assert!(d.head(0).is_err());
        let s = d.select(&[4, 0]).unwrap();
        assert_eq!(s.state(0, 0), d.state(4, 0));
        assert_eq!(s.input(1, 1), d.input(0, 1));
        assert!(d.select(&[5]).is_err());
        let mut bad = d.clone();
        bad.x[7] = f64::NAN;
        assert!(matches!(bad.validate(), Err(Error::NonFinite(_))));
        let mut bad = d.clone();
        bad.u.pop();
        assert!(matches!(bad.validate(), Err(Error::Dimension { .. })));
        let mut bad = d.clone();
        bad.meta.state_names.pop();
        assert!(matches!(bad.validate(), Err(Error::Dimension { .. })));
    }
}
