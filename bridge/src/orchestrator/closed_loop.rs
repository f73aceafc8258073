//! Lockstep closed-loop control of one simulator by the MPC service: reset to `x0`, then
//! solve → apply the first input → step, with the SPEC metrics of `koopman::mpc::metrics`
//! ([`ControlRun`] is one simulator's loop, driven step by step by [`super::control_loop`]).

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use koopman::mpc::metrics::{final_error, quantile, time_to_goal, wrapped_error, GoalSpec};
use serde::{Deserialize, Serialize};

use super::position_loop::PositionLoop;
use super::reference::Reference;
use super::view::{RunView, StepView, ViewStep};
use crate::client::{Client, Liveliness, SimClient};
use crate::codec::{SolveReply, SolveRequest, SolveStatus, StateMsg, StepStatus};
use crate::error::{Error, ErrorCode, Result};
use crate::keyexpr::{Role, SimLeaf};
use crate::messages::{ResetRequest, SimInfo};
use crate::scenario::Controller;

/// Closed-loop control result.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ControlReport {
    /// Simulator id.
    pub sim: String,
    /// Model name (the model a baseline controller's run was compared with; it did not use it).
    pub model: String,
    /// The entry's `label` (its row's name; the plot `control-{label}.png`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub label: Option<String>,
    /// What decided the inputs: the MPC service, or a baseline (`feedforward`, `zero-input`).
    #[serde(default)]
    pub controller: Controller,
    /// The perturbation the simulator applied to the episode (`[control] perturbation`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub perturbation: Option<crate::messages::Perturbation>,
    /// State names.
    pub state_names: Vec<String>,
    /// Input names.
    pub input_names: Vec<String>,
    /// Sampling period.
    pub dt: f64,
    /// Reference state (a fixed reference: as given; a trajectory: its first row).
    pub reference: Vec<f64>,
    /// The reference state at each step 0..=T (a trajectory from `reference_file`); absent for
    /// a fixed reference.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference_trajectory: Option<Vec<Vec<f64>>>,
    /// States x_0..x_T.
    pub x: Vec<Vec<f64>>,
    /// Inputs u_0..u_{T-1}.
    pub u: Vec<Vec<f64>>,
    /// Final error norm (angles wrapped).
    pub final_error: f64,
    /// First step from which the state stays within the SPEC goal ([`GoalSpec::default`]:
    /// 0.05 for angles, 0.1 for the others) of the reference for 50 steps; `None` if never.
    pub time_to_goal_steps: Option<usize>,
    /// Error norm ‖x_k − r_k‖ (angles wrapped) at each step 0..=T.
    #[serde(default)]
    pub error: Vec<f64>,
    /// Tracking RMS per state over steps 0..=T (angles wrapped).
    #[serde(default)]
    pub tracking_rms: Vec<f64>,
    /// Tracking RMS over every state and step.
    #[serde(default)]
    pub tracking_rms_total: f64,
    /// Median solve time inside the service in µs.
    pub solve_median_us: f64,
    /// Median solve round trip (query to reply) in µs.
    pub solve_round_trip_median_us: f64,
    /// Median step round trip (query to reply) in µs.
    #[serde(default)]
    pub step_round_trip_median_us: f64,
    /// Solves whose status was not `solved` (the sum of `not_solved_by_status`).
    pub not_solved: usize,
    /// The solves that were not `solved`, by the status the MPC service answered:
    /// `suboptimal` (an iteration or time limit, a feasible plan), `inaccurate` (optimal to
    /// reduced accuracy) or `fallback` (the solver failed: the previous plan shifted and
    /// clamped to the bounds was applied); statuses that did not occur are absent.
    #[serde(default)]
    pub not_solved_by_status: BTreeMap<String, usize>,
    /// The offset-free correction the MPC applied (`[control] offset_free`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub offset_free: Option<koopman::mpc::OffsetFreeConfig>,
    /// The MPC settings the service solved with (the scenario's `[control].mpc` over SPEC's
    /// defaults, bounds intersected with the simulator's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mpc: Option<koopman::mpc::MpcConfig>,
    /// True when the MPC planned the deviation from a plan (`feedforward_file`: the error-state
    /// MPC), false for the standard MPC.
    #[serde(default)]
    pub error_state: bool,
    /// The position loop that corrected the plan at every step (`[control] position_loop`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position_loop: Option<crate::scenario::PositionLoopSpec>,
    /// The noise on the state the MPC saw (`[control] observation_noise`); `x` is the true state.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub observation_noise: Option<crate::scenario::ObservationNoise>,
    /// The steps the simulator flagged in its step replies (an episode end, a clipped input;
    /// PROTOCOL.md §4); absent when it flagged none.
    #[serde(default, skip_serializing_if = "StepFlags::is_empty")]
    pub step_flags: StepFlags,
}

