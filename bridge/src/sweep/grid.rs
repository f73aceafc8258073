//! The grid of a scaling sweep: every (m, n_mult, seed, regulariser) point of one dataset, each
//! with a stable name (its model name in the trainers' stores) and its training settings.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::keyexpr::validate_chunk;

/// Which auxiliary losses a point trains with (SPEC's ablation "base / +ctrl / +cov / +both").
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Regularisers {
    /// Inverse-control and covariance losses (the paper's headline runs).
    Both,
    /// Neither: the prediction loss alone ("base").
    None,
    /// The inverse-control loss only.
    Ctrl,
    /// The covariance loss only.
    Cov,
}

impl Regularisers {
    /// Every setting, in the order of the paper's ablation table.
    pub const ALL: [Regularisers; 4] = [
        Regularisers::None,
        Regularisers::Ctrl,
        Regularisers::Cov,
        Regularisers::Both,
    ];

    /// `(ctrl, cov)`: whether the inverse-control and the covariance loss are on.
    pub fn flags(self) -> (bool, bool) {
        match self {
            Regularisers::Both => (true, true),
            Regularisers::None => (false, false),
            Regularisers::Ctrl => (true, false),
            Regularisers::Cov => (false, true),
        }
    }

    /// The setting with these flags.
    pub fn from_flags(ctrl: bool, cov: bool) -> Self {
        match (ctrl, cov) {
            (true, true) => Regularisers::Both,
            (false, false) => Regularisers::None,
            (true, false) => Regularisers::Ctrl,
            (false, true) => Regularisers::Cov,
        }
    }

    /// Its name on the command line and in results (`both`, `none`, `ctrl`, `cov`).
    pub fn as_str(self) -> &'static str {
        match self {
            Regularisers::Both => "both",
            Regularisers::None => "none",
            Regularisers::Ctrl => "ctrl",
            Regularisers::Cov => "cov",
        }
    }

    /// The settings a grid trains on data with `nu` inputs: the names asked for, else `both`
    /// (`cov` for data without inputs, where the inverse-control loss has nothing to invert —
    /// asking for `ctrl` or `both` there is refused with the reason).
    pub fn for_data(asked: &[String], nu: usize) -> Result<Vec<Self>> {
        if asked.is_empty() {
            return Ok(vec![if nu == 0 {
                Regularisers::Cov
            } else {
                Regularisers::Both
            }]);
        }
        let parsed = asked
            .iter()
            .map(|r| Regularisers::parse(r))
            .collect::<Result<Vec<_>>>()?;
        if nu == 0 {
            if let Some(r) = parsed.iter().find(|r| r.flags().0) {
                return Err(Error::Config(format!(
                    "regulariser setting '{}': {}; use none or cov",
                    r.as_str(),
                    koopman::train::AUTONOMOUS_CTRL
                )));
            }
        }
        Ok(parsed)
    }

    /// Parses a name; the error lists the valid ones.
    pub fn parse(s: &str) -> Result<Self> {
        Regularisers::ALL
            .into_iter()
            .find(|r| r.as_str() == s.trim())
            .ok_or_else(|| {
                Error::Config(format!(
                    "unknown regulariser setting '{s}': expected one of both, none, ctrl, cov"
                ))
            })
    }
}

/// What a sweep spans. Every list must be non-empty; the grid is their Cartesian product.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SweepGrid {
    /// Short name of the dataset (`[a-z0-9-]`, e.g. `damped-pendulum-reference`): the prefix of
    /// every point's name.
    pub data: String,
    /// Training windows m (the first m of the train pool).
    pub samples: Vec<usize>,
    /// Encoder width multipliers n_mult (n_enc = n_mult · nx).
    pub n_mult: Vec<usize>,
    /// Training seeds.
    pub seeds: Vec<u64>,
    /// Regulariser settings.
    pub regularisers: Vec<Regularisers>,
    /// Training iterations of every point (None: SPEC's default).
    #[serde(default)]
    pub iterations: Option<usize>,
    /// Further `TrainConfig` fields shared by every point (e.g. `hidden`, `batch`); not the
    /// ones the grid sets.
    #[serde(default)]
    pub settings: serde_json::Map<String, serde_json::Value>,
}

