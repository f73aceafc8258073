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
mod tests {
    use super::*;
    use crate::data::{generate_splits, SplitSpec, Splits};
    use crate::systems::by_name;
    use std::f64::consts::PI;

    /// FNV-1a over the bits of the values (the golden values below were computed with numpy
    /// from the files `koopbridge data gen` wrote before regions existed).
    fn fnv(parts: &[&[f64]]) -> u64 {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        for v in parts.iter().flat_map(|p| p.iter()) {
            h ^= v.to_bits();
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
        h
    }

    fn small(region: Option<DataRegion>) -> SplitSpec {
        SplitSpec {
            windows: 90,
            train: 70,
            val: 10,
            test: 10,
            region,
            ..SplitSpec::default()
        }
    }

    /// The double-pendulum control task's region (issue 12 §3).
    fn task_region() -> DataRegion {
        DataRegion {
            x0_low: Some(vec![-0.2, -1.0, -2.0, -2.0]),
            x0_high: Some(vec![1.4, 0.2, 2.0, 2.0]),
            u_low: Some(vec![-40.0, -40.0]),
            u_high: Some(vec![40.0, 40.0]),
        }
    }

    #[test]
    fn default_generation_is_bitwise_unchanged() {
        let golden = [
            ("double", 0x3d3d_ef82_29cd_c7ba_u64),
            ("damped", 0x3a5d_bbc3_3a58_ed92),
            ("polynomial", 0x62c8_0187_d64c_ad89),
        ];
        for (env, want) in golden {
            let s = by_name(env).unwrap();
            let sp = generate_splits(s.as_ref(), &small(None)).unwrap();
            assert_eq!(fnv(&[&sp.train.x, &sp.train.u]), want, "{env} moved");
            assert_eq!(sp.train.meta.region, None);
            let json = serde_json::to_string(&sp.train.meta).unwrap();
            assert!(!json.contains("region"), "{json}");
        }
        // A region equal to SPEC's own box draws the same numbers in the same order.
        let s = by_name("double").unwrap();
        let spec_box = DataRegion {
            x0_low: Some(vec![-0.1 * PI, -0.1 * PI, -1.0, -1.0]),
            x0_high: Some(vec![0.1 * PI, 0.1 * PI, 1.0, 1.0]),
            u_low: Some(vec![-6.0, -6.0]),
            u_high: Some(vec![6.0, 6.0]),
        };
        let sp = generate_splits(s.as_ref(), &small(Some(spec_box))).unwrap();
        assert_eq!(fnv(&[&sp.train.x, &sp.train.u]), golden[0].1);
    }

    #[test]
    fn every_window_starts_in_the_region_with_inputs_in_bounds() {
        let s = by_name("double").unwrap();
        let region = task_region();
        let spec = SplitSpec {
            windows: 600,
            train: 400,
            val: 100,
            test: 100,
            ..small(Some(region.clone()))
        };
        let sp = generate_splits(s.as_ref(), &spec).unwrap();
        let (lo, hi) = (region.x0_low.unwrap(), region.x0_high.unwrap());
        let (mut beyond_spec, mut big_input) = (0, 0);
        let mut y = [0.0; 4];
        for d in [&sp.train, &sp.val, &sp.test] {
            assert_eq!(d.meta.region, Some(task_region()));
            for i in 0..d.n {
                let x0 = d.state(i, 0);
                for k in 0..4 {
                    assert!(lo[k] <= x0[k] && x0[k] <= hi[k], "window {i}: {x0:?}");
                }
                beyond_spec += usize::from(x0[0] > 0.1 * PI);
                for t in 0..d.steps {
                    let u = d.input(i, t);
                    assert!(u.iter().all(|v| v.abs() <= 40.0), "{u:?}");
                    big_input += usize::from(u.iter().any(|v| v.abs() > 6.0));
                    // Still the true system, aligned pairing.
                    s.step(d.state(i, t), u, &mut y);
                    assert_eq!(&y[..], d.state(i, t + 1));
                }
            }
        }
        // The region is used, not SPEC's box (θ1 > 0.1π for ~60% of the windows, |u| > 6 for
        // ~98% of the steps).
        assert!(beyond_spec > 250, "{beyond_spec}");
        assert!(big_input > 8000, "{big_input}");
        // The region survives the files.
        let dir = std::env::temp_dir().join(format!("koopman-region-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        sp.save(&dir).unwrap();
        assert_eq!(Splits::load(&dir).unwrap(), sp);
        let side = std::fs::read_to_string(dir.join("train.json")).unwrap();
        assert!(
            side.contains("\"region\"") && side.contains("\"x0_high\""),
            "{side}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn from_parts_builds_checks_and_refuses() {
        let s = by_name("double").unwrap();
        let s = s.as_ref();
        let v = |x: &[f64]| Some(x.to_vec());
        assert_eq!(
            DataRegion::from_parts(s, (None, None), (None, None), None).unwrap(),
            None
        );
        let r = DataRegion::from_parts(s, (None, None), (None, None), Some(40.0))
            .unwrap()
            .unwrap();
        assert_eq!(
            (r.u_low, r.u_high, r.x0_low),
            (v(&[-40.0, -40.0]), v(&[40.0, 40.0]), None)
        );
        let x0 = (v(&[-0.2, -1.0, -2.0, -2.0]), v(&[1.4, 0.2, 2.0, 2.0]));
        let ok = DataRegion::from_parts(s, x0.clone(), (None, None), Some(40.0)).unwrap();
        assert_eq!(ok, Some(task_region()));
        let bad: Vec<(_, _, Option<f64>)> = vec![
            // wrong lengths
            ((v(&[0.0; 3]), v(&[1.0; 3])), (None, None), None),
            (x0.clone(), (v(&[-1.0]), v(&[1.0])), None),
            // crossed bounds
            (
                (v(&[0.0, 1.0, 0.0, 0.0]), v(&[1.0, 0.5, 1.0, 1.0])),
                (None, None),
                None,
            ),
            (x0.clone(), (v(&[1.0, 1.0]), v(&[-1.0, 2.0])), None),
            // NaN and infinity
            (
                (v(&[f64::NAN, 0.0, 0.0, 0.0]), v(&[1.0; 4])),
                (None, None),
                None,
            ),
            (
                x0.clone(),
                (v(&[-1.0, -1.0]), v(&[1.0, f64::INFINITY])),
                None,
            ),
            ((None, None), (None, None), Some(f64::NAN)),
            ((None, None), (None, None), Some(-3.0)),
            // one side only, or both forms of the input range
            ((v(&[0.0; 4]), None), (None, None), None),
            ((None, None), (None, v(&[1.0, 1.0])), None),
            ((None, None), (v(&[-1.0, -1.0]), v(&[1.0, 1.0])), Some(2.0)),
        ];
        for (i, (x0, u, b)) in bad.into_iter().enumerate() {
            let err = DataRegion::from_parts(s, x0, u, b);
            assert!(err.is_err(), "case {i} accepted: {err:?}");
        }
        // A system without inputs takes no input range, and InRegion re-checks.
        let p = by_name("polynomial").unwrap();
        assert!(DataRegion::from_parts(p.as_ref(), (None, None), (None, None), Some(1.0)).is_err());
        let crossed = DataRegion {
            u_low: v(&[1.0, 1.0]),
            u_high: v(&[0.0, 0.0]),
            ..DataRegion::default()
        };
        assert!(InRegion::new(s, crossed.clone()).is_err());
        assert!(generate_splits(s, &small(Some(crossed))).is_err());
    }
}
