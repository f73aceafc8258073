//! Data regions: generate windows from a box of initial states and inputs of one's choosing
//! instead of a system's SPEC distributions (e.g. the double-pendulum control task's data
//! around its target, issue 12 §3), recorded in the dataset's metadata.

use crate::rng::Rng;
use crate::systems::System;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// Where generated windows start and which inputs they apply: `x_0 ~ U(x0_low, x0_high)` per
/// component (drawn in component order, like the SPEC systems' own samplers) and
/// `u_t ~ U(u_low, u_high)` per component. A part left `None` keeps the system's own
/// distribution (SPEC.md's). Stored as `region` in the dataset's JSON metadata.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DataRegion {
    /// Lower bounds of the initial state (`nx` values), with `x0_high`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub x0_low: Option<Vec<f64>>,
    /// Upper bounds of the initial state (`nx` values), with `x0_low`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub x0_high: Option<Vec<f64>>,
    /// Lower input bounds of the random inputs (`nu` values), with `u_high`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub u_low: Option<Vec<f64>>,
    /// Upper input bounds of the random inputs (`nu` values), with `u_low`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub u_high: Option<Vec<f64>>,
}

impl DataRegion {
    /// A region from optional pieces, given the way the command line gives them: `x0_low` and
    /// `x0_high` together, the inputs as `u_low` and `u_high` together or as one symmetric
    /// bound `u_bound` (|u_i| ≤ B, one value for every input). Returns `None` when nothing is
    /// given (the system's SPEC distributions, bit for bit). Checked against `system` with
    /// [`DataRegion::check`].
    pub fn from_parts(
        system: &dyn System,
        x0: (Option<Vec<f64>>, Option<Vec<f64>>),
        u: (Option<Vec<f64>>, Option<Vec<f64>>),
        u_bound: Option<f64>,
    ) -> Result<Option<DataRegion>> {
        let (u_low, u_high) = match (u, u_bound) {
            ((None, None), Some(b)) => {
                if !(b.is_finite() && b > 0.0) {
                    return Err(Error::InvalidArgument(format!(
                        "the input bound must be a positive finite number, got {b}"
                    )));
                }
                (Some(vec![-b; system.nu()]), Some(vec![b; system.nu()]))
            }
            ((lo, hi), None) => (lo, hi),
            (_, Some(_)) => {
                return Err(Error::InvalidArgument(
                    "give the input range either as one symmetric bound or as low and high \
                     bounds, not both"
                        .into(),
                ))
            }
        };
        let region = DataRegion {
            x0_low: x0.0,
            x0_high: x0.1,
            u_low,
            u_high,
        };
        if region == DataRegion::default() {
            return Ok(None);
        }
        region.check(system)?;
        Ok(Some(region))
    }

    /// Checks the region against `system`: low and high given together, `nx` (initial state)
    /// and `nu` (inputs) values, finite, and `low ≤ high` component by component.
    pub fn check(&self, system: &dyn System) -> Result<()> {
        check_pair(
            "initial-state",
            &self.x0_low,
            &self.x0_high,
            system.nx(),
            system,
        )?;
        if system.nu() == 0 && (self.u_low.is_some() || self.u_high.is_some()) {
            return Err(Error::InvalidArgument(format!(
                "{} has no inputs: an input range does not apply",
                system.name()
            )));
        }
        check_pair("input", &self.u_low, &self.u_high, system.nu(), system)
    }
}

/// Checks one (low, high) pair of a region.
fn check_pair(
    what: &str,
    low: &Option<Vec<f64>>,
    high: &Option<Vec<f64>>,
    n: usize,
    system: &dyn System,
) -> Result<()> {
    let (lo, hi) = match (low, high) {
        (None, None) => return Ok(()),
        (Some(lo), Some(hi)) => (lo, hi),
        _ => {
            return Err(Error::InvalidArgument(format!(
                "the {what} range needs both its low and its high bounds"
            )))
        }
    };
    for (side, v) in [("low", lo), ("high", hi)] {
        if v.len() != n {
            return Err(Error::dimension(
                format!("{what} {side} bounds of {}", system.name()),
                n,
                v.len(),
            ));
        }
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            return Err(Error::InvalidArgument(format!(
                "{what} {side} bound {i} is {} (bounds must be finite)",
                v[i]
            )));
        }
    }
    if let Some(i) = (0..n).find(|&i| lo[i] > hi[i]) {
        return Err(Error::InvalidArgument(format!(
            "{what} bounds are crossed at component {i}: low {} > high {}",
            lo[i], hi[i]
        )));
    }
    Ok(())
}

/// A system whose sampling distributions are replaced by a [`DataRegion`]; everything else
/// (dynamics, names, dt) is the wrapped system's. Built by [`InRegion::new`], which checks the
/// region.
pub struct InRegion<'a> {
    inner: &'a dyn System,
    region: DataRegion,
}

impl<'a> InRegion<'a> {
    /// Wraps `system` with `region` (checked with [`DataRegion::check`]).
    pub fn new(system: &'a dyn System, region: DataRegion) -> Result<InRegion<'a>> {
        region.check(system)?;
        Ok(InRegion {
            inner: system,
            region,
        })
    }

    /// The region.
    pub fn region(&self) -> &DataRegion {
        &self.region
    }
}

impl System for InRegion<'_> {
    fn name(&self) -> &str {
        self.inner.name()
    }
    fn nx(&self) -> usize {
        self.inner.nx()
    }
    fn nu(&self) -> usize {
        self.inner.nu()
    }
    fn dt(&self) -> f64 {
        self.inner.dt()
    }
    fn state_names(&self) -> Vec<String> {
        self.inner.state_names()
    }
    fn input_names(&self) -> Vec<String> {
        self.inner.input_names()
    }
    fn input_bounds(&self) -> (Vec<f64>, Vec<f64>) {
        match (&self.region.u_low, &self.region.u_high) {
            (Some(lo), Some(hi)) => (lo.clone(), hi.clone()),
            _ => self.inner.input_bounds(),
        }
    }
    fn angle_indices(&self) -> Vec<usize> {
        self.inner.angle_indices()
    }
    fn window_steps(&self) -> usize {
        self.inner.window_steps()
    }
    fn sample_initial_state(&self, rng: &mut Rng) -> Vec<f64> {
        match (&self.region.x0_low, &self.region.x0_high) {
            (Some(lo), Some(hi)) => lo
                .iter()
                .zip(hi)
                .map(|(&l, &h)| rng.uniform(l, h))
                .collect(),
            _ => self.inner.sample_initial_state(rng),
        }
    }
    fn sample_input(&self, rng: &mut Rng) -> Vec<f64> {
        match (&self.region.u_low, &self.region.u_high) {
            (Some(lo), Some(hi)) => lo
                .iter()
                .zip(hi)
                .map(|(&l, &h)| rng.uniform(l, h))
                .collect(),
            _ => self.inner.sample_input(rng),
        }
    }
    fn parameters(&self) -> String {
        self.inner.parameters()
    }
    fn step(&self, x: &[f64], u: &[f64], x_next: &mut [f64]) {
        self.inner.step(x, u, x_next)
    }
}

#[cfg(test)]
mod tests;
