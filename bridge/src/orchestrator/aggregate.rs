//! On-policy aggregation (`koopbridge run --aggregate ROUNDS`, the paper's Strategy III): the
//! recorder records every controlled simulator's closed-loop rollout, the trainer retrains that
//! simulator's model on the union of the collected training windows and every rollout so far
//! (windows of the scenario's T), and control runs again; each round's control result beside the
//! previous one's, and a warning when a round made control worse ([`regression`]).

use std::path::Path;
use std::time::Duration;

use koopman::data::Dataset;
use serde::{Deserialize, Serialize};

use super::commands::Placeholders;
use super::control::{control_phase, ControlPhase};
use super::train::{train_model, TrainReport};
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
    /// Time to goal (steps) before the round; `None` = never.
    #[serde(default)]
    pub time_to_goal_before: Option<usize>,
    /// Time to goal (steps) with the retrained model; `None` = never.
    #[serde(default)]
    pub time_to_goal_after: Option<usize>,
    /// Solves that were not `solved` before the round.
    #[serde(default)]
    pub not_solved_before: usize,
    /// Solves that were not `solved` with the retrained model.
    #[serde(default)]
    pub not_solved_after: usize,
    /// What got worse in this round ([`regression`]); absent when nothing did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub regression: Option<String>,
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

/// A figure counts as worse after a round when it grew by more than this fraction …
pub const REGRESSION_RELATIVE: f64 = 0.1;
/// … and by more than this amount (errors so small that their change is noise are not
/// regressions).
pub const REGRESSION_ABSOLUTE: f64 = 1e-3;

/// What got worse from the control run `before` a round to the one `after` it, in words
/// (`None` when nothing did): the final error or the tracking RMS grew by more than
/// [`REGRESSION_RELATIVE`] and [`REGRESSION_ABSOLUTE`], the goal reached before is no longer
/// reached, or more solves failed to solve.
pub fn regression(before: &ControlReport, after: &ControlReport) -> Option<String> {
    let worse = |b: f64, a: f64| a > b * (1.0 + REGRESSION_RELATIVE) + REGRESSION_ABSOLUTE;
    let mut what = Vec::new();
    for (name, b, a) in [
        ("final error", before.final_error, after.final_error),
        (
            "tracking RMS",
            before.tracking_rms_total,
            after.tracking_rms_total,
        ),
    ] {
        if worse(b, a) || (b.is_finite() && !a.is_finite()) {
            what.push(format!(
                "{name} {b:.4} -> {a:.4} ({:.1}x)",
                a / b.max(1e-300)
            ));
        }
    }
    if let (Some(b), None) = (before.time_to_goal_steps, after.time_to_goal_steps) {
        what.push(format!("time to goal {b} steps -> never"));
    }
    if after.not_solved > before.not_solved {
        what.push(format!(
            "unsolved MPC steps {} -> {}",
            before.not_solved, after.not_solved
        ));
    }
    (!what.is_empty()).then(|| what.join(", "))
}

