//! `koopbridge run`: starts the scenario's simulators and services as child processes, passes
//! the readiness barrier, collects data in lockstep, trains through the trainer service and
//! closes the loop through the MPC service; returns a report.
//!
//! - [`cluster`]: the child processes and the orchestrator's own session ([`Cluster`]);
//! - [`closed_loop`]: one simulator's lockstep closed loop through the MPC service
//!   ([`closed_loop()`], [`closed_loop::ControlRun`]);
//! - [`control_loop`]: several controlled simulators in one lockstep loop, concurrently;
//! - [`control`]: the control phase of a run (models configured, references read, the loop);
//! - [`control_settings`]: a `[control]` entry's simulator, MPC settings and position loop;
//! - [`diagnose`]: why a control run missed: closed-loop vs test prediction, saturation, next step;
//! - [`reference`]: fixed and time-varying (`reference_file`) references and their windows;
//! - [`tracking`]: tracking tasks (`[control] references`): a closed loop per reference and
//!   model kind beside the replay row, scored by [`survival`]; [`reference_set`] reads them;
//!   [`track_aggregate`]: their on-policy aggregation rounds; [`tracking_report`]: their rows;
//! - [`commands`]: command placeholders and `[[hooks]]`;
//! - [`program`]: the program an external command runs (`{python}`, relative paths);
//! - [`aggregate`]: on-policy aggregation rounds (`--aggregate`);
//! - [`validate`]: the whole scenario checked against the simulators' `info` before collection;
//! - [`reuse`]: a rerun into the same folder reuses unchanged data and models;
//! - [`train`]: one simulator's model trained through the trainer service ([`TrainReport`]);
//! - [`compare`]: the models of a run (one per simulator and `[train].model` kind) side by side;
//! - [`view`]: what a viewer shows, published while someone watches; [`viewer`]: the viewer
//!   process of `--view` / `--record-view`;
//! - [`run`]: the whole scenario ([`run_scenario`]); [`report`]: its report (`report.json`).

pub mod aggregate;
pub mod authority;
pub mod closed_loop;
pub mod cluster;
pub mod commands;
pub mod compare;
pub mod control;
pub mod control_loop;
pub mod control_settings;
pub mod control_summary;
mod control_warnings;
pub mod data_quality;
pub mod diagnose;
pub mod growth;
pub mod position_loop;
pub mod pretrained;
pub mod program;
pub mod reference;
pub mod reference_set;
pub mod report;
pub mod reuse;
pub mod run;
pub mod survival;
pub mod track_aggregate;
pub mod tracking;
pub mod tracking_report;
pub mod train;
pub mod validate;
pub mod view;
pub mod viewer;

use std::path::PathBuf;
use std::time::Duration;

use crate::session::ZenohOptions;

pub use closed_loop::{closed_loop, ControlReport, ControlTask};
pub use cluster::Cluster;
pub use control_loop::{control_loop, LoopReport};
pub use position_loop::PositionLoop;
pub use reference::Reference;
pub use run::{run_scenario, run_scenario_with, CollectReport, Report, RunExtras};
pub use train::TrainReport;

/// Id of the services process started by the orchestrator.
pub const SERVICES_ID: &str = "main";

/// How to run a scenario.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// The `koopbridge` executable to start children with.
    pub exe: PathBuf,
    /// Output folder (`results/{scenario}`).
    pub out_dir: PathBuf,
    /// Zenoh options of the orchestrator (its children connect to it, and to `connect`).
    pub zenoh: ZenohOptions,
    /// Session id (fresh when `None`).
    pub session: Option<String>,
    /// Readiness timeout.
    pub ready_timeout: Duration,
    /// Use the simulators and services that are already in the session (found by their
    /// liveliness tokens) and start only the missing ones; `false`: refuse to start while a
    /// participant with the same role and id is already there.
    pub attach_existing: bool,
}

/// What the progress callback is told.
pub enum Event<'a> {
    /// A phase starts.
    Phase(&'a str),
    /// Collection progress: (split, done, total).
    Collect(&'static str, usize, usize),
    /// A training progress message from the trainer.
    Train(&'a serde_json::Value),
    /// A control step: (k, total).
    Control(usize, usize),
    /// Something the user should know about the results (also in `report.json`'s
    /// `warnings`): an MPC that did not solve every step, an aggregation round that made
    /// control worse.
    Warning(&'a str),
}
