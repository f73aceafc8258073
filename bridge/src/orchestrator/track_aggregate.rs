//! On-policy aggregation of tracking tasks (`koopbridge run --aggregate ROUNDS` with `[control]`
//! entries marked `aggregate = true`, the legged robots' Strategy III): each round retrains a
//! simulator's model on its collected training windows plus every on-policy window the
//! aggregation tasks' closed loops have left so far, then runs every tracking task again with the
//! retrained model; each round's tables beside the previous one's.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::path::PathBuf;

use koopman::data::Dataset;
use serde::{Deserialize, Serialize};

use super::aggregate::union;
use super::commands::Placeholders;
use super::tracking::{tracking_phase, ReplayCache, TrackReport, TrackingPhase};
use super::train::{train_model_as, TrainReport};
use super::{Cluster, Event, RunOptions};
use crate::client::SimClient;
use crate::error::{Error, Result};
use crate::scenario::Scenario;
use crate::services::model_kind::ModelKind;

/// One simulator's model of one kind, retrained in one round.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RetrainedSim {
    /// Simulator id.
    pub sim: String,
    /// The model kind.
    pub kind: String,
    /// On-policy windows added in this round (from the previous pass's aggregation tasks).
    pub added_windows: usize,
    /// Training windows of the retrained model (collected + every on-policy window so far).
    pub train_windows: usize,
    /// The retrained model's training.
    pub train: TrainReport,
}

/// One aggregation round of the tracking tasks.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TrackingRound {
    /// Round number, from 1.
    pub round: usize,
    /// The retrained simulators.
    pub sims: Vec<RetrainedSim>,
    /// Every tracking task again, with the retrained models.
    pub tracking: Vec<TrackReport>,
}

/// The on-policy windows the aggregation tasks' model rows left in `pass`, by simulator and
/// model kind (each kind's model retrains on its own closed loops).
pub fn onpolicy_paths(pass: &[TrackReport]) -> BTreeMap<(String, String), Vec<PathBuf>> {
    let mut out: BTreeMap<(String, String), Vec<PathBuf>> = BTreeMap::new();
    for t in pass.iter().filter(|t| t.aggregate) {
        for r in &t.rows {
            let (Some(kind), Some(path)) =
                (&r.kind, r.onpolicy.as_ref().and_then(|o| o.path.clone()))
            else {
                continue;
            };
            out.entry((t.sim.clone(), kind.clone()))
                .or_default()
                .push(path);
        }
    }
    out
}

/// The model of simulator `sim` and kind `kind` after round `round` (round 0: the scenario's).
pub fn round_model(sc: &Scenario, sim: &str, kind: ModelKind, round: usize) -> String {
    match round {
        0 => sc.model_name(sim, kind),
        r => format!("{}-agg{r}", sc.model_name(sim, kind)),
    }
}

/// Runs `rounds` aggregation rounds after the first tracking pass `first` (its replay rows in
/// `replays`, reused: they do not depend on the model): every model kind of `kinds` whose
/// aggregation rows left windows is retrained on its own.
#[allow(clippy::too_many_arguments)]
pub fn aggregate_tracking(
    sc: &Scenario,
    opts: &RunOptions,
    cluster: &Cluster,
    clients: &mut [SimClient],
    ph: &Placeholders,
    (first, replays): (&[TrackReport], &RefCell<ReplayCache>),
    kinds: &[ModelKind],
    rounds: usize,
    on: &mut dyn FnMut(Event<'_>),
) -> Result<Vec<TrackingRound>> {
    let mut pools: BTreeMap<(String, String), Vec<Dataset>> = BTreeMap::new();
    // The round of each (simulator, kind)'s newest model.
    let mut latest: BTreeMap<(String, String), usize> = BTreeMap::new();
    let mut pass = first.to_vec();
    let mut out = Vec::new();
    for round in 1..=rounds {
        on(Event::Phase(&format!(
            "aggregation round {round}/{rounds}: retraining on the collected data + the \
             aggregation tasks' closed loops"
        )));
        let mut sims = Vec::new();
        for ((sim, kind_name), paths) in onpolicy_paths(&pass) {
            let Some(&kind) = kinds.iter().find(|k| k.name() == kind_name) else {
                continue;
            };
            let dir = opts.out_dir.join("data").join(&sim);
            let pool = match pools.entry((sim.clone(), kind_name.clone())) {
                std::collections::btree_map::Entry::Occupied(e) => e.into_mut(),
                std::collections::btree_map::Entry::Vacant(e) => {
                    e.insert(vec![Dataset::load_npz(&dir.join("train.npz"))?])
                }
            };
            let mut added = 0;
            for p in &paths {
                let d = Dataset::load_npz(p)?;
                added += d.n;
                pool.push(d);
            }
            let all = union(pool)?;
            let model = round_model(sc, &sim, kind, round);
            let path = dir.join(format!("train-{model}.npz"));
            all.save_npz(&path)?;
            let train = train_model_as(sc, opts, cluster, &sim, kind, &model, &path, on)?;
            sims.push(RetrainedSim {
                sim,
                kind: kind_name,
                added_windows: added,
                train_windows: all.n,
                train,
            });
        }
        if sims.is_empty() {
            return Err(Error::Config(
                "--aggregate: no tracking task with `aggregate = true` left on-policy windows \
                 (every closed loop ended before one window of onpolicy_steps)"
                    .into(),
            ));
        }
        for s in &sims {
            latest.insert((s.sim.clone(), s.kind.clone()), round);
        }
        let model_of = |id: &str, k: ModelKind| {
            let r = latest.get(&(id.to_string(), k.name().to_string()));
            round_model(sc, id, k, r.copied().unwrap_or(0))
        };
        let tracking = tracking_phase(
            sc,
            &cluster.client,
            &cluster.live,
            clients,
            ph,
            &TrackingPhase {
                out_dir: &opts.out_dir,
                kinds,
                model_of: &model_of,
                pretrained: &[],
                aggregating: true,
                replays,
                view: &cluster.view,
            },
            on,
        )?;
        pass = tracking.clone();
        out.push(TrackingRound {
            round,
            sims,
            tracking,
        });
    }
    Ok(out)
}

/// Each round's model rows beside the first pass's, as text: per task and simulator, the mean
/// survival (or tracking RMS without a survival metric) of the first pass and of every round.
pub fn rounds_table(first: &[TrackReport], rounds: &[TrackingRound]) -> String {
    let figure = |t: &TrackReport| -> String {
        t.rows
            .iter()
            .filter(|r| r.model.is_some())
            .map(|r| match &r.survival {
                Some(s) => format!("{:.1}", s.mean),
                None => format!(
                    "rms {:.4}",
                    r.tracking_rms.iter().sum::<f64>() / r.tracking_rms.len().max(1) as f64
                ),
            })
            .collect::<Vec<_>>()
            .join(" / ")
    };
    let mut s = String::new();
    for (i, t) in first.iter().enumerate() {
        let mut line = format!(
            "{}{}: {}",
            t.sim,
            t.label
                .as_ref()
                .map_or(String::new(), |l| format!(" [{l}]")),
            figure(t)
        );
        for r in rounds {
            if let Some(tr) = r.tracking.get(i) {
                line += &format!(" -> round {}: {}", r.round, figure(tr));
            }
        }
        s += &line;
        s.push('\n');
    }
    s
}