/// The warnings of one aggregation round: every simulator whose control got worse than with the
/// previous round's model ([`AggregatedSim::regression`]), and every control run of the round
/// whose MPC did not solve every step.
pub fn round_warnings(round: &AggregationRound) -> Vec<String> {
    let mut out = Vec::new();
    for a in &round.sims {
        if let Some(what) = &a.regression {
            out.push(format!(
                "aggregation round {} made control of '{}' worse than {} ({what}); model '{}' \
                 is the retrained one",
                round.round,
                a.sim,
                if round.round == 1 {
                    "the model trained on the collected data".to_string()
                } else {
                    format!("round {}", round.round - 1)
                },
                a.control.model
            ));
        }
        out.extend(a.control.warnings());
    }
    out
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
        let model_of = |id: &str| Some(model_name(sc, id, round));
        let (next, _) = control_phase(
            sc,
            &cluster.client,
            &cluster.live,
            clients,
            ph,
            &ControlPhase {
                model_of: &model_of,
                first_pass: true,
                publish: round < rounds,
                baseline: false,
                deprioritise: &|id| cluster.deprioritise_sim(id),
                view: &cluster.view,
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
                    time_to_goal_before: before.time_to_goal_steps,
                    time_to_goal_after: after.time_to_goal_steps,
                    not_solved_before: before.not_solved,
                    not_solved_after: after.not_solved,
                    regression: regression(before, after),
                    control: after.clone(),
                },
            )
            .collect();
        let done = AggregationRound { round, sims };
        for w in round_warnings(&done) {
            on(Event::Warning(&w));
        }
        out.push(done);
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
                window_flags: None,
            },
        }
    }

    fn control(
        final_error: f64,
        rms: f64,
        goal: Option<usize>,
        not_solved: usize,
    ) -> ControlReport {
        ControlReport {
            sim: "pend".into(),
            model: "m-agg1".into(),
            label: None,
            controller: Default::default(),
            perturbation: None,
            state_names: vec!["x".into()],
            input_names: vec!["u".into()],
            dt: 0.1,
            reference: vec![0.0],
            reference_trajectory: None,
            x: vec![vec![0.0]; 3],
            u: vec![vec![0.0]; 2],
            final_error,
            time_to_goal_steps: goal,
            error: Vec::new(),
            tracking_rms: vec![rms],
            tracking_rms_total: rms,
            solve_median_us: 0.0,
            solve_round_trip_median_us: 0.0,
            step_round_trip_median_us: 0.0,
            not_solved,
            not_solved_by_status: if not_solved > 0 {
                [("fallback".to_string(), not_solved)].into()
            } else {
                Default::default()
            },
            offset_free: None,
            mpc: None,
            error_state: false,
            position_loop: None,
            observation_noise: None,
            step_flags: Default::default(),
        }
    }

    #[test]
    fn a_round_that_makes_control_worse_is_a_regression_and_a_warning() {
        let before = control(0.040, 0.2, Some(30), 0);
        // The round: final error 0.040 -> 0.444.
        let worse = control(0.444, 0.2, Some(30), 0);
        let what = regression(&before, &worse).unwrap();
        assert!(
            what.contains("final error 0.0400 -> 0.4440 (11.1x)"),
            "{what}"
        );
        assert!(!what.contains("tracking RMS"), "{what}");
        // Within 10 % and 0.001: noise, not a regression; better is not one either.
        assert_eq!(
            regression(&before, &control(0.0449, 0.2209, Some(30), 0)),
            None
        );
        assert_eq!(regression(&before, &control(0.001, 0.1, Some(5), 0)), None);
        // Each figure on its own: tracking RMS, the goal lost, unsolved steps, a NaN.
        let w = regression(&before, &control(0.04, 0.3, Some(30), 0)).unwrap();
        assert!(w.starts_with("tracking RMS 0.2000 -> 0.3000"), "{w}");
        let w = regression(&before, &control(0.04, 0.2, None, 0)).unwrap();
        assert_eq!(w, "time to goal 30 steps -> never");
        let w = regression(&before, &control(0.04, 0.2, Some(30), 2)).unwrap();
        assert_eq!(w, "unsolved MPC steps 0 -> 2");
        assert!(regression(&before, &control(f64::NAN, 0.2, Some(30), 0)).is_some());
        // The round's warnings: the regression, naming the round and what it compares with,
        // and the unsolved steps of its control run.
        let sim = |after: ControlReport| AggregatedSim {
            sim: "pend".into(),
            recorded: RecordSummary::default(),
            train_windows: 3,
            train: TrainReport {
                sim: "pend".into(),
                model: after.model.clone(),
                job: "j".into(),
                metrics: serde_json::Value::Null,
                reused: false,
            },
            error_before: before.tracking_rms_total,
            error_after: after.tracking_rms_total,
            final_error_before: before.final_error,
            final_error_after: after.final_error,
            time_to_goal_before: before.time_to_goal_steps,
            time_to_goal_after: after.time_to_goal_steps,
            not_solved_before: before.not_solved,
            not_solved_after: after.not_solved,
            regression: regression(&before, &after),
            control: after,
        };
        let round = AggregationRound {
            round: 1,
            sims: vec![sim(control(0.444, 0.2, Some(30), 2))],
        };
        let w = round_warnings(&round);
        assert_eq!(w.len(), 2, "{w:?}");
        assert!(
            w[0].starts_with(
                "aggregation round 1 made control of 'pend' worse than the model \
                              trained on the collected data (final error 0.0400 -> 0.4440"
            ),
            "{}",
            w[0]
        );
        assert!(
            w[1].contains("did not solve 2 of 2 steps (fallback 2)"),
            "{}",
            w[1]
        );
        let round = AggregationRound {
            round: 2,
            sims: vec![sim(control(0.02, 0.1, Some(30), 0))],
        };
        assert!(round_warnings(&round).is_empty());
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
