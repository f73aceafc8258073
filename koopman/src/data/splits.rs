//! The SPEC split: generate a pool of windows with one data seed, shuffle it, and cut it into
//! train pool / validation / test (140,000 / 20,000 / 20,000 of 180,000 by default).

use super::region::{DataRegion, InRegion};
use super::{generate_with_progress, Dataset, Pairing};
use crate::rng::Rng;
use crate::systems::System;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// What to generate and how to split it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SplitSpec {
    /// Total windows (must equal train + val + test).
    pub windows: usize,
    /// Train pool size.
    pub train: usize,
    /// Validation size.
    pub val: usize,
    /// Test size.
    pub test: usize,
    /// Data seed (generation and shuffle).
    pub seed: u64,
    /// Input pairing.
    pub pairing: Pairing,
    /// Transitions per window; `None` = the system's own T (15, or 1 for the polynomial system).
    pub steps: Option<usize>,
    /// Initial states and inputs of a region of one's choosing instead of the system's SPEC
    /// distributions (`None`, the default: SPEC's data, bit for bit); recorded as `region` in
    /// every split's metadata.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub region: Option<DataRegion>,
}

impl Default for SplitSpec {
    /// SPEC.md: 180,000 windows, seed 42, 140k/20k/20k, aligned pairing.
    fn default() -> Self {
        SplitSpec {
            windows: 180_000,
            train: 140_000,
            val: 20_000,
            test: 20_000,
            seed: 42,
            pairing: Pairing::Aligned,
            steps: None,
            region: None,
        }
    }
}

/// Train pool, validation and test sets.
#[derive(Clone, Debug, PartialEq)]
pub struct Splits {
    /// Train pool (a run with m samples takes its first m windows).
    pub train: Dataset,
    /// Validation set.
    pub val: Dataset,
    /// Test set.
    pub test: Dataset,
}

/// The stream that shuffles the pool: independent of every window's stream.
const SHUFFLE_STREAM: u64 = u64::MAX;

/// Generates `spec.windows` windows, shuffles them with the data seed and splits them.
pub fn generate_splits(system: &dyn System, spec: &SplitSpec) -> Result<Splits> {
    generate_splits_with_progress(system, spec, &|_| {})
}

/// Like [`generate_splits`], reporting generated windows through `progress`.
pub fn generate_splits_with_progress(
    system: &dyn System,
    spec: &SplitSpec,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Splits> {
    if spec.train == 0 || spec.val == 0 || spec.test == 0 {
        return Err(Error::InvalidArgument(
            "train, validation and test sizes must all be positive".into(),
        ));
    }
    let total = spec
        .train
        .checked_add(spec.val)
        .and_then(|s| s.checked_add(spec.test));
    if total != Some(spec.windows) {
        return Err(Error::InvalidArgument(format!(
            "train + val + test = {} + {} + {} must equal the number of windows {}",
            spec.train, spec.val, spec.test, spec.windows
        )));
    }
    let steps = spec.steps.unwrap_or_else(|| system.window_steps());
    let in_region = spec
        .region
        .clone()
        .map(|r| InRegion::new(system, r))
        .transpose()?;
    let sampled: &dyn System = match &in_region {
        Some(s) => s,
        None => system,
    };
    let mut all = generate_with_progress(
        sampled,
        spec.windows,
        steps,
        spec.seed,
        spec.pairing,
        progress,
    )?;
    all.meta.region = spec.region.clone();
    let mut order: Vec<usize> = (0..spec.windows).collect();
    Rng::derive(spec.seed, SHUFFLE_STREAM).shuffle(&mut order);
    let (a, rest) = order.split_at(spec.train);
    let (b, c) = rest.split_at(spec.val);
    Ok(Splits {
        train: all.select(a)?,
        val: all.select(b)?,
        test: all.select(c)?,
    })
}

impl Splits {
    /// Writes `train.npz`, `val.npz` and `test.npz` (with sidecars) into `dir`, atomically each.
    pub fn save(&self, dir: &Path) -> Result<()> {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        self.train.save_npz(&dir.join("train.npz"))?;
        self.val.save_npz(&dir.join("val.npz"))?;
        self.test.save_npz(&dir.join("test.npz"))
    }

    /// Reads the three files written by [`Splits::save`] and checks that they agree on T, nx, nu.
    pub fn load(dir: &Path) -> Result<Splits> {
        let train = Dataset::load_npz(&dir.join("train.npz"))?;
        let val = Dataset::load_npz(&dir.join("val.npz"))?;
        let test = Dataset::load_npz(&dir.join("test.npz"))?;
        for (name, d) in [("val", &val), ("test", &test)] {
            if (d.steps, d.nx, d.nu) != (train.steps, train.nx, train.nu) {
                return Err(Error::format(
                    dir.join(format!("{name}.npz")),
                    format!(
                        "T={}, nx={}, nu={} differs from train.npz (T={}, nx={}, nu={})",
                        d.steps, d.nx, d.nu, train.steps, train.nx, train.nu
                    ),
                ));
            }
        }
        Ok(Splits { train, val, test })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::systems::by_name;

    #[test]
    fn splits_partition_a_shuffled_pool() {
        let s = by_name("polynomial").unwrap();
        let spec = SplitSpec {
            windows: 90,
            train: 70,
            val: 10,
            test: 10,
            ..SplitSpec::default()
        };
        let sp = generate_splits(s.as_ref(), &spec).unwrap();
        assert_eq!((sp.train.n, sp.val.n, sp.test.n), (70, 10, 10));
        assert_eq!(sp.train.steps, 1);
        assert_eq!(sp.train.meta.source, "koopman::systems (n_poly=5)");
        let pool = crate::data::generate(s.as_ref(), 90, 1, 42, Pairing::Aligned).unwrap();
        // Every window of the pool appears exactly once across the splits, and the order changed.
        let key = |d: &Dataset, i: usize| {
            d.state(i, 0)
                .iter()
                .map(|v| v.to_bits())
                .collect::<Vec<_>>()
        };
        let mut seen: Vec<Vec<u64>> = Vec::new();
        for d in [&sp.train, &sp.val, &sp.test] {
            for i in 0..d.n {
                seen.push(key(d, i));
            }
        }
        let mut orig: Vec<Vec<u64>> = (0..90).map(|i| key(&pool, i)).collect();
        assert_ne!(seen, orig, "pool was not shuffled");
        seen.sort();
        orig.sort();
        assert_eq!(seen, orig);
        let bad = SplitSpec {
            train: 71,
            ..spec.clone()
        };
        assert!(generate_splits(s.as_ref(), &bad).is_err());
    }

    #[test]
    fn save_and_load_directory() {
        let s = by_name("damped").unwrap();
        let spec = SplitSpec {
            windows: 30,
            train: 20,
            val: 5,
            test: 5,
            pairing: Pairing::Reference,
            ..SplitSpec::default()
        };
        let sp = generate_splits(s.as_ref(), &spec).unwrap();
        let dir = std::env::temp_dir().join(format!("koopman-splits-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        sp.save(&dir).unwrap();
        let back = Splits::load(&dir).unwrap();
        assert_eq!(back, sp);
        assert_eq!(back.train.meta.pairing, Pairing::Reference);
        std::fs::remove_file(dir.join("val.npz")).unwrap();
        assert!(matches!(Splits::load(&dir), Err(Error::Io { .. })));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
