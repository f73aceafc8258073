//! The control phase of a run: every `[control]` entry's model configured on the MPC service,
//! its reference read, and all controlled simulators stepped in one lockstep loop
//! ([`control_loop`]); optionally each of them alone too, for the loop's slowdown figure.

use std::time::Duration;

use super::commands::Placeholders;
use super::control_loop::{control_loop, LoopReport};
use super::control_settings::{controlled_sim, mpc_config, position_loop_of};
use super::position_loop::PositionLoop;
use super::reference::{reference_of, Reference};
use super::{ControlReport, ControlTask, Event, SERVICES_ID};
use crate::client::{Client, Liveliness, SimClient};
use crate::error::{Error, Result};
use crate::scenario::Scenario;
use crate::services::mpc::{configure, ConfigureRequest};

/// One control entry made ready: which simulator, which model, what to track.
struct Prepared {
    sim: usize,
    model: String,
    reference: Reference,
    mpc: koopman::mpc::MpcConfig,
    position_loop: Option<PositionLoop>,
}

/// What the control phase is asked to do.
pub struct ControlPhase<'a> {
    /// The model of simulator `id` (default `{scenario}-{id}`).
    pub model_of: &'a dyn Fn(&str) -> String,
    /// Publish the executed states (for the recorder).
    pub publish: bool,
    /// Also run each controlled simulator alone in the loop (after the loop of all), for
    /// [`LoopReport::slowdown_vs_slowest_alone`].
    pub baseline: bool,
    /// Lowers the CPU priority of simulator `id`'s process once the loop of several has found
    /// another one to be its critical path; true if it did (e.g. [`super::Cluster::deprioritise_sim`]).
    pub deprioritise: &'a dyn Fn(&str) -> bool,
    /// Where the closed loops are shown to a viewer.
    pub view: &'a super::view::RunView,
}

/// Runs the control phase of `sc`: returns one report per `[control]` entry (in order) and the
/// loop's figures. `clients[j]` is `sc.sims[j]`'s client.
pub fn control_phase(
    sc: &Scenario,
    client: &Client,
    live: &Liveliness,
    clients: &mut [SimClient],
    ph: &Placeholders,
    what: &ControlPhase<'_>,
    on: &mut dyn FnMut(Event<'_>),
) -> Result<(Vec<ControlReport>, LoopReport)> {
    let mut prepared = Vec::new();
    for ctrl in &sc.control {
        let j = controlled_sim(sc, ctrl);
        let info = &clients[j].info.sim;
        let model = (what.model_of)(&sc.sims[j].id);
        let mpc = mpc_config(info, &ctrl.mpc)?;
        let at =
            |e: Error| Error::Config(format!("[control] for simulator '{}': {e}", sc.sims[j].id));
        let reference = reference_of(ctrl, info.nx(), info.nu(), ph).map_err(at)?;
        let position_loop = match &ctrl.position_loop {
            Some(s) => Some(position_loop_of(s, info, &mpc).map_err(|e| at(Error::Config(e)))?),
            None => None,
        };
        let req = ConfigureRequest {
            model: model.clone(),
            mpc: Some(mpc.clone()),
            offset_free: ctrl.offset_free.clone(),
        };
        configure(client, SERVICES_ID, &req, Duration::from_secs(60))?;
        prepared.push(Prepared {
            sim: j,
            model,
            reference,
            mpc,
            position_loop,
        });
    }
    let run = |clients: &mut [SimClient],
               which: &[usize],
               publish: bool,
               on: &mut dyn FnMut(Event<'_>)|
     -> Result<(Vec<ControlReport>, LoopReport)> {
        // Disjoint &mut borrows of the controlled clients, in the order of `which`.
        let mut slots: Vec<Option<&mut SimClient>> = clients.iter_mut().map(Some).collect();
        let (mut jobs, mut ids) = (Vec::new(), Vec::new());
        for &i in which {
            let (p, ctrl) = (&prepared[i], &sc.control[i]);
            let Some(c) = slots[p.sim].take() else {
                continue;
            };
            ids.push(sc.sims[p.sim].id.as_str());
            jobs.push((
                c,
                ControlTask {
                    mpc_id: SERVICES_ID,
                    model: &p.model,
                    x0: &ctrl.x0,
                    reference: &p.reference,
                    horizon: p.mpc.horizon,
                    position_loop: p.position_loop.as_ref(),
                    steps: ctrl.steps,
                    publish,
                    replay: None,
                    perturbation: None,
                    view: Some(super::view::StepView {
                        view: what.view,
                        row: &p.model,
                        episode: None,
                    }),
                },
            ));
        }
        // The others yield to the critical path: on 2 cores the macro step then costs less.
        let mut yield_to = |critical: usize| -> Vec<String> {
            ids.iter()
                .enumerate()
                .filter(|&(j, id)| j != critical && (what.deprioritise)(id))
                .map(|(_, id)| id.to_string())
                .collect()
        };
        control_loop(
            client,
            live,
            jobs,
            &mut |k, n| on(Event::Control(k, n)),
            &mut yield_to,
        )
    };
    let all: Vec<usize> = (0..prepared.len()).collect();
    let (mut reports, mut figures) = run(clients, &all, what.publish, on)?;
    for ((r, p), ctrl) in reports.iter_mut().zip(&prepared).zip(&sc.control) {
        r.mpc = Some(p.mpc.clone());
        r.offset_free = ctrl.offset_free.clone();
    }
    if what.baseline && prepared.len() > 1 {
        on(Event::Phase(
            "each controlled simulator alone in the loop (baseline)",
        ));
        for &i in &all {
            // Not published: the recordings are of the loop of all.
            let (_, alone) = run(clients, &[i], false, on)?;
            figures
                .alone_steps_per_second
                .push(alone.macro_steps_per_second);
        }
        let slowest = figures
            .alone_steps_per_second
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min);
        figures.slowdown_vs_slowest_alone =
            Some(slowest / figures.macro_steps_per_second.max(1e-9));
    }
    Ok((reports, figures))
}
