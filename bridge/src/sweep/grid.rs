//! The grid of a scaling sweep: every (m, n_mult, seed, regulariser) point of one dataset — m from
//! a fixed list and/or from budget curves m = c·N·ln N — each with a stable name (its model name in
//! the trainers' stores) and its training settings.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::budget::{check_budgets, BudgetCell, DataShape};
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
    /// Training windows m (the first m of the train pool); may be empty when `budgets` is not.
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
    /// Budget factors c: every n_mult also trains on m = ⌈c·N·ln N⌉ windows (N = nx·(1 + n_mult)),
    /// capped at the train pool. Absent in sweeps made before budgets existed.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub budgets: Vec<f64>,
    /// The dataset's nx and pool size, which budget points need.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shape: Option<DataShape>,
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
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
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
    /// The budget factors c whose curve m = c·N·ln N this point lies on (ascending; empty for a
    /// point of the fixed m list only). Not part of the name or the training: a budget point with
    /// the m of a fixed-m point is that point.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub budgets: Vec<f64>,
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
    /// The (c, n_mult) cells of the budget curves, c-major in the order given (duplicates
    /// dropped). Errors on a bad factor, or on budgets without the data's shape.
    pub fn budget_cells(&self) -> Result<Vec<BudgetCell>> {
        if self.budgets.is_empty() {
            return Ok(Vec::new());
        }
        check_budgets(&self.budgets)?;
        let shape = self.shape.ok_or_else(|| {
            Error::Config("budget points need the dataset's nx and pool size (shape)".into())
        })?;
        let mut out = Vec::new();
        for &c in &uniq(&self.budgets) {
            for &n_mult in &uniq(&self.n_mult) {
                out.push(BudgetCell::new(c, n_mult, shape));
            }
        }
        Ok(out)
    }

    /// Every point, m-major (small m first, so the cheap points finish first), n_mult, seeds and
    /// regularisers each in the order given; duplicates in a list are dropped. The (m, n_mult)
    /// pairs are the fixed m list × n_mult plus one per budget cell; a budget cell with the m of
    /// another pair is that pair (one point, which lists every c it lies on). Errors on empty
    /// lists, a zero m or n_mult, a bad budget factor, or a dataset name that makes an invalid
    /// key chunk.
    pub fn points(&self) -> Result<Vec<SweepPoint>> {
        for (what, empty) in [
            (
                "--samples and --budget list",
                self.samples.is_empty() && self.budgets.is_empty(),
            ),
            ("--n-mult lists", self.n_mult.is_empty()),
            ("--seeds lists", self.seeds.is_empty()),
            ("--regularisers lists", self.regularisers.is_empty()),
        ] {
            if empty {
                return Err(Error::Config(format!("{what} nothing: the sweep is empty")));
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
        let n_mults = uniq(&self.n_mult);
        let rank = |n: usize| n_mults.iter().position(|&x| x == n).unwrap_or(0);
        // (m, rank of n_mult) -> the budget factors of that pair.
        let mut pairs: BTreeMap<(usize, usize), Vec<f64>> = BTreeMap::new();
        for &m in &self.samples {
            for &n_mult in &n_mults {
                pairs.entry((m, rank(n_mult))).or_default();
            }
        }
        for cell in self.budget_cells()? {
            let budgets = pairs.entry((cell.m, rank(cell.n_mult))).or_default();
            if !budgets.contains(&cell.c) {
                budgets.push(cell.c);
                budgets.sort_by(f64::total_cmp);
            }
        }
        let mut out = Vec::new();
        for ((m, k), budgets) in pairs {
            let n_mult = n_mults[k];
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
                        budgets: budgets.clone(),
                        name,
                    });
                }
            }
        }
        Ok(out)
    }
}

