//! Closed-loop evaluation on the reference systems: the SPEC tasks (pendulum regulation and
//! smooth tracking), the loop itself, and its metrics and trajectory.

use std::f64::consts::PI;

use serde::{Deserialize, Serialize};

use super::metrics::{
    bound_violation, frobenius, quantile, rms, time_to_goal, wrapped_error, GoalSpec,
};
use super::policy::Policy;
use crate::error::{Error, Result};
use crate::systems::System;

/// What the controller has to do.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TaskKind {
    /// Bring the state to a fixed target and hold it.
    Regulate,
    /// Follow a smooth time-varying reference.
    Track,
}

/// A closed-loop task: start state, reference and length.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Task {
    /// Environment name.
    pub env: String,
    /// Regulation or tracking.
    pub kind: TaskKind,
    /// Initial state.
    pub x0: Vec<f64>,
    /// Number of control steps.
    pub steps: usize,
    /// Sampling period (s).
    pub dt: f64,
    target: Vec<f64>,
    /// Tracking: per-angle amplitude, the reference being `a_i sin(ω t)` (rates `a_i ω cos(ω t)`).
    amplitudes: Vec<f64>,
    omega: f64,
}

impl Task {
    /// The SPEC task for a reference system: damped pendulum regulation from [−2.5, 0.1] to 0,
    /// double pendulum from 0 to [1.2, −0.8, 0, 0], 200 steps; tracking of `0.4 sin(πt)` (damped)
    /// or `±0.3 sin(πt)` (double) from rest at 0.
    pub fn standard(system: &dyn System, kind: TaskKind) -> Result<Task> {
        let (x0, target, amplitudes) = match (system.name(), kind) {
            ("damped-pendulum", TaskKind::Regulate) => (vec![-2.5, 0.1], vec![0.0, 0.0], vec![]),
            ("double-pendulum", TaskKind::Regulate) => {
                (vec![0.0; 4], vec![1.2, -0.8, 0.0, 0.0], vec![])
            }
            ("damped-pendulum", TaskKind::Track) => (vec![0.0, 0.0], vec![], vec![0.4]),
            ("double-pendulum", TaskKind::Track) => (vec![0.0; 4], vec![], vec![0.3, -0.3]),
            (name, _) => {
                return Err(Error::UnknownName {
                    kind: "control environment",
                    name: name.to_string(),
                    known: "damped-pendulum, double-pendulum".into(),
                })
            }
        };
        Ok(Task {
            env: system.name().to_string(),
            kind,
            x0,
            steps: 200,
            dt: system.dt(),
            target,
            amplitudes,
            omega: PI,
        })
    }

    /// The reference state at step k (beyond the end the reference simply continues).
    pub fn reference(&self, k: usize) -> Vec<f64> {
        match self.kind {
            TaskKind::Regulate => self.target.clone(),
            TaskKind::Track => {
                let t = k as f64 * self.dt;
                let (s, c) = (self.omega * t).sin_cos();
                let ang = self.amplitudes.iter().map(|a| a * s);
                let rates = self.amplitudes.iter().map(|a| a * self.omega * c);
                ang.chain(rates).collect()
            }
        }
    }

    /// `r_{k+1}..r_{k+h}` stacked.
    pub fn window(&self, k: usize, h: usize) -> Vec<f64> {
        (1..=h).flat_map(|j| self.reference(k + j)).collect()
    }
}

/// The recorded closed loop: `x_0..x_T`, `r_0..r_T`, `u_0..u_{T−1}`.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Trajectory {
    /// Time of each state sample (s).
    pub t: Vec<f64>,
    /// States.
    pub x: Vec<Vec<f64>>,
    /// References.
    pub r: Vec<Vec<f64>>,
    /// Applied inputs.
    pub u: Vec<Vec<f64>>,
    /// Decision time of each input (ms).
    pub solve_ms: Vec<f64>,
}

