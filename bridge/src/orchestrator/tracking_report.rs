//! What a tracking task reports: its rows side by side ([`TrackReport`], [`TrackRow`]), paired
//! by reference, and the table they make ([`table`]).

use std::collections::BTreeMap;
use std::path::PathBuf;

use koopman::mpc::MpcConfig;
use serde::{Deserialize, Serialize};

use super::survival::Summary;
use crate::messages::Perturbation;
use crate::scenario::{PerturbationSpec, SurvivalSpec};

/// The name of the replay row.
pub const REPLAY_ROW: &str = "replay";

/// One tracking task's result: its rows side by side, paired by reference.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TrackReport {
    /// The simulator tracked.
    pub sim: String,
    /// The task's label (`None`: its rows are the models' names).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub label: Option<String>,
    /// The references file as read.
    pub references_file: String,
    /// How many references.
    pub references: usize,
    /// Steps per reference (the survival cap).
    pub steps: usize,
    /// The survival metric (absent: each run went to its end).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub survival: Option<SurvivalSpec>,
    /// Whether runs went on after the threshold was crossed.
    pub continue_after_failure: bool,
    /// Whether the models planned about each reference with its inputs as feed-forward.
    pub error_state: bool,
    /// Whether its closed loops are the training data of `--aggregate`.
    #[serde(default)]
    pub aggregate: bool,
    /// The perturbation of every episode, as the task gave it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub perturbation: Option<PerturbationSpec>,
    /// Each reference's perturbation as sent with its reset (the push drawn for it).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub perturbations: Vec<Perturbation>,
    /// The MPC's offset-free correction (restarted with every reference), as the task gave it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub offset_free: Option<koopman::mpc::OffsetFreeConfig>,
    /// The replay row first (when run), then one row per model kind.
    pub rows: Vec<TrackRow>,
}

/// One controller over every reference.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TrackRow {
    /// The row's name: [`REPLAY_ROW`], or the model's (`{model}+{label}`).
    pub row: String,
    /// The model (absent for the replay row).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<String>,
    /// Its kind (`koopman`, `edmd`, ...; absent for the replay row).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kind: Option<String>,
    /// The MPC settings it solved with (absent for the replay row).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mpc: Option<MpcConfig>,
    /// Survival steps per reference (empty without a survival metric).
    pub survivals: Vec<usize>,
    /// Their summary (`at_cap`: how many reached the cap).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub survival: Option<Summary>,
    /// References on which this row survived longer / shorter than the replay row.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub above_replay: Option<usize>,
    /// See `above_replay`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub below_replay: Option<usize>,
    /// Steps run per reference (a run stops at its first failure unless `continue_after_failure`).
    pub steps_run: Vec<usize>,
    /// Tracking RMS over every state and step run, per reference (angles wrapped).
    pub tracking_rms: Vec<f64>,
    /// The first reference's run, step by step: the error the survival metric scores (the mean
    /// |x − r| over its states; without a metric the error norm), for the plot.
    #[serde(default)]
    pub first_errors: Vec<f64>,
    /// Runs in which the simulator reported a fall (or refused a step).
    pub falls: usize,
    /// Median and 99th percentile of the solve time in the service, µs (0 for the replay row).
    pub solve_median_us: f64,
    /// See `solve_median_us`.
    pub solve_p99_us: f64,
    /// Solves that were not `solved`, by status.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub not_solved_by_status: BTreeMap<String, usize>,
    /// The simulator's refusals (the first ten), `reference i: message`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub sim_errors: Vec<String>,
    /// The closed loops as training windows (`.npz`, the dataset layout), for aggregation.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub onpolicy: Option<OnPolicy>,
    /// Seconds this row took.
    pub wall_s: f64,
}

/// Where a row's on-policy windows were written.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct OnPolicy {
    /// The `.npz` (absent when no run was long enough for a window).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub path: Option<PathBuf>,
    /// How many windows.
    pub windows: usize,
    /// Transitions per window.
    pub steps: usize,
}

/// The tracking tasks' rows as a Markdown table (one per task; the replay row first).
pub fn table(reports: &[TrackReport]) -> String {
    let mut s = String::new();
    for r in reports {
        let metric = match &r.survival {
            Some(m) => format!(
                "survival = steps until the mean |x − r| over states {:?} exceeds {} or a fall, capped at {}",
                m.states, m.threshold, r.steps
            ),
            None => format!("tracking RMS over {} steps", r.steps),
        };
        s += &format!(
            "Tracking '{}'{}: {} references from {} ({metric}{})\n\n",
            r.sim,
            r.label
                .as_ref()
                .map_or(String::new(), |l| format!(" [{l}]")),
            r.references,
            r.references_file,
            if r.error_state {
                "; error-state MPC"
            } else {
                ""
            }
        );
        s += "| row | mean | sem | median | q25-q75 | min-max | at cap | above / below replay | falls | tracking RMS (mean) | solve median (p99) µs |\n";
        s += "|---|---|---|---|---|---|---|---|---|---|---|\n";
        for row in &r.rows {
            let sv = row.survival.clone().unwrap_or_default();
            let rms = row.tracking_rms.iter().sum::<f64>() / row.tracking_rms.len().max(1) as f64;
            let vs = match (row.above_replay, row.below_replay) {
                (Some(a), Some(b)) => format!("{a} / {b}"),
                _ => "-".into(),
            };
            let solve = if row.model.is_some() {
                format!("{:.0} ({:.0})", row.solve_median_us, row.solve_p99_us)
            } else {
                "-".into()
            };
            if row.survival.is_some() {
                s += &format!(
                    "| {} | {:.1} | {:.1} | {} | {}-{} | {}-{} | {} | {vs} | {} | {rms:.4} | {solve} |\n",
                    row.row, sv.mean, sv.sem, sv.median, sv.q25, sv.q75, sv.min, sv.max,
                    sv.at_cap.unwrap_or(0), row.falls
                );
            } else {
                s += &format!(
                    "| {} | - | - | - | - | - | - | - | {} | {rms:.4} | {solve} |\n",
                    row.row, row.falls
                );
            }
        }
        s += "\n";
    }
    s
}