/// How many closed-loop steps the simulator's step replies flagged, by flag.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct StepFlags {
    /// Steps flagged `terminated` (the task says the episode had ended: a fall, a Gymnasium
    /// termination). The loop goes on; the states after it are in `x` as any other.
    pub terminated: usize,
    /// The step index `k` of the first state flagged `terminated`; `None` if none was.
    pub first_terminated: Option<usize>,
    /// Steps flagged `truncated` (a time limit of the simulator's own).
    pub truncated: usize,
    /// Steps whose input the simulator clipped into its bounds.
    pub clipped: usize,
}

impl StepFlags {
    /// Counts the status of the reply that brought state `k`.
    pub fn count(&mut self, k: usize, s: StepStatus) {
        if s.terminated() {
            self.terminated += 1;
            self.first_terminated.get_or_insert(k);
        }
        self.truncated += usize::from(s.truncated());
        self.clipped += usize::from(s.clipped());
    }
    /// No step was flagged.
    pub fn is_empty(&self) -> bool {
        *self == StepFlags::default()
    }
}

/// A closed-loop control task for the MPC service.
#[derive(Clone, Debug)]
pub struct ControlTask<'a> {
    /// MPC service id.
    pub mpc_id: &'a str,
    /// Model name (configured on the service).
    pub model: &'a str,
    /// Initial state.
    pub x0: &'a [f64],
    /// What to track.
    pub reference: &'a Reference,
    /// The MPC horizon H (the window of a trajectory reference has H rows).
    pub horizon: usize,
    /// A position loop that corrects a plan's window before each solve.
    pub position_loop: Option<&'a PositionLoop>,
    /// Closed-loop steps.
    pub steps: usize,
    /// Publish every executed state on the simulator's `state` key (`StateMsg`, as a free-run
    /// adapter does), so that a recorder can record the closed loop.
    pub publish: bool,
    /// Apply these inputs open loop (row k at step k, the last past the end) instead of asking
    /// the MPC service: the replay row of a tracking task.
    pub replay: Option<&'a [Vec<f64>]>,
    /// What decides the inputs when nothing is replayed (a baseline needs no MPC service).
    pub controller: Controller,
    /// The row's name in the report.
    pub label: Option<&'a str>,
    /// The input bounds a baseline controller's inputs are clipped to (`u_min`, `u_max`; the
    /// MPC's bounds: the scenario's intersected with the simulator's).
    pub clip: Option<(&'a [f64], &'a [f64])>,
    /// The perturbation of the episode, sent with the reset (the simulator applies it).
    pub perturbation: Option<&'a crate::messages::Perturbation>,
    /// Noise on the state the MPC sees (its draws seeded by the noise's `seed`).
    pub observation_noise: Option<&'a crate::scenario::ObservationNoise>,
    /// Where its states are shown to a viewer (published only while one subscribes).
    pub view: Option<StepView<'a>>,
}

/// One simulator's closed loop in progress.
pub struct ControlRun<'a> {
    sim: &'a mut SimClient,
    task: ControlTask<'a>,
    info: SimInfo,
    key: String,
    who: String,
    xs: Vec<Vec<f64>>,
    us: Vec<Vec<f64>>,
    solve_us: Vec<f64>,
    rt_us: Vec<f64>,
    step_us: Vec<f64>,
    not_solved: BTreeMap<String, usize>,
    flags: StepFlags,
    terminated: Vec<bool>,
    sim_failure: Option<String>,
    publisher: Option<zenoh::pubsub::Publisher<'static>>,
    /// The input decided at the current state and the MPC's reply, until the view shows them.
    decided: Option<(Vec<f64>, Option<SolveReply>)>,
    /// The draws of the observation noise.
    noise_rng: koopman::rng::Rng,
}

