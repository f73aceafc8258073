//! The control phase of a run: every `[control]` entry's reference read, its model configured on
//! the MPC service, and the controlled simulators stepped in lockstep loops ([`control_loop`]):
//! every simulator's first entry in one loop, its labelled further entries in the rounds after;
//! optionally each of the first loop's simulators alone too, for the loop's slowdown figure.

use std::time::Duration;

use super::commands::Placeholders;
use super::control_loop::{control_loop, LoopReport};
use super::control_settings::{controlled_sim, mpc_config, position_loop_of};
use super::position_loop::PositionLoop;
use super::reference::{reference_of, Reference};
use super::{ControlReport, ControlTask, Event, SERVICES_ID};
use crate::client::{Client, Liveliness, SimClient};
use crate::error::{Error, Result};
use crate::scenario::{Controller, Scenario};
use crate::services::mpc::{configure, ConfigureRequest};

/// One control entry made ready: which simulator, which model, what to track.
struct Prepared {
    sim: usize,
    model: String,
    reference: Reference,
    mpc: koopman::mpc::MpcConfig,
    position_loop: Option<PositionLoop>,
    perturbation: Option<crate::messages::Perturbation>,
    /// Whether it runs in this pass (a row that needs no trained model runs in the first only).
    included: bool,
}

/// What the control phase is asked to do.
pub struct ControlPhase<'a> {
    /// The model this pass trained for simulator `id` (`{scenario}-{id}`...), `None` when the
    /// run trains none.
    pub model_of: &'a dyn Fn(&str) -> Option<String>,
    /// The first pass (of one per trained kind): the entries that need no trained model (a
    /// baseline controller, an entry naming its `model`) run in it only.
    pub first_pass: bool,
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
/// loop's figures. `clients[j]` is `sc.sims[j]`'s client. Every simulator's first entry steps
/// in one lockstep loop (round 0, whose figures are the loop's); a simulator's second, third...
/// entries (labelled rows: another controller, another plan) run in the rounds after it, each
/// round's MPC models configured just before it.
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
        let at =
            |e: Error| Error::Config(format!("[control] for simulator '{}': {e}", sc.sims[j].id));
        let mpc = mpc_config(info, &ctrl.mpc)?;
        let reference = reference_of(ctrl, info.nx(), info.nu(), ph).map_err(at)?;
        let position_loop = match &ctrl.position_loop {
            Some(s) => Some(position_loop_of(s, info, &mpc).map_err(|e| at(Error::Config(e)))?),
            None => None,
        };
        let trained = (what.model_of)(&sc.sims[j].id);
        let needs_trained = ctrl.controller == Controller::Mpc && ctrl.model.is_none();
        prepared.push(Prepared {
            sim: j,
            included: what.first_pass || needs_trained,
            // A baseline row keeps the pass's model name (as before), or none.
            model: ctrl.model.clone().or(trained).unwrap_or_default(),
            reference,
            mpc,
            position_loop,
            perturbation: ctrl.perturbation.as_ref().map(|p| p.for_reference(0)),
        });
    }
    let included: Vec<usize> = (0..prepared.len())
        .filter(|&i| prepared[i].included)
        .collect();
    let rounds: Vec<Vec<usize>> = rounds_of(
        &included
            .iter()
            .map(|&i| prepared[i].sim)
            .collect::<Vec<_>>(),
    )
    .into_iter()
    .map(|r| r.into_iter().map(|k| included[k]).collect())
    .collect();
    let configure_round = |which: &[usize]| -> Result<()> {
        for &i in which {
            let (p, ctrl) = (&prepared[i], &sc.control[i]);
            if ctrl.controller == Controller::Mpc {
                let req = ConfigureRequest {
                    model: p.model.clone(),
                    mpc: Some(p.mpc.clone()),
                    offset_free: ctrl.offset_free.clone(),
                };
                configure(client, SERVICES_ID, &req, Duration::from_secs(60))?;
            }
        }
        Ok(())
    };
    let run = |clients: &mut [SimClient],
               which: &[usize],
               publish: bool,
               on: &mut dyn FnMut(Event<'_>)|
     -> Result<(Vec<ControlReport>, LoopReport)> {
        // Disjoint &mut borrows of the controlled clients, in the order of `which` (a round
        // holds at most one entry per simulator).
        let mut slots: Vec<Option<&mut SimClient>> = clients.iter_mut().map(Some).collect();
        let (mut jobs, mut ids) = (Vec::new(), Vec::new());
        for &i in which {
            let (p, ctrl) = (&prepared[i], &sc.control[i]);
            let Some(c) = slots[p.sim].take() else {
                return Err(Error::Config(format!(
                    "simulator '{}' twice in one control round",
                    sc.sims[p.sim].id
                )));
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
                    controller: ctrl.controller,
                    label: ctrl.label.as_deref(),
                    clip: p.mpc.u_min.as_deref().zip(p.mpc.u_max.as_deref()),
                    perturbation: p.perturbation.as_ref(),
                    observation_noise: ctrl.observation_noise.as_ref(),
                    view: Some(super::view::StepView {
                        view: what.view,
                        row: ctrl.label.as_deref().unwrap_or(&p.model),
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
    let mut reports: Vec<Option<ControlReport>> = vec![None; prepared.len()];
    let mut figures = None;
    for (r, which) in rounds.iter().enumerate() {
        if r > 0 {
            let rows: Vec<&str> = which
                .iter()
                .map(|&i| sc.control[i].label.as_deref().unwrap_or("?"))
                .collect();
            on(Event::Phase(&format!(
                "closed-loop control: {}",
                rows.join(", ")
            )));
        }
        configure_round(which)?;
        let (got, loop_report) = run(clients, which, what.publish, on)?;
        for (&i, mut report) in which.iter().zip(got) {
            report.mpc = Some(prepared[i].mpc.clone());
            report.offset_free = sc.control[i].offset_free.clone();
            reports[i] = Some(report);
        }
        if r == 0 {
            figures = Some(loop_report);
        }
    }
    let mut figures = figures.unwrap_or_default();
    let first = rounds.first().cloned().unwrap_or_default();
    if what.baseline && first.len() > 1 {
        on(Event::Phase(
            "each controlled simulator alone in the loop (baseline)",
        ));
        configure_round(&first)?;
        for &i in &first {
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
    Ok((reports.into_iter().flatten().collect(), figures))
}

/// The rounds of control entries driving simulators `sims` (entry i drives `sims[i]`): round r
/// holds every simulator's (r+1)-th entry, in entry order.
fn rounds_of(sims: &[usize]) -> Vec<Vec<usize>> {
    let mut rounds: Vec<Vec<usize>> = Vec::new();
    for (i, &sim) in sims.iter().enumerate() {
        let r = sims[..i].iter().filter(|&&o| o == sim).count();
        if rounds.len() <= r {
            rounds.resize_with(r + 1, Vec::new);
        }
        rounds[r].push(i);
    }
    rounds
}

#[cfg(test)]
mod tests {
    use super::rounds_of;

    #[test]
    fn a_simulators_later_entries_run_in_later_rounds_in_entry_order() {
        assert_eq!(rounds_of(&[0, 1]), vec![vec![0, 1]]);
        assert_eq!(
            rounds_of(&[0, 0, 1, 0, 1]),
            vec![vec![0, 2], vec![1, 4], vec![3]]
        );
        assert!(rounds_of(&[]).is_empty());
    }
}