/// The list without its repeats, in the order of first appearance.
fn uniq<T: PartialEq + Copy>(v: &[T]) -> Vec<T> {
    let mut out: Vec<T> = Vec::new();
    for x in v {
        if !out.contains(x) {
            out.push(*x);
        }
    }
    out
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
            budgets: Vec::new(),
            shape: None,
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
        g.samples.clear();
        assert!(g
            .points()
            .unwrap_err()
            .to_string()
            .contains("--samples and --budget"));
        g.budgets = vec![10.0];
        assert!(g.points().unwrap_err().to_string().contains("shape"));
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

    /// A budget sweep on the damped pendulum's shape (nx = 2) with a pool of 4000 windows.
    fn budget_grid() -> SweepGrid {
        SweepGrid {
            samples: Vec::new(),
            n_mult: vec![1, 4, 16],
            seeds: vec![1],
            regularisers: vec![Regularisers::Both],
            budgets: vec![1.0, 10.0, 40.0],
            shape: Some(DataShape { nx: 2, pool: 4000 }),
            ..grid()
        }
    }

    #[test]
    fn budget_points_train_on_c_n_ln_n_windows_capped_at_the_pool() {
        let p = budget_grid().points().unwrap();
        // N = 4, 10, 34; m = ⌈c·N·ln N⌉ (closed form), c = 40 at N = 34 wants 4796 > 4000.
        let want: [(f64, usize, usize); 9] = [
            (1.0, 1, 6),
            (1.0, 4, 24),
            (1.0, 16, 120),
            (10.0, 1, 56),
            (10.0, 4, 231),
            (10.0, 16, 1199),
            (40.0, 1, 222),
            (40.0, 4, 922),
            (40.0, 16, 4000),
        ];
        assert_eq!(p.len(), want.len());
        for (c, n_mult, m) in want {
            let n = 2.0 * (1.0 + n_mult as f64);
            let closed = ((c * n * n.ln()).ceil() as usize).min(4000);
            assert_eq!(closed, m);
            let q = p
                .iter()
                .find(|q| q.n_mult == n_mult && q.budgets.contains(&c))
                .unwrap_or_else(|| panic!("no point for c = {c}, n_mult {n_mult}"));
            assert_eq!(q.m, m, "c = {c}, n_mult {n_mult}");
            assert_eq!(q.budgets, [c]);
            assert_eq!(q.config()["train_samples"], m);
            assert!(q.name.contains(&format!("-m{m}-n{n_mult}-")), "{}", q.name);
        }
        assert!(p.windows(2).all(|w| w[0].m <= w[1].m), "small m first");
        let names: std::collections::HashSet<_> = p.iter().map(|q| q.name.clone()).collect();
        assert_eq!(names.len(), p.len(), "names are unique");
        let cells = budget_grid().budget_cells().unwrap();
        let capped: Vec<_> = cells.iter().filter(|c| c.capped()).collect();
        assert_eq!(capped.len(), 1);
        assert_eq!((capped[0].c, capped[0].wanted), (40.0, 4796));
    }

    #[test]
    fn a_budget_point_with_the_m_of_another_point_is_that_point() {
        // The pool of 1000 caps both c = 10 and c = 40 at n_mult 16 (N = 34), and m = 1000 is
        // also on the fixed list: one point, on both curves, named and trained as the fixed-m
        // point of a sweep without budgets (so a rerun finds its run folder and skips it).
        let g = SweepGrid {
            samples: vec![1000],
            n_mult: vec![16],
            budgets: vec![40.0, 1.0, 10.0, 40.0],
            shape: Some(DataShape { nx: 2, pool: 1000 }),
            ..budget_grid()
        };
        let p = g.points().unwrap();
        let plain = SweepGrid {
            budgets: Vec::new(),
            shape: None,
            ..g.clone()
        }
        .points()
        .unwrap();
        assert_eq!(plain.len(), 1);
        assert_eq!(p.len(), 2, "c = 1 (m = 120) and the shared m = 1000 point");
        assert_eq!((p[0].m, p[0].budgets.clone()), (120, vec![1.0]));
        assert_eq!((p[1].m, p[1].budgets.clone()), (1000, vec![10.0, 40.0]));
        assert_eq!(p[1].name, plain[0].name);
        assert_eq!(p[1].config(), plain[0].config(), "the same training");
    }

    #[test]
    fn sweep_json_round_trips_and_old_files_still_load() {
        let g = budget_grid();
        let text = serde_json::to_string(&g).unwrap();
        assert!(text.contains("\"budgets\":[1.0,10.0,40.0]"), "{text}");
        assert_eq!(serde_json::from_str::<SweepGrid>(&text).unwrap(), g);
        // A sweep.json written before budgets existed.
        let old = r#"{"data": "damped-pendulum-reference", "samples": [1000, 4000],
            "n_mult": [16], "seeds": [17382], "regularisers": ["both"], "iterations": null,
            "settings": {}}"#;
        let g: SweepGrid = serde_json::from_str(old).unwrap();
        assert!(g.budgets.is_empty() && g.shape.is_none());
        let p = g.points().unwrap();
        assert_eq!(p[0].name, "damped-pendulum-reference-m1000-n16-s17382-both");
        assert!(p.iter().all(|q| q.budgets.is_empty()));
        // A fixed-m sweep still writes the file it wrote before.
        let text = serde_json::to_string(&g).unwrap();
        assert!(
            !text.contains("budgets") && !text.contains("shape"),
            "{text}"
        );
    }
}
