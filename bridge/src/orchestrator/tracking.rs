//! The tracking phase of a run: each tracking task (`[control]` with `references`) runs one closed
//! loop per reference from its first state — the same [`ControlRun`] as every closed loop — for
//! every trained model kind and every model trained elsewhere (`[train] pretrained`), and the
//! replay row (the references' inputs open loop); scores them
//! with the survival metric ([`super::survival`]) and writes the closed loops as on-policy
//! training windows.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::rc::Rc;
use std::time::{Duration, Instant};

use koopman::data::{Dataset, Normalisation};
use koopman::mpc::metrics::quantile;
use koopman::mpc::MpcConfig;

pub use super::tracking_report::{table, OnPolicy, TrackReport, TrackRow, REPLAY_ROW};

use super::closed_loop::{ControlReport, ControlRun, ControlTask};
use super::commands::Placeholders;
use super::control_settings::mpc_config;
use super::pretrained::Pretrained;
use super::reference::{reference_path, Reference};
use super::reference_set::ReferenceSet;
use super::survival::{fails, mean_abs_error, survival_of_run, windows, RunForWindows, Summary};
use super::view::{RunView, StepView};
use super::{Event, SERVICES_ID};
use crate::client::{Client, Liveliness, SimClient};
use crate::error::{Error, ErrorCode, Result};
use crate::messages::Perturbation;
use crate::scenario::{Scenario, TrackSpec};
use crate::services::model_kind::ModelKind;
use crate::services::mpc::{configure, ConfigureRequest};

/// The replay rows run so far, by simulator, references file, perturbation, metric and length:
/// a replay is deterministic, so a second task (or an aggregation round) with the same key
/// reuses it. Kept by the caller across tracking passes.
#[derive(Default)]
pub struct ReplayCache(BTreeMap<(usize, PathBuf, String), (TrackRow, Vec<Scored>)>);

/// What the tracking phase needs besides the scenario.
pub struct TrackingPhase<'a> {
    /// The run's output folder (`tracking/onpolicy/` is written under it; the training data are
    /// read from `data/{sim}/train.npz` for `q_from_data`).
    pub out_dir: &'a Path,
    /// The model kinds trained (one row each).
    pub kinds: &'a [ModelKind],
    /// The model of simulator `sim` and kind `kind` ([`Scenario::model_name`], or an
    /// aggregation round's).
    pub model_of: &'a dyn Fn(&str, ModelKind) -> String,
    /// Models trained elsewhere (`[train] pretrained`): one more row each in their simulator's
    /// tasks, after the trained kinds'.
    pub pretrained: &'a [Pretrained],
    /// Whether aggregation rounds follow: the tasks marked `aggregate` (whose only purpose is
    /// their on-policy windows) run only then.
    pub aggregating: bool,
    /// The replay rows of earlier tasks and passes.
    pub replays: &'a RefCell<ReplayCache>,
    /// Where the closed loops are shown to a viewer.
    pub view: &'a RunView,
}

/// One run of one row on one reference, as scored.
struct Scored {
    report: ControlReport,
    solve_us: Vec<f64>,
    terminated: Vec<bool>,
    failure: Option<String>,
    survival: Option<usize>,
    errors: Vec<f64>,
}