/// Metrics of one closed-loop run (SPEC.md, "Control").
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ClosedLoopMetrics {
    /// Environment.
    pub env: String,
    /// Task.
    pub task: TaskKind,
    /// Controller name.
    pub controller: String,
    /// Steps actually run (less than requested if the state diverged).
    pub steps: usize,
    /// Euclidean norm of the wrapped final error `x_T − r_T`.
    pub final_error: f64,
    /// Largest |wrapped angle error| at the end.
    pub final_angle_error: f64,
    /// First step from which the state stays at the goal for `goal.hold` steps.
    pub time_to_goal_steps: Option<usize>,
    /// The same in seconds.
    pub time_to_goal_s: Option<f64>,
    /// Thresholds used for the time to goal.
    pub goal: GoalSpec,
    /// RMS of the wrapped error over `x_1..x_T`, all components.
    pub tracking_rms: f64,
    /// Frobenius norm of the wrapped error matrix over `x_1..x_T`.
    pub tracking_frobenius: f64,
    /// RMS of the angle components only.
    pub angle_rms: f64,
    /// Median decision time (ms).
    pub solve_ms_median: f64,
    /// 99th percentile of the decision time (ms).
    pub solve_ms_p99: f64,
    /// Longest decision time (ms).
    pub solve_ms_max: f64,
    /// Steps whose input left the bounds by more than 1e-9.
    pub input_violations: usize,
    /// Largest input-bound violation.
    pub max_input_violation: f64,
    /// Steps at which the controller used its fallback.
    pub fallbacks: usize,
    /// True if the state became non-finite (the run stopped there).
    pub diverged: bool,
}

/// Runs `policy` on `system` for the task; inputs are applied as returned (not clamped here,
/// so that violations are measured), `u_min`/`u_max` are the bounds they are checked against.
pub fn run_closed_loop(
    system: &dyn System,
    policy: &mut dyn Policy,
    task: &Task,
    u_min: &[f64],
    u_max: &[f64],
    goal: &GoalSpec,
    mut progress: impl FnMut(usize, usize),
) -> Result<(ClosedLoopMetrics, Trajectory)> {
    let (nx, nu) = (system.nx(), system.nu());
    if task.x0.len() != nx {
        return Err(Error::dimension("task initial state", nx, task.x0.len()));
    }
    if u_min.len() != nu || u_max.len() != nu {
        return Err(Error::dimension(
            "input bounds",
            nu,
            u_min.len().min(u_max.len()),
        ));
    }
    let h = policy.horizon();
    let mut tr = Trajectory::default();
    let mut x = task.x0.clone();
    tr.t.push(0.0);
    tr.x.push(x.clone());
    tr.r.push(task.reference(0));
    let (mut violations, mut max_violation, mut fallbacks, mut diverged) = (0, 0.0f64, 0, false);
    let mut next = vec![0.0; nx];
    for k in 0..task.steps {
        progress(k, task.steps);
        let action = policy.act(&x, &task.reference(k), &task.window(k, h))?;
        if action.u.len() != nu || action.u.iter().any(|v| !v.is_finite()) {
            return Err(Error::Numerical(format!(
                "{} returned an invalid input at step {k}",
                policy.name()
            )));
        }
        let v = bound_violation(&action.u, u_min, u_max);
        if v > 1e-9 {
            violations += 1;
        }
        max_violation = max_violation.max(v);
        fallbacks += usize::from(action.fallback);
        system.step(&x, &action.u, &mut next);
        tr.u.push(action.u);
        tr.solve_ms.push(action.solve_time.as_secs_f64() * 1e3);
        if next.iter().any(|v| !v.is_finite()) {
            diverged = true;
            break;
        }
        x.copy_from_slice(&next);
        tr.t.push((k + 1) as f64 * task.dt);
        tr.x.push(x.clone());
        tr.r.push(task.reference(k + 1));
    }
    progress(task.steps, task.steps);
    let angles = system.angle_indices();
    let errors: Vec<Vec<f64>> =
        tr.x.iter()
            .zip(&tr.r)
            .map(|(x, r)| wrapped_error(x, r, &angles))
            .collect();
    let last = errors.last().cloned().unwrap_or_default();
    let after_start = &errors[1.min(errors.len())..];
    let angle_errs: Vec<Vec<f64>> = after_start
        .iter()
        .map(|e| angles.iter().map(|&i| e[i]).collect())
        .collect();
    let ttg = time_to_goal(&errors, &angles, goal);
    let metrics = ClosedLoopMetrics {
        env: task.env.clone(),
        task: task.kind,
        controller: policy.name(),
        steps: tr.u.len(),
        final_error: last.iter().map(|v| v * v).sum::<f64>().sqrt(),
        final_angle_error: angles.iter().map(|&i| last[i].abs()).fold(0.0, f64::max),
        time_to_goal_steps: ttg,
        time_to_goal_s: ttg.map(|k| k as f64 * task.dt),
        goal: *goal,
        tracking_rms: rms(after_start),
        tracking_frobenius: frobenius(after_start),
        angle_rms: rms(&angle_errs),
        solve_ms_median: quantile(&tr.solve_ms, 0.5),
        solve_ms_p99: quantile(&tr.solve_ms, 0.99),
        solve_ms_max: tr.solve_ms.iter().copied().fold(0.0, f64::max),
        input_violations: violations,
        max_input_violation: max_violation,
        fallbacks,
        diverged,
    };
    Ok((metrics, tr))
}
