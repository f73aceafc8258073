//! The report of a scenario run, as `report.json` holds it: collection, training, control,
//! tracking, aggregation rounds, diagnoses, the recorded view and the warnings.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::aggregate::AggregationRound;
use super::compare::ModelResult;
use super::control_loop::LoopReport;
use super::diagnose::ControlDiagnosis;
use super::pretrained::Pretrained;
use super::track_aggregate::TrackingRound;
use super::tracking::TrackReport;
use super::train::TrainReport;
use super::ControlReport;

/// The outcome of one scenario run (written as `report.json`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Report {
    /// Scenario name.
    pub scenario: String,
    /// Session id used.
    pub session: String,
    /// Collection summary (`None`: the scenario collects nothing, no `[collect]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub collect: Option<CollectReport>,
    /// Training results, one per simulator and model kind (the kinds in `[train].model` order,
    /// the simulators in `[[sims]]` order within each).
    pub train: Vec<TrainReport>,
    /// Closed-loop control result of the first `[control]` entry (as `controls[0]`).
    pub control: Option<ControlReport>,
    /// Closed-loop control results, one per `[control]` entry (in order) and model kind: the
    /// first kind's entries, then the next kind's.
    #[serde(default)]
    pub controls: Vec<ControlReport>,
    /// The models side by side: per simulator and model kind, the test prediction error and
    /// the control result ([`compare::side_by_side`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub models: Vec<ModelResult>,
    /// The figures of the control loop with the first model kind (all controlled simulators in
    /// one lockstep loop).
    #[serde(default)]
    pub control_loop: Option<LoopReport>,
    /// On-policy aggregation rounds (`koopbridge run --aggregate ROUNDS`): per round and
    /// controlled simulator, the error before and after retraining on the rollouts.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub aggregation: Vec<AggregationRound>,
    /// The tracking tasks (`[control]` entries with `references`), one per entry: the replay
    /// row and one row per model kind, paired by reference ([`TrackReport`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub tracking: Vec<TrackReport>,
    /// The models trained elsewhere (`[train] pretrained`) the tracking tasks scored.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub pretrained: Vec<Pretrained>,
    /// On-policy aggregation rounds of the tracking tasks (`--aggregate` with a task marked
    /// `aggregate = true`): per round the retrained models and every task again
    /// ([`TrackingRound`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub tracking_aggregation: Vec<TrackingRound>,
    /// Per control run, what the numbers say about a miss: the model's prediction error along
    /// the closed loop against the test set, the commands at a bound, one next step
    /// ([`diagnose::diagnose`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub diagnoses: Vec<ControlDiagnosis>,
    /// The run's recorded view (`--view`, `--record-view`), to open with `koopbridge view --open`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub view: Option<PathBuf>,
    /// The MP4s of `--video` (one per simulator, row and reference).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub videos: Vec<PathBuf>,
    /// What the user should know about the results, also reported as [`Event::Warning`]: every
    /// control run whose MPC did not solve every step or whose simulator reported an episode end
    /// ([`ControlReport::warnings`]),
    /// every aggregation round that made control worse ([`aggregate::round_warnings`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
    /// Total wall time in seconds.
    pub wall_seconds: f64,
}

/// Collection summary.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct CollectReport {
    /// Simulators stepped.
    pub sims: Vec<String>,
    /// Windows per split (train, val, test) and simulator.
    pub windows: [usize; 3],
    /// Transitions per window.
    pub steps: usize,
    /// Seconds spent collecting.
    pub seconds: f64,
    /// Lockstep macro steps per second (all simulators stepped once = one macro step).
    pub macro_steps_per_second: f64,
    /// Dataset files written.
    pub files: Vec<PathBuf>,
    /// True when this run reused the data a previous run collected into the same folder
    /// (`[[sims]]`, `[collect]` and the simulators' `info` unchanged); the figures are that
    /// run's.
    #[serde(default)]
    pub reused: bool,
}