/// Runs every tracking task of `sc` (in order); `clients[j]` is `sc.sims[j]`'s client.
pub fn tracking_phase(
    sc: &Scenario,
    client: &Client,
    live: &Liveliness,
    clients: &mut [SimClient],
    ph: &Placeholders,
    what: &TrackingPhase<'_>,
    on: &mut dyn FnMut(Event<'_>),
) -> Result<Vec<TrackReport>> {
    // The replay row of a simulator, file, perturbation, metric and length is run once.
    let mut replays = what.replays.borrow_mut();
    // Each references file and each simulator's training spread is read once.
    let mut loaded: BTreeMap<PathBuf, Rc<ReferenceSet>> = BTreeMap::new();
    let mut spreads: BTreeMap<String, Normalisation> = BTreeMap::new();
    let mut out = Vec::new();
    for t in sc
        .tracks
        .iter()
        .filter(|t| what.aggregating || !t.aggregate)
    {
        let j = sc.tracked_index(t);
        let sim_id = sc.sims[j].id.clone();
        let at = |e: Error| Error::Config(format!("[control] for simulator '{sim_id}': {e}"));
        let info = clients[j].info.sim.clone();
        let (nx, nu) = (info.nx(), info.nu());
        t.check_states(nx, &sim_id)?;
        let path = reference_path(&t.references, ph);
        let refs = match loaded.get(&path) {
            Some(r) => Rc::clone(r),
            None => {
                let r = Rc::new(ReferenceSet::load(&path, nx, nu)?);
                loaded.insert(path.clone(), Rc::clone(&r));
                r
            }
        };
        if (t.error_state || t.replay) && refs.u.is_none() {
            return Err(at(Error::Config(format!(
                "{} has no `u` (N, T, nu): {} needs the inputs that realised the references",
                path.display(),
                if t.error_state {
                    "error_state"
                } else {
                    "the replay row (set replay = false to skip it)"
                }
            ))));
        }
        let steps = t.steps.map_or(refs.steps(), |s| s.min(refs.steps()));
        let mut mpc = mpc_config(&info, &t.mpc).map_err(at)?;
        if let Some(q) = &t.q_from_data {
            let norm = match spreads.get(&sim_id) {
                Some(n) => n,
                None => {
                    let n = training_spread(what.out_dir, &sim_id)?;
                    spreads.entry(sim_id.clone()).or_insert(n)
                }
            };
            mpc.q = Some(q.weights(&norm.x_std));
        }
        let window_steps = t.onpolicy_steps.unwrap_or(sc.collect.steps);
        let perturbations: Vec<Perturbation> = match &t.perturbation {
            Some(p) => (0..refs.len()).map(|i| p.for_reference(i)).collect(),
            None => Vec::new(),
        };
        let mut rows = Vec::new();
        let replay_scored: Option<Vec<usize>> = if t.replay {
            let key = (
                j,
                path.clone(),
                serde_json::to_string(&(&t.perturbation, &t.survival, steps)).unwrap_or_default(),
            );
            if !replays.0.contains_key(&key) {
                on(Event::Phase(&format!(
                    "replaying the {} references' inputs open loop on '{sim_id}'",
                    refs.len()
                )));
                let t0 = Instant::now();
                let mut scored = Vec::new();
                // The view tells the replays of perturbed tasks apart by the task's label.
                let shown_as = match &t.label {
                    Some(l) if !l.is_empty() => format!("{REPLAY_ROW}+{l}"),
                    _ => REPLAY_ROW.to_string(),
                };
                for i in 0..refs.len() {
                    let u = &refs.u.as_ref().expect("checked above")[i];
                    let how = How {
                        row: Row::Replay(u),
                        model: "",
                        shown_as: &shown_as,
                        horizon: mpc.horizon,
                        steps,
                        perturbation: perturbations.get(i),
                        view: what.view,
                    };
                    scored.push(run_one(client, live, &mut clients[j], t, &refs, i, how)?);
                    on(Event::Control(i + 1, refs.len()));
                }
                let row = row_of(
                    REPLAY_ROW,
                    None,
                    None,
                    None,
                    &scored,
                    steps,
                    t0.elapsed().as_secs_f64(),
                );
                replays.0.insert(key.clone(), (row, scored));
            }
            let (row, scored) = &replays.0[&key];
            rows.push(row.clone());
            t.survival
                .as_ref()
                .map(|_| scored.iter().map(|s| s.survival.unwrap_or(0)).collect())
        } else {
            None
        };
        let trained = what
            .kinds
            .iter()
            .map(|&kind| ((what.model_of)(&sim_id, kind), kind));
        let given = what
            .pretrained
            .iter()
            .filter(|p| p.sim == sim_id)
            .map(|p| (p.name.clone(), p.kind));
        for (model, kind) in trained.chain(given).collect::<Vec<_>>() {
            let name = t.row(&model);
            on(Event::Phase(&format!(
                "tracking {} references on '{sim_id}' with {name} ({kind}{})",
                refs.len(),
                if t.error_state {
                    ", error-state MPC"
                } else {
                    ""
                }
            )));
            let request = ConfigureRequest {
                model: model.clone(),
                mpc: Some(mpc.clone()),
                offset_free: t.offset_free.clone(),
            };
            configure(client, SERVICES_ID, &request, Duration::from_secs(60))?;
            let t0 = Instant::now();
            let mut scored = Vec::new();
            for i in 0..refs.len() {
                if i > 0 && t.offset_free.is_some() {
                    // A fresh controller: the correction's estimate starts at zero each episode.
                    configure(client, SERVICES_ID, &request, Duration::from_secs(60))?;
                }
                let row = if t.error_state {
                    Row::ErrorState
                } else {
                    Row::Spec
                };
                let how = How {
                    row,
                    model: &model,
                    shown_as: &name,
                    horizon: mpc.horizon,
                    steps,
                    perturbation: perturbations.get(i),
                    view: what.view,
                };
                scored.push(run_one(client, live, &mut clients[j], t, &refs, i, how)?);
                on(Event::Control(i + 1, refs.len()));
            }
            let mut row = row_of(
                &name,
                Some(&model),
                Some(kind.name()),
                Some(&mpc),
                &scored,
                steps,
                t0.elapsed().as_secs_f64(),
            );
            if let (Some(floor), Some(_)) = (&replay_scored, &t.survival) {
                let pairs = row.survivals.iter().zip(floor);
                row.above_replay = Some(pairs.clone().filter(|(a, b)| a > b).count());
                row.below_replay = Some(pairs.filter(|(a, b)| a < b).count());
            }
            row.onpolicy = Some(write_onpolicy(
                what.out_dir,
                &name,
                &scored,
                window_steps,
                &info,
                t,
            )?);
            rows.push(row);
        }
        out.push(TrackReport {
            sim: sim_id.clone(),
            label: t.label.clone(),
            references_file: path.display().to_string(),
            references: refs.len(),
            steps,
            survival: t.survival.clone(),
            continue_after_failure: t.continue_after_failure,
            error_state: t.error_state,
            aggregate: t.aggregate,
            perturbation: t.perturbation.clone(),
            perturbations,
            offset_free: t.offset_free.clone(),
            rows,
        });
    }
    Ok(out)
}

/// What decides a run's inputs.
#[derive(Clone, Copy)]
enum Row<'a> {
    /// The references' inputs, open loop.
    Replay(&'a [Vec<f64>]),
    /// The MPC service with SPEC's reference window.
    Spec,
    /// The MPC service about the reference as a plan (its inputs as feed-forward).
    ErrorState,
}

/// How one run is driven: its row, the model served, the row's name in the view, the MPC
/// horizon, the steps at most, the perturbation, the view.
#[derive(Clone, Copy)]
struct How<'a> {
    row: Row<'a>,
    model: &'a str,
    shown_as: &'a str,
    horizon: usize,
    steps: usize,
    perturbation: Option<&'a Perturbation>,
    view: &'a RunView,
}

