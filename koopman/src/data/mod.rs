//! Datasets of windows (`x_0..x_T`, `u_0..u_{T−1}`): generation, splits and `.npz` I/O.

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
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
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
}
