//! Several simulators controlled in ONE lockstep loop: each macro step runs every simulator's
//! solve → step concurrently (one thread per simulator) and waits for all of them, so a macro
//! step costs about the slowest simulator, not the sum; the loop's own figures.

use std::sync::mpsc;
use std::time::Instant;

use koopman::mpc::metrics::quantile;
use serde::{Deserialize, Serialize};

use super::closed_loop::{ControlReport, ControlRun, ControlTask};
use crate::client::{Client, Liveliness, SimClient};
use crate::error::{Error, Result};

/// The figures of a multi-simulator control loop.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct LoopReport {
    /// The simulators stepped, in order.
    pub sims: Vec<String>,
    /// Macro steps (every simulator that still had steps stepped once).
    pub macro_steps: usize,
    /// Seconds of the stepping (after the resets).
    pub seconds: f64,
    /// Macro steps per second.
    pub macro_steps_per_second: f64,
    /// Median duration of one macro step in µs.
    pub macro_step_median_us: f64,
    /// Per simulator (same order as `sims`): median solve round trip in µs.
    pub solve_round_trip_median_us: Vec<f64>,
    /// Per simulator: median step round trip in µs.
    pub step_round_trip_median_us: Vec<f64>,
    /// Each simulator alone in the same loop, same tasks (`koopbridge run --loop-baseline`):
    /// macro steps per second; empty when not measured.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub alone_steps_per_second: Vec<f64>,
    /// Slowest simulator alone (its steps per second) divided by the loop's macro steps per
    /// second (goal ≤ 1.2); absent when not measured.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub slowdown_vs_slowest_alone: Option<f64>,
}

/// Runs every `(simulator, task)` in one lockstep loop: all reset, then each macro step steps
/// every loop that still has steps, concurrently, and waits for all; the first failure ends the
/// loop (naming its simulator). `progress(k, total)` after each macro step.
pub fn control_loop(
    client: &Client,
    live: &Liveliness,
    jobs: Vec<(&mut SimClient, ControlTask<'_>)>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<(Vec<ControlReport>, LoopReport)> {
    let total = jobs.iter().map(|(_, t)| t.steps).max().unwrap_or(0);
    let mut runs: Vec<ControlRun<'_>> = jobs
        .into_iter()
        .map(|(s, t)| ControlRun::start(client, s, t))
        .collect::<Result<_>>()?;
    let sims: Vec<String> = runs.iter().map(|r| r.sim_id().to_string()).collect();
    let mut macro_us = Vec::with_capacity(total);
    let t0 = Instant::now();
    if runs.len() == 1 {
        for k in 0..total {
            let t = Instant::now();
            runs[0].step(client, live)?;
            macro_us.push(t.elapsed().as_secs_f64() * 1e6);
            progress(k + 1, total);
        }
    } else {
        let steps: Vec<usize> = runs.iter().map(ControlRun::remaining).collect();
        std::thread::scope(|scope| -> Result<()> {
            let (done_tx, done_rx) = mpsc::channel::<Result<()>>();
            let mut go = Vec::new();
            for run in runs.iter_mut() {
                let (tx, rx) = mpsc::channel::<()>();
                go.push(tx);
                let done = done_tx.clone();
                scope.spawn(move || {
                    // One step per signal; the thread ends when its sender is dropped.
                    while rx.recv().is_ok() {
                        let r = run.step(client, live);
                        let failed = r.is_err();
                        if done.send(r).is_err() || failed {
                            return;
                        }
                    }
                });
            }
            drop(done_tx);
            for k in 0..total {
                let t = Instant::now();
                let active: Vec<usize> = (0..steps.len()).filter(|&j| steps[j] > k).collect();
                for &j in &active {
                    go[j].send(()).map_err(|_| {
                        Error::Config(format!("the control thread of '{}' ended", sims[j]))
                    })?;
                }
                let mut first_err = None;
                for _ in &active {
                    match done_rx.recv() {
                        Ok(Ok(())) => {}
                        Ok(Err(e)) => {
                            first_err.get_or_insert(e);
                        }
                        Err(_) => {
                            first_err.get_or_insert(Error::Config("a control thread ended".into()));
                        }
                    }
                }
                if let Some(e) = first_err {
                    return Err(e);
                }
                macro_us.push(t.elapsed().as_secs_f64() * 1e6);
                progress(k + 1, total);
            }
            Ok(())
        })?;
    }
    let seconds = t0.elapsed().as_secs_f64();
    let reports: Vec<ControlReport> = runs.into_iter().map(ControlRun::finish).collect();
    let report = LoopReport {
        macro_steps: macro_us.len(),
        seconds,
        macro_steps_per_second: macro_us.len() as f64 / seconds.max(1e-9),
        macro_step_median_us: quantile(&macro_us, 0.5),
        solve_round_trip_median_us: reports
            .iter()
            .map(|r| r.solve_round_trip_median_us)
            .collect(),
        step_round_trip_median_us: reports
            .iter()
            .map(|r| r.step_round_trip_median_us)
            .collect(),
        sims,
        alone_steps_per_second: Vec::new(),
        slowdown_vs_slowest_alone: None,
    };
    Ok((reports, report))
}