/// One closed loop (or replay) of reference `i`, scored: stops at a fall or a refused step (with
/// a survival metric), at the first failing step (unless `continue_after_failure`; the replay
/// row always goes on, so that its whole run can be compared), or at the end.
fn run_one(
    client: &Client,
    live: &Liveliness,
    sim: &mut SimClient,
    t: &TrackSpec,
    refs: &ReferenceSet,
    i: usize,
    how: How<'_>,
) -> Result<Scored> {
    let x = &refs.x[i];
    let reference = match how.row {
        Row::ErrorState => Reference::Plan {
            states: x.clone(),
            inputs: refs.u.as_ref().expect("checked by the caller")[i].clone(),
        },
        _ => Reference::Trajectory(x.clone()),
    };
    let task = ControlTask {
        mpc_id: SERVICES_ID,
        model: how.model,
        x0: &x[0],
        reference: &reference,
        horizon: how.horizon,
        position_loop: None,
        steps: how.steps,
        publish: false,
        replay: match how.row {
            Row::Replay(u) => Some(u),
            _ => None,
        },
        controller: crate::scenario::Controller::Mpc,
        label: None,
        clip: None,
        perturbation: how.perturbation,
        observation_noise: None,
        view: Some(StepView {
            view: how.view,
            row: how.shown_as,
            episode: Some(i),
        }),
    };
    run_task(client, live, sim, task, t, x)
}

/// Runs `task` under the stop rules of tracking task `t` against reference states `x`.
fn run_task(
    client: &Client,
    live: &Liveliness,
    sim: &mut SimClient,
    task: ControlTask<'_>,
    t: &TrackSpec,
    x: &[Vec<f64>],
) -> Result<Scored> {
    let (steps, replay) = (task.steps, task.replay.is_some());
    let mut run = ControlRun::start(client, live, sim, task)?;
    for k in 0..steps {
        let u = run.decide(client, live)?;
        match run.apply(u.clone(), live) {
            Ok(()) => {}
            Err(Error::Remote { reply, .. }) if reply.code == ErrorCode::SimFailure => {
                run.fail_step(u, format!("step {}: {}", k + 1, reply.message));
                break;
            }
            Err(e) => return Err(e),
        }
        let Some(spec) = &t.survival else { continue };
        let state = &run.states()[k + 1];
        let fell = run.terminated()[k + 1];
        if fell || (!replay && !t.continue_after_failure && fails(state, &x[k + 1], fell, spec)) {
            break;
        }
    }
    let terminated = run.terminated().to_vec();
    let failure = run.sim_failure().map(str::to_string);
    let solve_us = run.solve_times_us().to_vec();
    let report = run.finish();
    // The error the metric scores, at every step run (the error norm without a metric).
    let errors: Vec<f64> = match &t.survival {
        Some(spec) => report
            .x
            .iter()
            .enumerate()
            .map(|(k, s)| mean_abs_error(s, &x[k.min(x.len() - 1)], &spec.states))
            .collect(),
        None => report.error.clone(),
    };
    let survival = match &t.survival {
        Some(spec) => {
            Some(survival_of_run(&report.x, &terminated, x, steps, spec).map_err(Error::Config)?)
        }
        None => None,
    };
    Ok(Scored {
        report,
        solve_us,
        terminated,
        failure,
        survival,
        errors,
    })
}

