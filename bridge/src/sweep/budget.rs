//! The data budget m = c·N·ln N of a scaling sweep: the paper's heuristic (c = 40), the windows a
//! budget point trains on, and the record of a run's budget factors in its run folder.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// The paper's budget factor: m ≳ 40 · N · ln N training windows for a rank-N embedding.
pub const PAPER_BUDGET: f64 = 40.0;

/// The paper's data-budget heuristic for a rank-n embedding: m ≳ 40 · n · ln n training windows
/// (n ≥ 2; 40 for n ≤ 1, where ln n vanishes).
pub fn data_budget(latent_dim: usize) -> f64 {
    data_budget_for(PAPER_BUDGET, latent_dim)
}

/// The data budget c · n · ln n of a rank-n embedding (n ≥ 2; c for n ≤ 1, where ln n vanishes).
pub fn data_budget_for(c: f64, latent_dim: usize) -> f64 {
    let n = latent_dim.max(1) as f64;
    if n <= 1.0 {
        c
    } else {
        c * n * n.ln()
    }
}

/// The training windows of a budget point: ⌈c · n · ln n⌉, at least 1.
pub fn budget_windows(c: f64, latent_dim: usize) -> usize {
    (data_budget_for(c, latent_dim).ceil() as usize).max(1)
}

/// Checks budget factors: each finite and positive.
pub fn check_budgets(budgets: &[f64]) -> Result<()> {
    match budgets.iter().find(|c| !(c.is_finite() && **c > 0.0)) {
        Some(c) => Err(Error::Config(format!(
            "--budget {c}: a budget factor c must be a positive number (m = c·N·ln N)"
        ))),
        None => Ok(()),
    }
}

/// The dataset facts the budget points need.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DataShape {
    /// State dimension nx (N = nx · (1 + n_mult)).
    pub nx: usize,
    /// Windows in the train pool: the most a point can train on.
    pub pool: usize,
}

/// One (c, n_mult) cell of a budget sweep.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BudgetCell {
    /// Budget factor c.
    pub c: f64,
    /// Encoder width multiplier.
    pub n_mult: usize,
    /// Latent dimension N = nx · (1 + n_mult).
    pub latent_dim: usize,
    /// ⌈c · N · ln N⌉.
    pub wanted: usize,
    /// The windows the point trains on: `wanted`, capped at the train pool.
    pub m: usize,
}

impl BudgetCell {
    /// The cell of factor `c` at `n_mult` on data of this shape.
    pub fn new(c: f64, n_mult: usize, shape: DataShape) -> Self {
        let latent_dim = shape.nx * (1 + n_mult);
        let wanted = budget_windows(c, latent_dim);
        BudgetCell {
            c,
            n_mult,
            latent_dim,
            wanted,
            m: wanted.min(shape.pool),
        }
    }

    /// Whether the budget exceeds the pool (the point is then the full-data point).
    pub fn capped(&self) -> bool {
        self.m < self.wanted
    }
}

/// Adds `budgets` to the `"budgets"` lists of a run folder's `result.json` and `metrics.json`
/// (each a union, in ascending order; a missing file is passed over): a point trained earlier —
/// as a fixed-m point or on another budget curve — is then found on this curve too by
/// `koopbridge scaling --over budget`.
pub fn record_budgets(dir: &Path, budgets: &[f64]) -> Result<()> {
    if budgets.is_empty() {
        return Ok(());
    }
    for file in ["result.json", "metrics.json"] {
        let path = dir.join(file);
        let Ok(bytes) = std::fs::read(&path) else {
            continue;
        };
        let bad = |e: String| Error::Config(format!("{}: {e}", path.display()));
        let mut v: serde_json::Value =
            serde_json::from_slice(&bytes).map_err(|e| bad(e.to_string()))?;
        let obj = v
            .as_object_mut()
            .ok_or_else(|| bad("not a JSON object".into()))?;
        let mut all: Vec<f64> = obj
            .get("budgets")
            .and_then(|b| b.as_array())
            .map(|a| a.iter().filter_map(|x| x.as_f64()).collect())
            .unwrap_or_default();
        let before = all.len();
        for c in budgets {
            if !all.contains(c) {
                all.push(*c);
            }
        }
        if all.len() == before {
            continue;
        }
        all.sort_by(f64::total_cmp);
        obj.insert("budgets".into(), serde_json::json!(all));
        let out = serde_json::to_vec_pretty(&v).map_err(|e| bad(e.to_string()))?;
        koopman::fsutil::write_atomic(&path, &out)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn data_budget_is_40_n_ln_n() {
        assert!((data_budget(34) - 40.0 * 34.0 * 34f64.ln()).abs() < 1e-9);
        assert_eq!(data_budget(1), 40.0);
        // N = 34 (damped pendulum, n_mult 16) needs ~4.8k windows; m = 1000 is below it.
        assert!(data_budget(34) > 4000.0 && data_budget(34) < 5000.0);
    }

    #[test]
    fn budget_windows_are_the_ceiling_of_c_n_ln_n() {
        // Closed form, computed independently (python: math.ceil(c*n*math.log(n))).
        for (n, want) in [
            (4, [6, 56, 222]),
            (10, [24, 231, 922]),
            (34, [120, 1199, 4796]),
        ] {
            for (c, w) in [1.0, 10.0, 40.0].into_iter().zip(want) {
                assert_eq!(budget_windows(c, n), w, "c = {c}, N = {n}");
            }
        }
        assert_eq!(budget_windows(1.0, 1), 1);
        assert_eq!(budget_windows(0.01, 2), 1, "never 0 windows");
    }

    #[test]
    fn cells_are_capped_at_the_pool() {
        let shape = DataShape { nx: 2, pool: 1000 };
        let small = BudgetCell::new(10.0, 1, shape);
        assert_eq!((small.latent_dim, small.m, small.capped()), (4, 56, false));
        let big = BudgetCell::new(40.0, 16, shape);
        assert_eq!(
            (big.latent_dim, big.wanted, big.m, big.capped()),
            (34, 4796, 1000, true)
        );
    }

    #[test]
    fn bad_factors_are_refused() {
        for c in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(check_budgets(&[1.0, c]).is_err(), "{c}");
        }
        check_budgets(&[0.5, 40.0]).unwrap();
    }

    #[test]
    fn budgets_are_merged_into_the_run_files() {
        let dir = std::env::temp_dir().join(format!("koopbridge-budget-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("result.json"), r#"{"name": "p", "m": 56}"#).unwrap();
        std::fs::write(dir.join("metrics.json"), r#"{"budgets": [40.0]}"#).unwrap();
        let read = |f: &str| -> serde_json::Value {
            serde_json::from_slice(&std::fs::read(dir.join(f)).unwrap()).unwrap()
        };
        record_budgets(&dir, &[10.0]).unwrap();
        assert_eq!(read("result.json")["budgets"], serde_json::json!([10.0]));
        assert_eq!(
            read("metrics.json")["budgets"],
            serde_json::json!([10.0, 40.0])
        );
        record_budgets(&dir, &[40.0, 10.0]).unwrap();
        assert_eq!(
            read("result.json")["budgets"],
            serde_json::json!([10.0, 40.0])
        );
        assert_eq!(read("result.json")["m"], 56, "the other fields are kept");
        assert_eq!(
            read("metrics.json")["budgets"],
            serde_json::json!([10.0, 40.0])
        );
        std::fs::write(dir.join("result.json"), "[1]").unwrap();
        assert!(record_budgets(&dir, &[1.0]).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
