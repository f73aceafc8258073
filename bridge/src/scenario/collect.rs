//! A scenario's `[collect]` table: the input policy, the split sizes, window length and seed,
//! and the optional initial-state box, checked when the file is read.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// How inputs are chosen during collection.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Policy {
    /// A fresh uniform random input `u ~ U(low, high)` every step (SPEC.md); absent bounds are
    /// the simulator's `info` bounds (checked against them and `nu` before collection:
    /// [`crate::collect::uniform_bounds`]).
    Uniform {
        /// Lower bounds: one value for every input or `nu` values (default `info.u_min`).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        low: Option<crate::messages::InputBound>,
        /// Upper bounds: one value for every input or `nu` values (default `info.u_max`).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        high: Option<crate::messages::InputBound>,
    },
    /// A fixed input sequence (each entry `nu` values), cycled.
    Scripted {
        /// The inputs.
        inputs: Vec<Vec<f64>>,
    },
    /// Each simulator runs the windows itself, `block` windows per `collect` request
    /// (PROTOCOL.md, "Collect"), drawing its inputs from `inputs` (default: uniform within its
    /// bounds) with its own generator.
    Adapter {
        /// The input policy the simulators draw from.
        #[serde(default)]
        inputs: crate::messages::CollectPolicy,
        /// Windows per request (default 500).
        #[serde(default = "default_block")]
        block: u32,
    },
}

impl Policy {
    /// The uniform policy within the simulator's bounds (no `low`/`high`).
    pub fn uniform() -> Self {
        Policy::Uniform {
            low: None,
            high: None,
        }
    }
}

fn default_block() -> u32 {
    500
}

/// Data collection: by lockstep stepping, or by the simulators themselves (`Policy::Adapter`).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CollectSpec {
    /// Input policy.
    pub policy: Policy,
    /// Training windows (per simulator).
    pub train_windows: usize,
    /// Validation windows (per simulator).
    pub val_windows: usize,
    /// Test windows (per simulator).
    pub test_windows: usize,
    /// Transitions per window T (default: 15).
    #[serde(default = "default_steps")]
    pub steps: usize,
    /// Data seed (initial states and random inputs).
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// Lower corner of the box the windows' initial states are drawn from (`nx` values), with
    /// `x0_high`; absent = the simulator's own seeded reset. See [`CollectSpec::x0_box`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub x0_low: Option<Vec<f64>>,
    /// Upper corner of the initial-state box (`nx` values), with `x0_low`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub x0_high: Option<Vec<f64>>,
    /// The centre of the initial-state box (`nx` values), with `x0_radius`; instead of
    /// `x0_low`/`x0_high`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub x0_center: Option<Vec<f64>>,
    /// The half-widths of the initial-state box around `x0_center`: one value for every state
    /// or `nx` values (≥ 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub x0_radius: Option<crate::messages::InputBound>,
}

impl CollectSpec {
    /// The initial-state box `(low, high)` the scenario asks for, if any: `x0_low`/`x0_high`
    /// as given, or `x0_center ± x0_radius`. Checked without the simulator: the keys of one
    /// form together and not both forms, equal lengths, finite values, `low ≤ high` (a radius
    /// ≥ 0); the length against the simulator's `nx` is checked with its `info`
    /// ([`crate::collect::check_x0_box`]).
    pub fn x0_box(&self) -> Result<Option<(Vec<f64>, Vec<f64>)>> {
        self.x0_box_checked()
    }

    /// The scenario keys the initial-state box comes from (for messages): `x0_low`/`x0_high`,
    /// or `x0_center` for both sides.
    pub fn x0_keys(&self) -> [&'static str; 2] {
        if self.x0_center.is_some() {
            ["x0_center", "x0_center"]
        } else {
            ["x0_low", "x0_high"]
        }
    }

    fn x0_box_checked(&self) -> Result<Option<(Vec<f64>, Vec<f64>)>> {
        let xb = x0_box_of(
            "[collect]",
            [&self.x0_low, &self.x0_high, &self.x0_center],
            &self.x0_radius,
        )?;
        if xb.is_some() {
            self.check_takes_region("[collect]")?;
        }
        Ok(xb)
    }

