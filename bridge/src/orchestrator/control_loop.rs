//! Several simulators controlled in ONE lockstep loop: each macro step runs every simulator's
//! solve → step concurrently (one thread per simulator) and waits for all of them, so a macro
//! step costs about the slowest simulator, not the sum; the loop's own figures. After a warm-up
//! the loop names its critical path (the simulator whose solve → step takes longest), so that
//! the caller can let it go first when the processes outnumber the cores.

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
    /// The critical path found after [`WARMUP_MACRO_STEPS`]: the simulator whose solve → step
    /// took longest on average (absent for a loop of one).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub critical_path: Option<String>,
    /// The simulators whose processes were then given a lower CPU priority (nice +10) so that
    /// the critical path is served first (those this run started; empty when none was).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub deprioritised: Vec<String>,
}

/// Macro steps after which the loop names its critical path (the first ones include warm-up
/// costs: first solves, caches).
pub const WARMUP_MACRO_STEPS: usize = 20;

/// Runs every `(simulator, task)` in one lockstep loop: all reset, then each macro step steps
/// every loop that still has steps, concurrently, and waits for all; the first failure ends the
/// loop (naming its simulator). `progress(k, total)` after each macro step. With several
/// simulators, after [`WARMUP_MACRO_STEPS`] `on_critical(j)` is called once with the index (in
/// `jobs`) of the critical path; it returns the simulators it deprioritised (for the report).
/// From then on the critical path's solve is also the first issued in each macro step.
pub fn control_loop(
    client: &Client,
    live: &Liveliness,
    jobs: Vec<(&mut SimClient, ControlTask<'_>)>,
    progress: &mut dyn FnMut(usize, usize),
    on_critical: &mut dyn FnMut(usize) -> Vec<String>,
) -> Result<(Vec<ControlReport>, LoopReport)> {
    let total = jobs.iter().map(|(_, t)| t.steps).max().unwrap_or(0);
    let mut runs: Vec<ControlRun<'_>> = jobs
        .into_iter()
        .map(|(s, t)| ControlRun::start(client, live, s, t))
        .collect::<Result<_>>()?;
    let sims: Vec<String> = runs.iter().map(|r| r.sim_id().to_string()).collect();
    let mut macro_us = Vec::with_capacity(total);
    let (mut critical, mut deprioritised) = (None, Vec::new());
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
            // (simulator, outcome, seconds its solve → step took)
            let (done_tx, done_rx) = mpsc::channel::<(usize, Result<()>, f64)>();
            let mut go = Vec::new();
            for (j, run) in runs.iter_mut().enumerate() {
                let (tx, rx) = mpsc::channel::<()>();
                go.push(tx);
                let done = done_tx.clone();
                scope.spawn(move || {
                    // One step per signal; the thread ends when its sender is dropped.
                    while rx.recv().is_ok() {
                        let t = Instant::now();
                        let r = run.step(client, live);
                        let failed = r.is_err();
                        if done.send((j, r, t.elapsed().as_secs_f64())).is_err() || failed {
                            return;
                        }
                    }
                });
            }
            let mut chain_seconds = vec![0.0; steps.len()];
            // The order the threads are signalled in: the critical path first once it is known.
            let mut order: Vec<usize> = (0..steps.len()).collect();
            drop(done_tx);
            for k in 0..total {
                let t = Instant::now();
                let active: Vec<usize> = order.iter().copied().filter(|&j| steps[j] > k).collect();
                for &j in &active {
                    go[j].send(()).map_err(|_| {
                        Error::Config(format!("the control thread of '{}' ended", sims[j]))
                    })?;
                }
                let mut first_err = None;
                for _ in &active {
                    match done_rx.recv() {
                        Ok((j, Ok(()), seconds)) => chain_seconds[j] += seconds,
                        Ok((_, Err(e), _)) => {
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
                if k + 1 == WARMUP_MACRO_STEPS {
                    let j = slowest(&chain_seconds);
                    order.retain(|&i| i != j);
                    order.insert(0, j);
                    critical = Some(sims[j].clone());
                    deprioritised = on_critical(j);
                }
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
        critical_path: critical,
        deprioritised,
    };
    Ok((reports, report))
}

/// The index of the largest total (the first of equal ones).
fn slowest(totals: &[f64]) -> usize {
    totals
        .iter()
        .enumerate()
        .fold(0, |best, (j, &t)| if t > totals[best] { j } else { best })
}

#[cfg(test)]
mod tests {
    use super::slowest;

    #[test]
    fn the_critical_path_is_the_largest_total_and_the_first_of_a_tie() {
        assert_eq!(slowest(&[0.2, 0.9, 0.4]), 1);
        assert_eq!(slowest(&[0.5, 0.1, 0.5]), 0);
        assert_eq!(slowest(&[3.0]), 0);
    }
}
