//! On-policy aggregation (`koopbridge run --aggregate ROUNDS`, the paper's Strategy III): the
//! recorder records every controlled simulator's closed-loop rollout, the trainer retrains that
//! simulator's model on the union of the collected training windows and every rollout so far
//! (windows of the scenario's T), and control runs again; the error before and after each round.

use std::path::Path;
use std::time::Duration;

use koopman::data::Dataset;
use serde::{Deserialize, Serialize};

use super::commands::Placeholders;
use super::control::{control_phase, ControlPhase};
use super::run::{train_model, TrainReport};
use super::{Cluster, ControlReport, Event, RunOptions, SERVICES_ID};
use crate::client::SimClient;
use crate::error::{Error, Result};
use crate::fsutil::write_atomic;
use crate::scenario::Scenario;
use crate::services::recorder::{record_start, record_stop, RecordSummary};

/// One simulator in one aggregation round.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct AggregatedSim {
    /// Simulator id.
    pub sim: String,
    /// What the recorder recorded of the previous control run.
    pub recorded: RecordSummary,
    /// Training windows of the retrained model (collected + every rollout so far).
    pub train_windows: usize,
    /// The retrained model's training.
    pub train: TrainReport,
    /// Tracking RMS (every state and step) of the control run before the round (with the
    /// previous model).
    pub error_before: f64,
    /// Tracking RMS of the control run with the retrained model.
    pub error_after: f64,
    /// Final error before the round.
    pub final_error_before: f64,
    /// Final error with the retrained model.
    pub final_error_after: f64,
    /// The control run with the retrained model.
    pub control: ControlReport,
}

/// One aggregation round.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct AggregationRound {
    /// Round number, from 1.
    pub round: usize,
    /// Per controlled simulator (in `[control]` order).
    pub sims: Vec<AggregatedSim>,
}

/// The name of the recording of simulator `sim`'s control run before round `round`.
fn recording(sc: &Scenario, sim: &str, round: usize) -> String {
    format!("{}-{sim}-rollout-{round}", sc.name)
}

/// The model of simulator `sim` after round `round` (round 0: the scenario's model).
pub fn model_name(sc: &Scenario, sim: &str, round: usize) -> String {
    if round == 0 {
        format!("{}-{sim}", sc.name)
    } else {
        format!("{}-{sim}-agg{round}", sc.name)
    }
}

/// Starts recording every controlled simulator's state stream (windows of the scenario's T;
/// a fixed `reference` goes to the MCAP file's reference channel).
pub fn start_recording(sc: &Scenario, cluster: &Cluster) -> Result<()> {
    for ctrl in &sc.control {
        let sim = sc.controlled_id(ctrl);
        record_start(
            &cluster.client,
            SERVICES_ID,
            sim,
            Some(sc.collect.steps),
            ctrl.reference.clone(),
            Duration::from_secs(30),
        )?;
    }
    Ok(())
}

/// The windows of several datasets of the same shape, in order.
pub fn union(parts: &[Dataset]) -> Result<Dataset> {
    let first = parts
        .first()
        .ok_or_else(|| Error::Config("nothing to aggregate".into()))?;
    let mut out = first.clone();
    for d in &parts[1..] {
        if (d.steps, d.nx, d.nu) != (first.steps, first.nx, first.nu) {
            return Err(Error::Config(format!(
                "cannot aggregate windows of (T, nx, nu) = {:?} with {:?}",
                (d.steps, d.nx, d.nu),
                (first.steps, first.nx, first.nu)
            )));
        }
        out.n += d.n;
        out.x.extend_from_slice(&d.x);
        out.u.extend_from_slice(&d.u);
    }
    out.meta.policy = format!("{} + closed-loop rollouts", first.meta.policy);
    Ok(out)
}

/// Stops the recording of `sim` and fetches it from the recorder (`…/data/{name}`) into
/// `path`.
fn fetch_rollout(
    sc: &Scenario,
    cluster: &Cluster,
    sim: &str,
    round: usize,
    path: &Path,
) -> Result<(RecordSummary, Dataset)> {
    let name = recording(sc, sim, round);
    let summary = record_stop(
        &cluster.client,
        SERVICES_ID,
        sim,
        &name,
        Duration::from_secs(60),
    )?;
    let key = cluster.client.keys.data(&name)?;
    let bytes = cluster.client.query(
        &key,
        Vec::new(),
        Duration::from_secs(60),
        &format!("recorder '{SERVICES_ID}'"),
    )?;
    write_atomic(path, &bytes)?;
    Ok((summary, Dataset::load_npz(path)?))
}

