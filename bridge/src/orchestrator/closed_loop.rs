//! Lockstep closed-loop regulation of one simulator by the MPC service: reset to `x0`, then
//! solve → apply the first input → step, with the SPEC metrics of `koopman::mpc::metrics`.

use std::time::{Duration, Instant};

use koopman::mpc::metrics::{final_error, quantile, time_to_goal, wrapped_error, GoalSpec};
use serde::{Deserialize, Serialize};

use crate::client::{Client, Liveliness, SimClient};
use crate::codec::{SolveReply, SolveRequest, SolveStatus};
use crate::error::{Error, ErrorCode, Result};
use crate::keyexpr::Role;
use crate::messages::ResetRequest;

/// Closed-loop control result.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ControlReport {
    /// Simulator id.
    pub sim: String,
    /// Model name.
    pub model: String,
    /// State names.
    pub state_names: Vec<String>,
    /// Input names.
    pub input_names: Vec<String>,
    /// Sampling period.
    pub dt: f64,
    /// Reference state.
    pub reference: Vec<f64>,
    /// States x_0..x_T.
    pub x: Vec<Vec<f64>>,
    /// Inputs u_0..u_{T-1}.
    pub u: Vec<Vec<f64>>,
    /// Final error norm (angles wrapped).
    pub final_error: f64,
    /// First step from which the state stays within the SPEC goal ([`GoalSpec::default`]:
    /// 0.05 for angles, 0.1 for the others) of the reference for 50 steps; `None` if never.
    pub time_to_goal_steps: Option<usize>,
    /// Median solve time inside the service in µs.
    pub solve_median_us: f64,
    /// Median solve round trip (query to reply) in µs.
    pub solve_round_trip_median_us: f64,
    /// Solves whose status was not `solved`.
    pub not_solved: usize,
}

/// A closed-loop regulation task for the MPC service.
#[derive(Clone, Debug)]
pub struct ControlTask<'a> {
    /// MPC service id.
    pub mpc_id: &'a str,
    /// Model name (configured on the service).
    pub model: &'a str,
    /// Initial state.
    pub x0: &'a [f64],
    /// Reference state.
    pub reference: &'a [f64],
    /// Closed-loop steps.
    pub steps: usize,
}

/// Closed-loop regulation of `sim` by the MPC service (lockstep): reset to `x0`, then `steps`
/// times solve → apply the first input → step.
pub fn closed_loop(
    client: &Client,
    live: &Liveliness,
    sim: &mut SimClient,
    task: &ControlTask<'_>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ControlReport> {
    let ControlTask {
        mpc_id,
        model,
        x0,
        reference,
        steps,
    } = *task;
    let info = sim.info.sim.clone();
    let first = sim.reset(&ResetRequest {
        seed: None,
        x0: Some(x0.to_vec()),
    })?;
    let key = client.keys.mpc_solve(mpc_id)?;
    let who = format!("MPC service '{mpc_id}'");
    let mut xs = vec![first.x];
    let mut us = Vec::new();
    let (mut solve_us, mut rt_us, mut not_solved) = (Vec::new(), Vec::new(), 0);
    for k in 0..steps {
        let req = SolveRequest {
            model: model.to_string(),
            x: xs[k].clone(),
            reference: reference.to_vec(),
        };
        let t = Instant::now();
        let p = client.start(&key, req.encode(), Duration::from_secs(10), &who)?;
        let b = p.wait(Some((live, Role::Mpc, mpc_id)))?;
        rt_us.push(t.elapsed().as_secs_f64() * 1e6);
        let r = SolveReply::decode(&b)?;
        if r.u.len() < info.nu() {
            return Err(Error::protocol(
                ErrorCode::Dimension,
                format!("{who} returned {} inputs", r.u.len()),
            ));
        }
        solve_us.push(r.solve_time_ns as f64 / 1e3);
        if r.status != SolveStatus::Solved {
            not_solved += 1;
        }
        let u = r.u[..info.nu()].to_vec();
        let next = sim.step(&u, Some(live))?;
        xs.push(next.x);
        us.push(u);
        progress(k + 1, steps);
    }
    let errs: Vec<Vec<f64>> = xs
        .iter()
        .map(|x| wrapped_error(x, reference, &info.angle_indices))
        .collect();
    Ok(ControlReport {
        sim: sim.id.clone(),
        model: model.to_string(),
        state_names: info.state_names.clone(),
        input_names: info.input_names.clone(),
        dt: info.dt,
        reference: reference.to_vec(),
        x: xs,
        u: us,
        final_error: final_error(&errs),
        time_to_goal_steps: time_to_goal(&errs, &info.angle_indices, &GoalSpec::default()),
        solve_median_us: quantile(&solve_us, 0.5),
        solve_round_trip_median_us: quantile(&rt_us, 0.5),
        not_solved,
    })
}