impl<'a> ControlRun<'a> {
    /// Resets `sim` to the task's `x0` (and declares the state publisher when asked); a
    /// simulator that loses its liveliness token in `live` meanwhile ends it as gone.
    pub fn start(
        client: &Client,
        live: &Liveliness,
        sim: &'a mut SimClient,
        task: ControlTask<'a>,
    ) -> Result<Self> {
        let info = sim.info.sim.clone();
        let first = sim.reset_watched(
            &ResetRequest {
                seed: None,
                x0: Some(task.x0.to_vec()),
                perturbation: task.perturbation.cloned(),
            },
            Some(live),
        )?;
        let publisher = if task.publish {
            use zenoh::Wait;
            Some(
                client
                    .session
                    .declare_publisher(client.keys.sim(&sim.id, SimLeaf::State)?)
                    .congestion_control(zenoh::qos::CongestionControl::Block)
                    .wait()
                    .map_err(Error::zenoh)?,
            )
        } else {
            None
        };
        let noise_rng = koopman::rng::Rng::new(task.observation_noise.map_or(0, |n| n.seed));
        let run = ControlRun {
            key: client.keys.mpc_solve(task.mpc_id)?,
            who: format!("MPC service '{}'", task.mpc_id),
            sim,
            task,
            info,
            xs: vec![first.x],
            us: Vec::new(),
            solve_us: Vec::new(),
            rt_us: Vec::new(),
            step_us: Vec::new(),
            not_solved: BTreeMap::new(),
            flags: StepFlags::default(),
            terminated: vec![first.status.terminated()],
            sim_failure: None,
            publisher,
            decided: None,
            noise_rng,
        };
        run.publish(first.k, first.t, &[])?;
        Ok(run)
    }

    /// The simulator's id.
    pub fn sim_id(&self) -> &str {
        &self.sim.id
    }

    /// Steps this loop has still to make.
    pub fn remaining(&self) -> usize {
        self.task.steps.saturating_sub(self.us.len())
    }

    fn publish(&self, k: u64, t: f64, u: &[f64]) -> Result<()> {
        if let Some(p) = &self.publisher {
            use zenoh::Wait;
            let m = StateMsg {
                seq: self.xs.len() as u64 - 1,
                k,
                t,
                x: self.xs[self.xs.len() - 1].clone(),
                u: u.to_vec(),
            };
            p.put(m.encode()).wait().map_err(Error::zenoh)?;
        }
        Ok(())
    }

    /// The states so far, x_0..x_k.
    pub fn states(&self) -> &[Vec<f64>] {
        &self.xs
    }

    /// Whether each state so far came with a `terminated` flag (a fall), x_0's from the reset.
    pub fn terminated(&self) -> &[bool] {
        &self.terminated
    }

    /// The solve times inside the MPC service so far, µs (none for a replay).
    pub fn solve_times_us(&self) -> &[f64] {
        &self.solve_us
    }

    /// The simulator's refusal that ended the loop ([`ControlRun::fail_step`]), if any.
    pub fn sim_failure(&self) -> Option<&str> {
        self.sim_failure.as_deref()
    }

    /// One step: decide the input ([`ControlRun::decide`]) and step the simulator with it.
    pub fn step(&mut self, client: &Client, live: &Liveliness) -> Result<()> {
        let u = self.decide(client, live)?;
        self.apply(u, live)
    }

    /// The input of the current step: the replayed one, a baseline controller's, or the MPC
    /// service's first planned input for the current state (and the reference window of this
    /// step).
    pub fn decide(&mut self, client: &Client, live: &Liveliness) -> Result<Vec<f64>> {
        let k = self.us.len();
        if let Some(inputs) = self.task.replay {
            return Ok(self.decided_alone(inputs[k.min(inputs.len() - 1)].clone()));
        }
        let (r, h) = (self.task.reference, self.task.horizon);
        let nu = self.info.nu();
        match self.task.controller {
            Controller::Mpc => {}
            Controller::ZeroInput => return Ok(self.decided_alone(vec![0.0; nu])),
            Controller::Feedforward => {
                let (mut state, mut u) = (r.window(k, 1), r.feedforward(k, 1));
                if let Some(pl) = self.task.position_loop {
                    pl.correct(&self.xs[k], &mut state, &mut u);
                }
                if let Some((lo, hi)) = self.task.clip {
                    for ((v, l), h) in u.iter_mut().zip(lo).zip(hi) {
                        *v = v.clamp(*l, *h);
                    }
                }
                return Ok(self.decided_alone(u));
            }
        }
        let (mut reference, mut feedforward) = (r.window(k, h), r.feedforward(k, h));
        if let (Some(pl), Reference::Plan { .. }) = (self.task.position_loop, r) {
            pl.correct(&self.xs[k], &mut reference, &mut feedforward);
        }
        let req = SolveRequest {
            model: self.task.model.to_string(),
            x: self.observed(k),
            reference,
            feedforward,
        };
        let t = Instant::now();
        let p = client.start(&self.key, req.encode(), Duration::from_secs(10), &self.who)?;
        let b = p.wait(Some((live, Role::Mpc, self.task.mpc_id)))?;
        self.rt_us.push(t.elapsed().as_secs_f64() * 1e6);
        let r = SolveReply::decode(&b)?;
        if r.u.len() < nu {
            return Err(Error::protocol(
                ErrorCode::Dimension,
                format!("{} returned {} inputs", self.who, r.u.len()),
            ));
        }
        self.solve_us.push(r.solve_time_ns as f64 / 1e3);
        if r.status != SolveStatus::Solved {
            *self
                .not_solved
                .entry(status_name(r.status).to_string())
                .or_default() += 1;
        }
        let u = r.u[..nu].to_vec();
        self.decided = Some((u.clone(), Some(r)));
        Ok(u)
    }