/// Runs `rounds` aggregation rounds after the first control run, whose reports are `first`
/// (recorded: [`start_recording`] was called before it and it published its states).
#[allow(clippy::too_many_arguments)]
pub fn aggregate(
    sc: &Scenario,
    opts: &RunOptions,
    cluster: &Cluster,
    clients: &mut [SimClient],
    ph: &Placeholders,
    first: &[ControlReport],
    rounds: usize,
    on: &mut dyn FnMut(Event<'_>),
) -> Result<Vec<AggregationRound>> {
    let ids: Vec<String> = sc
        .control
        .iter()
        .map(|c| sc.controlled_id(c).to_string())
        .collect();
    let mut rollouts: Vec<Vec<Dataset>> = ids
        .iter()
        .map(|id| {
            Dataset::load_npz(&opts.out_dir.join("data").join(id).join("train.npz"))
                .map(|d| vec![d])
        })
        .collect::<std::result::Result<_, _>>()?;
    let mut current: Vec<ControlReport> = first.to_vec();
    let mut out = Vec::new();
    for round in 1..=rounds {
        on(Event::Phase(&format!("aggregation round {round}/{rounds}: retraining on the collected data + the closed-loop rollouts")));
        let mut trained = Vec::new();
        for (i, id) in ids.iter().enumerate() {
            let dir = opts.out_dir.join("data").join(id);
            let (summary, ds) = fetch_rollout(
                sc,
                cluster,
                id,
                round,
                &dir.join(format!("rollout-{round}.npz")),
            )?;
            if ds.n > 0 {
                rollouts[i].push(ds);
            }
            let all = union(&rollouts[i])?;
            let path = dir.join(format!("train-agg{round}.npz"));
            all.save_npz(&path)?;
            let report = train_model(sc, opts, cluster, id, &model_name(sc, id, round), &path, on)?;
            trained.push((summary, all.n, report));
        }
        if round < rounds {
            start_recording(sc, cluster)?;
        }
        let model_of = |id: &str| model_name(sc, id, round);
        let (next, _) = control_phase(
            sc,
            &cluster.client,
            &cluster.live,
            clients,
            ph,
            &ControlPhase {
                model_of: &model_of,
                publish: round < rounds,
                baseline: false,
                deprioritise: &|id| cluster.deprioritise_sim(id),
            },
            on,
        )?;
        let sims = trained
            .into_iter()
            .zip(current.iter().zip(&next))
            .zip(&ids)
            .map(
                |(((recorded, train_windows, train), (before, after)), id)| AggregatedSim {
                    sim: id.clone(),
                    recorded,
                    train_windows,
                    train,
                    error_before: before.tracking_rms_total,
                    error_after: after.tracking_rms_total,
                    final_error_before: before.final_error,
                    final_error_after: after.final_error,
                    control: after.clone(),
                },
            )
            .collect();
        out.push(AggregationRound { round, sims });
        current = next;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use koopman::data::{DatasetMeta, Pairing};

    fn ds(n: usize, v: f64) -> Dataset {
        Dataset {
            n,
            steps: 1,
            nx: 1,
            nu: 1,
            x: vec![v; n * 2],
            u: vec![v; n],
            meta: DatasetMeta {
                env: "e".into(),
                dt: 0.1,
                state_names: vec!["x".into()],
                input_names: vec!["u".into()],
                pairing: Pairing::Aligned,
                seed: 1,
                source: "s".into(),
                policy: "uniform".into(),
                region: None,
            },
        }
    }

    #[test]
    fn the_union_keeps_every_window_in_order_and_refuses_other_shapes() {
        let u = union(&[ds(2, 1.0), ds(1, 2.0)]).unwrap();
        assert_eq!(u.n, 3);
        assert_eq!(u.x, [1.0, 1.0, 1.0, 1.0, 2.0, 2.0]);
        assert_eq!(u.u, [1.0, 1.0, 2.0]);
        u.validate().unwrap();
        let mut other = ds(1, 0.0);
        other.nx = 2;
        other.x = vec![0.0; 4];
        assert!(union(&[ds(1, 0.0), other]).is_err());
    }
}