/// `TrainConfig` fields that a sweep's grid sets itself (and `settings` may not).
pub const GRID_FIELDS: [&str; 6] = [
    "train_samples",
    "n_mult",
    "seed",
    "ctrl",
    "cov",
    "iterations",
];

/// One training of a sweep.
#[derive(Clone, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct SweepPoint {
    /// Training windows m.
    pub m: usize,
    /// Encoder width multiplier.
    pub n_mult: usize,
    /// Training seed.
    pub seed: u64,
    /// Auxiliary losses.
    pub regularisers: Regularisers,
    /// Training iterations (None: SPEC's default).
    pub iterations: Option<usize>,
    /// Further `TrainConfig` fields (the grid's `settings`).
    pub settings: serde_json::Map<String, serde_json::Value>,
    /// Its name: the model name in the trainer's store and the run folder's name.
    pub name: String,
}

impl SweepPoint {
    /// The trainer job's `config` fields (`koopman::train::TrainConfig` names).
    pub fn config(&self) -> serde_json::Map<String, serde_json::Value> {
        let (ctrl, cov) = self.regularisers.flags();
        let mut c = self.settings.clone();
        c.insert("train_samples".into(), self.m.into());
        c.insert("n_mult".into(), self.n_mult.into());
        c.insert("seed".into(), self.seed.into());
        c.insert("ctrl".into(), ctrl.into());
        c.insert("cov".into(), cov.into());
        if let Some(it) = self.iterations {
            c.insert("iterations".into(), it.into());
        }
        c
    }
}

impl SweepGrid {
    /// Every point, m-major (small m first, so the cheap points finish first), each list in the
    /// order given; duplicates in a list are dropped. Errors on an empty list, a zero m or
    /// n_mult, or a dataset name that makes an invalid key chunk.
    pub fn points(&self) -> Result<Vec<SweepPoint>> {
        fn uniq<T: PartialEq + Copy>(v: &[T]) -> Vec<T> {
            let mut out: Vec<T> = Vec::new();
            for x in v {
                if !out.contains(x) {
                    out.push(*x);
                }
            }
            out
        }
        for (what, empty) in [
            ("--samples", self.samples.is_empty()),
            ("--n-mult", self.n_mult.is_empty()),
            ("--seeds", self.seeds.is_empty()),
            ("--regularisers", self.regularisers.is_empty()),
        ] {
            if empty {
                return Err(Error::Config(format!(
                    "{what} lists nothing: the sweep is empty"
                )));
            }
        }
        if self.samples.contains(&0) || self.n_mult.contains(&0) {
            return Err(Error::Config("m and n_mult must be at least 1".into()));
        }
        if self.iterations == Some(0) {
            return Err(Error::Config("iterations must be at least 1".into()));
        }
        if let Some(k) = self
            .settings
            .keys()
            .find(|k| GRID_FIELDS.contains(&k.as_str()))
        {
            return Err(Error::Config(format!(
                "setting '{k}' is set by the sweep's grid; use its own option instead"
            )));
        }
        let mut samples = uniq(&self.samples);
        samples.sort_unstable();
        let mut out = Vec::new();
        for &m in &samples {
            for &n_mult in &uniq(&self.n_mult) {
                for &seed in &uniq(&self.seeds) {
                    for &regularisers in &uniq(&self.regularisers) {
                        let mut name = format!(
                            "{}-m{m}-n{n_mult}-s{seed}-{}",
                            self.data,
                            regularisers.as_str()
                        );
                        if let Some(it) = self.iterations {
                            name.push_str(&format!("-i{it}"));
                        }
                        validate_chunk("sweep point name", &name)?;
                        out.push(SweepPoint {
                            m,
                            n_mult,
                            seed,
                            regularisers,
                            iterations: self.iterations,
                            settings: self.settings.clone(),
                            name,
                        });
                    }
                }
            }
        }
        Ok(out)
    }
}