    /// Refuses a data region (an initial-state box, input bounds) that the policy cannot take
    /// ([`takes_region`]).
    pub(crate) fn check_takes_region(&self, table: &str) -> Result<()> {
        takes_region(&self.policy, table)
    }
}

/// Refuses a data region (an initial-state box, input bounds) in scenario table `table` that
/// `policy` cannot take: `Policy::Adapter` with planned or expert inputs (the simulator draws
/// those windows itself).
pub(crate) fn takes_region(policy: &Policy, table: &str) -> Result<()> {
    match policy {
        Policy::Adapter { inputs, .. }
            if !matches!(inputs, crate::messages::CollectPolicy::Uniform { .. }) =>
        {
            Err(Error::Config(format!(
                "{table}: an initial-state box or input bounds need uniform inputs; with \
                 inputs = {} the simulator draws its windows itself",
                inputs.describe()
            )))
        }
        _ => Ok(()),
    }
}

/// An initial-state box given in scenario table `table` as `[x0_low, x0_high, x0_center]` and
/// `x0_radius`: `x0_low`/`x0_high` as given, or `x0_center ± x0_radius`; `None` without
/// either. Checked without the simulator: the keys of one form together and not both forms,
/// equal lengths, finite values, `low ≤ high` (a radius ≥ 0); the length against the
/// simulator's `nx` is checked with its `info` ([`crate::collect::check_x0_box`]).
pub(crate) fn x0_box_of(
    table: &str,
    [x0_low, x0_high, x0_center]: [&Option<Vec<f64>>; 3],
    x0_radius: &Option<crate::messages::InputBound>,
) -> Result<Option<(Vec<f64>, Vec<f64>)>> {
    fn fail<T>(table: &str, m: String) -> Result<T> {
        Err(Error::Config(format!("{table}: {m}")))
    }
    let finite = |what: &str, v: &[f64]| match v.iter().position(|x| !x.is_finite()) {
        Some(i) => fail(table, format!("{what}[{i}] is {} (must be finite)", v[i])),
        None => Ok(()),
    };
    let boxed = x0_low.is_some() || x0_high.is_some();
    let around = x0_center.is_some() || x0_radius.is_some();
    let (lo, hi) = match (boxed, around) {
        (false, false) => return Ok(None),
        (true, true) => {
            return fail(
                table,
                "give the initial-state box either as x0_low and x0_high or as x0_center and \
                 x0_radius, not both"
                    .into(),
            )
        }
        (true, false) => match (x0_low, x0_high) {
            (Some(lo), Some(hi)) => {
                finite("x0_low", lo)?;
                finite("x0_high", hi)?;
                (lo.clone(), hi.clone())
            }
            _ => {
                return fail(
                    table,
                    "x0_low and x0_high go together (the box's two corners)".into(),
                )
            }
        },
        (false, true) => {
            let (Some(c), Some(r)) = (x0_center, x0_radius) else {
                return fail(table, "x0_center and x0_radius go together".into());
            };
            finite("x0_center", c)?;
            let Some(r) = r.resolve(c.len()) else {
                return fail(
                    table,
                    format!(
                        "x0_radius must have 1 value or one per state ({}, as x0_center)",
                        c.len()
                    ),
                );
            };
            finite("x0_radius", &r)?;
            if let Some(i) = r.iter().position(|&v| v < 0.0) {
                return fail(table, format!("x0_radius[{i}] is {} (must be ≥ 0)", r[i]));
            }
            (
                c.iter().zip(&r).map(|(c, r)| c - r).collect(),
                c.iter().zip(&r).map(|(c, r)| c + r).collect(),
            )
        }
    };
    if lo.len() != hi.len() {
        return fail(
            table,
            format!("x0_low has {} values and x0_high {}", lo.len(), hi.len()),
        );
    }
    if let Some(i) = (0..lo.len()).find(|&i| lo[i] > hi[i]) {
        return fail(
            table,
            format!(
                "x0_low[{i}] = {} > x0_high[{i}] = {} (the box is empty)",
                lo[i], hi[i]
            ),
        );
    }
    Ok(Some((lo, hi)))
}

fn default_steps() -> usize {
    15
}
fn default_seed() -> u64 {
    42
}