    /// State `k` as the MPC sees it: with the observation noise's draws added to its states.
    fn observed(&mut self, k: usize) -> Vec<f64> {
        let mut x = self.xs[k].clone();
        if let Some(n) = self.task.observation_noise {
            for &i in &n.states {
                x[i] += n.sigma * self.noise_rng.normal();
            }
        }
        x
    }

    /// `u`, decided without the MPC service (a replay or a baseline controller).
    fn decided_alone(&mut self, u: Vec<f64>) -> Vec<f64> {
        self.decided = Some((u.clone(), None));
        u
    }

    /// Shows the state the last input was decided at to a viewer (once the step has come back:
    /// the viewer's work then overlaps the next solve, not the simulator's step).
    fn show_decided(&mut self) {
        if let Some((u, reply)) = self.decided.take() {
            self.show(self.us.len(), Some(&u), reply.as_ref());
        }
    }

    /// Shows state `k` to a viewer, if one watches: with the input decided there and the MPC's
    /// reply (its plan predicted by the model), or alone (the last state).
    fn show(&self, k: usize, u: Option<&[f64]>, reply: Option<&SolveReply>) {
        let Some(v) = &self.task.view else { return };
        let Some(publisher) = v.view.step_publisher(&self.sim.id) else {
            return;
        };
        let x = &self.xs[k];
        let step = ViewStep {
            row: v.row,
            episode: v.episode,
            k,
            t: k as f64 * self.info.dt,
            x,
            reference: self.task.reference.at(k, self.info.nx()),
            u,
            solve_us: reply.map(|r| r.solve_time_ns as f64 / 1e3),
            status: reply.map(|r| status_name(r.status)),
            plan: reply.and_then(|r| v.view.plan(self.task.model, x, &r.u)),
        };
        RunView::publish_step(&publisher, &step);
    }

    /// Steps the simulator with `u` and records the state it brought.
    pub fn apply(&mut self, u: Vec<f64>, live: &Liveliness) -> Result<()> {
        let t = Instant::now();
        let next = self.sim.step(&u, Some(live))?;
        self.step_us.push(t.elapsed().as_secs_f64() * 1e6);
        self.show_decided();
        self.xs.push(next.x);
        self.terminated.push(next.status.terminated());
        self.flags.count(self.xs.len() - 1, next.status);
        self.publish(next.k, next.t, &u)?;
        self.us.push(u);
        Ok(())
    }

    /// Records that the simulator refused to step with `u` (`why`): a non-finite state ends the
    /// run, so that it scores as a failure at this step.
    pub fn fail_step(&mut self, u: Vec<f64>, why: String) {
        self.show_decided();
        let nx = self.info.nx();
        self.xs.push(vec![f64::NAN; nx]);
        self.terminated.push(true);
        self.us.push(u);
        self.sim_failure = Some(why);
    }

