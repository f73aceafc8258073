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

super::data_region::with_x0_box! {
    /// Data collection: by lockstep stepping, or by the simulators themselves
    /// (`Policy::Adapter`).
    #[derive(Clone, Debug, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct CollectSpec {
        /// Input policy (default: SPEC's, a fresh uniform random input within the simulator's
        /// bounds every step, [`Policy::uniform`]).
        #[serde(default = "Policy::uniform")]
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
        @x0_box("The box the windows' initial states are drawn from (`x0_low`/`x0_high` or \
                 `x0_center`/`x0_radius`); absent = the simulator's own seeded reset. See \
                 [`CollectSpec::x0_box`]."),
    }
}

impl CollectSpec {
    /// No data at all: what a scenario without `[collect]` collects (it scores models trained
    /// elsewhere, `[train] pretrained`, and trains none).
    pub fn nothing() -> Self {
        CollectSpec {
            policy: Policy::uniform(),
            train_windows: 0,
            val_windows: 0,
            test_windows: 0,
            steps: default_steps(),
            seed: default_seed(),
            x0_low: None,
            x0_high: None,
            x0_center: None,
            x0_radius: None,
        }
    }

    /// Whether any data is collected (a `[collect]` table with training windows).
    pub fn collects(&self) -> bool {
        self.train_windows > 0
    }

    /// Checks the table without the simulators: positive training windows and steps, a
    /// scripted policy with inputs, an adapter policy's block ≥ 1, the initial-state box, the
    /// uniform policy's bounds.
    pub fn check(&self) -> Result<()> {
        if self.train_windows == 0 || self.steps == 0 {
            return Err(Error::Config(
                "collect.train_windows and collect.steps must be positive (a scenario that \
                 collects nothing has no [collect] table)"
                    .into(),
            ));
        }
        if let Policy::Scripted { inputs } = &self.policy {
            if inputs.is_empty() {
                return Err(Error::Config(
                    "a scripted policy needs at least one input".into(),
                ));
            }
        }
        if matches!(self.policy, Policy::Adapter { block: 0, .. }) {
            return Err(Error::Config(
                "collect.policy.block must be at least 1".into(),
            ));
        }
        self.x0_box()?;
        if let Policy::Uniform { low, high } = &self.policy {
            super::data_region::check_bounds("collect.policy", ["`low`", "`high`"], low, high)?;
        }
        Ok(())
    }

    /// The initial-state box `(low, high)` the scenario asks for, if any: `x0_low`/`x0_high`
    /// as given, or `x0_center ± x0_radius`. Checked without the simulator: the keys of one
    /// form together and not both forms, equal lengths, finite values, `low ≤ high` (a radius
    /// ≥ 0), and a policy that takes a box ([`takes_region`]); the length against the
    /// simulator's `nx` is checked with its `info` ([`crate::collect::check_x0_box`]).
    pub fn x0_box(&self) -> Result<Option<(Vec<f64>, Vec<f64>)>> {
        let xb = self.x0_box_in("[collect]")?;
        if xb.is_some() {
            takes_region(&self.policy, "[collect]")?;
        }
        Ok(xb)
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

fn default_steps() -> usize {
    15
}
fn default_seed() -> u64 {
    42
}