/// A row's figures from its scored runs.
fn row_of(
    name: &str,
    model: Option<&str>,
    kind: Option<&str>,
    mpc: Option<&MpcConfig>,
    scored: &[Scored],
    cap: usize,
    wall_s: f64,
) -> TrackRow {
    let survivals: Vec<usize> = scored.iter().filter_map(|s| s.survival).collect();
    let solve_us: Vec<f64> = scored
        .iter()
        .flat_map(|s| s.solve_us.iter().copied())
        .collect();
    let mut not_solved = BTreeMap::new();
    for s in scored {
        for (k, v) in &s.report.not_solved_by_status {
            *not_solved.entry(k.clone()).or_default() += v;
        }
    }
    TrackRow {
        row: name.to_string(),
        model: model.map(str::to_string),
        kind: kind.map(str::to_string),
        mpc: mpc.cloned(),
        survival: (!survivals.is_empty()).then(|| {
            let v: Vec<f64> = survivals.iter().map(|&s| s as f64).collect();
            Summary::of(&v, Some(cap as f64))
        }),
        survivals,
        above_replay: None,
        below_replay: None,
        steps_run: scored.iter().map(|s| s.report.u.len()).collect(),
        tracking_rms: scored.iter().map(|s| s.report.tracking_rms_total).collect(),
        first_errors: scored.first().map(|s| s.errors.clone()).unwrap_or_default(),
        falls: scored
            .iter()
            .filter(|s| s.terminated.iter().skip(1).any(|&f| f))
            .count(),
        solve_median_us: quantile(&solve_us, 0.5),
        solve_p99_us: quantile(&solve_us, 0.99),
        not_solved_by_status: not_solved,
        sim_errors: scored
            .iter()
            .enumerate()
            .filter_map(|(i, s)| s.failure.as_ref().map(|f| format!("reference {i}: {f}")))
            .take(10)
            .collect(),
        onpolicy: None,
        wall_s,
    }
}

/// The spread of simulator `sim`'s training split (`{out}/data/{sim}/train.npz`), as a
/// normalised model is fitted to it.
pub fn training_spread(out_dir: &Path, sim: &str) -> Result<Normalisation> {
    let path = out_dir.join("data").join(sim).join("train.npz");
    Ok(Normalisation::fit(&Dataset::load_npz(&path)?)?)
}

/// Writes row `name`'s closed loops as windows of `steps` transitions to
/// `{out}/tracking/onpolicy/{name}.npz` (each run up to its first fallen or non-finite state).
fn write_onpolicy(
    out_dir: &Path,
    name: &str,
    scored: &[Scored],
    steps: usize,
    info: &crate::messages::SimInfo,
    t: &TrackSpec,
) -> Result<OnPolicy> {
    let good: Vec<Vec<bool>> = scored
        .iter()
        .map(|s| {
            s.report
                .x
                .iter()
                .zip(&s.terminated)
                .map(|(x, &fell)| !fell && x.iter().all(|v| v.is_finite()))
                .collect()
        })
        .collect();
    let runs: Vec<RunForWindows<'_>> = scored
        .iter()
        .zip(&good)
        .map(|(s, g)| RunForWindows {
            x: &s.report.x,
            u: &s.report.u,
            good: g,
        })
        .collect();
    let w = windows(&runs, steps);
    let mut rec = OnPolicy {
        path: None,
        windows: w.len(),
        steps,
    };
    if w.is_empty() {
        return Ok(rec);
    }
    let mut data = crate::collect::empty_dataset(
        info,
        w.len(),
        steps,
        0,
        format!("koopbridge tracking task ({})", t.references),
        &format!(
            "MPC ({name}) tracking the references; windows of {steps} cut back to back from \
             each run up to its end, failure or fall"
        ),
    );
    for (x, u) in &w {
        data.x.extend(x.iter().flatten());
        data.u.extend(u.iter().flatten());
    }
    let path = out_dir
        .join("tracking")
        .join("onpolicy")
        .join(format!("{name}.npz"));
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| Error::Io {
            path: dir.to_path_buf(),
            source: e,
        })?;
    }
    data.save_npz(&path)?;
    rec.path = Some(path);
    Ok(rec)
}