/// The paper's data-budget heuristic for a rank-n embedding: m ≳ 40 · n · ln n training windows
/// (n ≥ 2; 40 for n ≤ 1, where ln n vanishes).
pub fn data_budget(latent_dim: usize) -> f64 {
    let n = latent_dim.max(1) as f64;
    if n <= 1.0 {
        40.0
    } else {
        40.0 * n * n.ln()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> SweepGrid {
        SweepGrid {
            data: "damped-pendulum-reference".into(),
            samples: vec![4000, 1000, 1000],
            n_mult: vec![1, 16],
            seeds: vec![17382, 76849],
            regularisers: vec![Regularisers::Both, Regularisers::None],
            iterations: Some(500),
            settings: serde_json::Map::new(),
        }
    }

    #[test]
    fn grid_is_the_product_without_duplicates_small_m_first() {
        let p = grid().points().unwrap();
        assert_eq!(p.len(), 2 * 2 * 2 * 2);
        assert!(p[..8].iter().all(|q| q.m == 1000));
        assert!(p[8..].iter().all(|q| q.m == 4000));
        let names: std::collections::HashSet<_> = p.iter().map(|q| q.name.clone()).collect();
        assert_eq!(names.len(), p.len(), "names are unique");
        assert_eq!(
            p[0].name,
            "damped-pendulum-reference-m1000-n1-s17382-both-i500"
        );
    }

    #[test]
    fn config_says_what_the_point_is() {
        let p = &grid().points().unwrap()[1];
        assert_eq!(p.regularisers, Regularisers::None);
        let c = p.config();
        assert_eq!(c["train_samples"], 1000);
        assert_eq!(c["n_mult"], 1);
        assert_eq!(c["ctrl"], false);
        assert_eq!(c["cov"], false);
        assert_eq!(c["iterations"], 500);
        // Every field is a TrainConfig field (the trainer rejects unknown ones).
        let known = serde_json::to_value(koopman::train::TrainConfig::default()).unwrap();
        for k in c.keys() {
            assert!(known.get(k).is_some(), "{k} is not a TrainConfig field");
        }
    }

    #[test]
    fn bad_grids_are_errors() {
        let mut g = grid();
        g.seeds.clear();
        assert!(g.points().unwrap_err().to_string().contains("--seeds"));
        let mut g = grid();
        g.samples.push(0);
        assert!(g.points().is_err());
        let mut g = grid();
        g.settings.insert("seed".into(), 3.into());
        assert!(g.points().unwrap_err().to_string().contains("'seed'"));
        let mut g = grid();
        g.data = "Bad Name".into();
        assert!(g.points().is_err());
        assert!(Regularisers::parse("all")
            .unwrap_err()
            .to_string()
            .contains("both, none, ctrl, cov"));
    }

    #[test]
    fn data_without_inputs_default_to_cov_and_refuse_ctrl() {
        let names = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert_eq!(
            Regularisers::for_data(&[], 1).unwrap(),
            [Regularisers::Both]
        );
        assert_eq!(Regularisers::for_data(&[], 0).unwrap(), [Regularisers::Cov]);
        assert_eq!(
            Regularisers::for_data(&names(&["none", "cov"]), 0).unwrap(),
            [Regularisers::None, Regularisers::Cov]
        );
        for asked in [["none", "both"], ["ctrl", "cov"]] {
            let e = Regularisers::for_data(&names(&asked), 0)
                .unwrap_err()
                .to_string();
            assert!(e.contains("needs inputs") && e.contains("nu = 0"), "{e}");
        }
        assert_eq!(
            Regularisers::for_data(&names(&["ctrl"]), 2).unwrap(),
            [Regularisers::Ctrl]
        );
    }

    #[test]
    fn regularisers_round_trip() {
        for r in Regularisers::ALL {
            let (a, b) = r.flags();
            assert_eq!(Regularisers::from_flags(a, b), r);
            assert_eq!(Regularisers::parse(r.as_str()).unwrap(), r);
        }
    }

    #[test]
    fn data_budget_is_40_n_ln_n() {
        assert!((data_budget(34) - 40.0 * 34.0 * 34f64.ln()).abs() < 1e-9);
        assert_eq!(data_budget(1), 40.0);
        // N = 34 (damped pendulum, n_mult 16) needs ~4.8k windows; m = 1000 is below it.
        assert!(data_budget(34) > 4000.0 && data_budget(34) < 5000.0);
    }
}