    /// The report of the finished loop.
    pub fn finish(mut self) -> ControlReport {
        self.show_decided();
        self.show(self.xs.len() - 1, None, None);
        let info = &self.info;
        let nx = info.nx();
        let r = self.task.reference;
        let refs: Vec<Vec<f64>> = (0..self.xs.len()).map(|k| r.at(k, nx)).collect();
        let errs: Vec<Vec<f64>> = self
            .xs
            .iter()
            .zip(&refs)
            .map(|(x, rk)| wrapped_error(x, rk, &info.angle_indices))
            .collect();
        let norm = |e: &Vec<f64>| e.iter().map(|v| v * v).sum::<f64>().sqrt();
        let n = errs.len().max(1) as f64;
        let tracking_rms: Vec<f64> = (0..nx)
            .map(|i| {
                let sq: f64 = errs.iter().filter_map(|e| e.get(i)).map(|v| v * v).sum();
                (sq / n).sqrt()
            })
            .collect();
        ControlReport {
            sim: self.sim.id.clone(),
            model: self.task.model.to_string(),
            label: self.task.label.map(str::to_string),
            controller: self.task.controller,
            perturbation: self.task.perturbation.cloned(),
            state_names: info.state_names.clone(),
            input_names: info.input_names.clone(),
            dt: info.dt,
            reference: match r {
                Reference::Fixed(v) => v.clone(),
                Reference::Trajectory(_) | Reference::Plan { .. } => refs[0].clone(),
            },
            reference_trajectory: r.rows().map(|_| refs.clone()),
            final_error: final_error(&errs),
            time_to_goal_steps: time_to_goal(&errs, &info.angle_indices, &GoalSpec::default()),
            error: errs.iter().map(norm).collect(),
            tracking_rms_total: koopman::mpc::metrics::rms(&errs),
            tracking_rms,
            solve_median_us: quantile(&self.solve_us, 0.5),
            solve_round_trip_median_us: quantile(&self.rt_us, 0.5),
            step_round_trip_median_us: quantile(&self.step_us, 0.5),
            not_solved: self.not_solved.values().sum(),
            not_solved_by_status: self.not_solved,
            offset_free: None,
            mpc: None,
            error_state: self.task.controller == Controller::Mpc
                && matches!(r, Reference::Plan { .. }),
            position_loop: self.task.position_loop.map(|p| p.spec().clone()),
            observation_noise: self.task.observation_noise.cloned(),
            step_flags: self.flags,
            x: self.xs,
            u: self.us,
        }
    }
}

/// The name of a solve status in reports (`solved`, `suboptimal`, `fallback`, `inaccurate`).
pub fn status_name(s: SolveStatus) -> &'static str {
    match s {
        SolveStatus::Solved => "solved",
        SolveStatus::Suboptimal => "suboptimal",
        SolveStatus::Fallback => "fallback",
        SolveStatus::Inaccurate => "inaccurate",
    }
}

/// Closed-loop control of `sim` by the MPC service (lockstep): reset to `x0`, then `steps`
/// times solve → apply the first input → step.
pub fn closed_loop(
    client: &Client,
    live: &Liveliness,
    sim: &mut SimClient,
    task: &ControlTask<'_>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ControlReport> {
    let steps = task.steps;
    let mut run = ControlRun::start(client, live, sim, task.clone())?;
    for k in 0..steps {
        run.step(client, live)?;
        progress(k + 1, steps);
    }
    Ok(run.finish())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn step_flags_count_each_flag_and_the_first_termination() {
        let mut f = StepFlags::default();
        assert!(f.is_empty());
        f.count(1, StepStatus::CLIPPED);
        f.count(2, StepStatus::EMPTY);
        f.count(3, StepStatus::TERMINATED | StepStatus::CLIPPED);
        f.count(4, StepStatus::TERMINATED | StepStatus::TRUNCATED);
        let want = StepFlags {
            terminated: 2,
            first_terminated: Some(3),
            truncated: 1,
            clipped: 2,
        };
        assert_eq!(f, want);
        // A report written before the field reads (no flags, no warning) and is written as
        // before; with the flags, they are in the JSON and the warning names the first step.
        let mut r: ControlReport = serde_json::from_value(serde_json::json!({
            "sim": "go2", "model": "m", "state_names": ["x"], "input_names": ["u"], "dt": 0.02,
            "reference": [0.0], "x": [[0.0], [1.0], [2.0], [3.0], [4.0]],
            "u": [[0.0], [0.0], [0.0], [0.0]], "final_error": 1.0, "solve_median_us": 1.0,
            "solve_round_trip_median_us": 1.0, "not_solved": 0
        }))
        .unwrap();
        assert!(r.step_flags.is_empty() && r.terminated_warning().is_none());
        assert!(serde_json::to_value(&r)
            .unwrap()
            .get("step_flags")
            .is_none());
        r.step_flags = f;
        let json = serde_json::to_value(&r).unwrap();
        assert_eq!(json["step_flags"]["first_terminated"], 3);
        let back: ControlReport = serde_json::from_value(json).unwrap();
        assert_eq!(back.step_flags, want);
        let w = r.terminated_warning().unwrap();
        assert!(w.contains("at step 3, and at 2 of 4 steps"), "{w}");
        assert_eq!(
            r.warnings(),
            vec![w],
            "the run's warnings carry the episode end"
        );
    }
}
