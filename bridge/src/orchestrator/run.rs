//! A whole scenario: start the cluster, collect in lockstep, train through the trainer service
//! (one model per simulator and `[train].model` kind), regulate through the MPC service with
//! each kind's models, and the report of it all.

use std::path::{Path, PathBuf};
use std::time::Instant;

use koopman::data::Dataset;

use super::aggregate;
use super::commands::{run_hooks, Placeholders};
use super::compare;
use super::control::{control_phase, ControlPhase};
use super::diagnose::{self, ControlDiagnosis};
use super::pretrained;
pub use super::report::{CollectReport, Report};
use super::reuse;
use super::track_aggregate::aggregate_tracking;
use super::tracking::{tracking_phase, ReplayCache, TrackingPhase};
use super::train::{job_config, train_model_as, TrainReport};
use super::validate::validate_scenario;
use super::viewer::ViewerProc;
use super::{Cluster, ControlReport, Event, RunOptions};
use crate::client::SimClient;
use crate::collect::{collect_regions, CollectJob, Split};
use crate::error::{Error, Result};
use crate::keyexpr::fresh_session_id;
use crate::messages::SimInfo;
use crate::scenario::{HookPhase, Scenario};
use crate::services::model_kind::ModelKind;
use crate::services::Service;

fn save(d: &Dataset, p: &Path) -> Result<PathBuf> {
    d.save_npz(p)?;
    Ok(p.to_path_buf())
}

/// The services a scenario needs.
fn services_of(sc: &Scenario, extras: &RunExtras) -> Vec<Service> {
    let mut services = Vec::new();
    if sc.train.is_some() {
        services.extend([Service::Trainer, Service::Models]);
    }
    if !(sc.control.is_empty() && sc.tracks.is_empty()) {
        services.push(Service::Mpc);
    }
    if extras.aggregate > 0 {
        services.push(Service::Recorder);
    }
    services
}

/// Options of a run beyond [`RunOptions`] (`koopbridge run` flags).
#[derive(Clone, Debug, Default)]
pub struct RunExtras {
    /// Also run each controlled simulator alone in the control loop, for the loop's slowdown
    /// figure ([`LoopReport::slowdown_vs_slowest_alone`]).
    pub loop_baseline: bool,
    /// On-policy aggregation rounds after the first control run ([`super::aggregate`]); 0 =
    /// none.
    pub aggregate: usize,
    /// Show the run live and record it (`view.rrd`, [`super::viewer`]); `None`: no viewer.
    pub view: Option<super::viewer::ViewOptions>,
}

/// The placeholders of a run's commands.
fn placeholders(
    sc: &Scenario,
    opts: &RunOptions,
    session: &str,
    endpoint: &str,
) -> Result<Placeholders> {
    let abs = |p: &Path| {
        std::path::absolute(p).map_err(|e| Error::Io {
            path: p.to_path_buf(),
            source: e,
        })
    };
    let base = abs(sc.base_dir.as_deref().unwrap_or(Path::new(".")))?;
    Ok(Placeholders::new(
        &base,
        &abs(&opts.out_dir)?,
        session,
        endpoint,
    ))
}

/// Runs a whole scenario. `on` receives progress events. Right after the readiness barrier the
/// whole scenario is checked against the simulators' `info` ([`validate_scenario`]); data and
/// models a previous run left in the output folder are reused when their sections are
/// unchanged ([`super::reuse`]). Writes `report.json` into the output folder (before the
/// `after-control` hooks run).
pub fn run_scenario(
    sc: &Scenario,
    opts: &RunOptions,
    on: &mut dyn FnMut(Event<'_>),
) -> Result<Report> {
    run_scenario_with(sc, opts, &RunExtras::default(), on)
}

/// [`run_scenario`] with the extra options.
pub fn run_scenario_with(
    sc: &Scenario,
    opts: &RunOptions,
    extras: &RunExtras,
    on: &mut dyn FnMut(Event<'_>),
) -> Result<Report> {
    let t0 = Instant::now();
    let aggregate_tracks = sc.tracks.iter().any(|t| t.aggregate);
    if extras.aggregate > 0 && sc.control.is_empty() && !aggregate_tracks {
        return Err(Error::Config(
            "--aggregate needs [train] and [control] (it retrains on closed-loop rollouts): a \
             `[control]` loop, or a tracking task marked `aggregate = true`"
                .into(),
        ));
    }
    if extras.aggregate > 0 && sc.control.iter().any(|c| c.label.is_some()) {
        return Err(Error::Config(
            "--aggregate retrains each simulator's model on its one [control] loop; labelled \
             [control] entries (several rows per simulator) are for comparing controllers: run \
             them without --aggregate"
                .into(),
        ));
    }
    let kinds = sc.trained_kinds();
    if extras.aggregate > 0 && !sc.control.is_empty() && kinds.len() > 1 {
        return Err(Error::Config(format!(
            "--aggregate retrains one model per simulator from its [control] loop; \
             [train].model lists {} kinds ({}): list one (tracking tasks marked `aggregate` \
             retrain every kind)",
            kinds.len(),
            kinds
                .iter()
                .map(|k| k.name())
                .collect::<Vec<_>>()
                .join(", ")
        )));
    }
    let session_id = opts.session.clone().unwrap_or_else(fresh_session_id);
    on(Event::Phase("starting simulators and services"));
    let cluster = Cluster::launch_with(
        opts,
        &session_id,
        &sc.sims,
        &sc.participants,
        &services_of(sc, extras),
        sc.base_dir.as_deref(),
    )?;
    if !cluster.existing.is_empty() {
        on(Event::Phase(&format!(
            "using the participants already in session '{session_id}': {}",
            super::cluster::names(&cluster.existing)
        )));
    }
    let mut warnings = Vec::new();
    let viewer = extras.view.as_ref().and_then(|v| {
        let (endpoint, live) = (&cluster.endpoint, &cluster.live);
        let base = sc.base_dir.as_deref().unwrap_or(Path::new("."));
        ViewerProc::start(
            v,
            &session_id,
            endpoint,
            &opts.out_dir,
            base,
            live,
            &mut |w| warnings.push(w.to_string()),
        )
    });
    warnings.iter().for_each(|w| on(Event::Warning(w)));
    if let Some(url) = viewer.as_ref().and_then(ViewerProc::web_url) {
        on(Event::Phase(&format!(
            "live view (Rerun's web viewer): {url}"
        )));
    }
    // Every event is also published for a viewer (while one subscribes).
    let view = &cluster.view;
    let outer = on;
    let on: &mut dyn FnMut(Event<'_>) = &mut |e| {
        view.event(&e);
        outer(e)
    };
    let mut clients: Vec<SimClient> = sc
        .sims
        .iter()
        .map(|s| SimClient::connect(&cluster.client, &s.id, opts.ready_timeout))
        .collect::<Result<_>>()?;
    let infos: Vec<&SimInfo> = clients.iter().map(|c| &c.info.sim).collect();
    validate_scenario(sc, &infos)?;
    let collect_key = reuse::collect_key(sc, &infos);
    let ph = placeholders(sc, opts, &session_id, &cluster.endpoint)?;
    // The models trained elsewhere that exist already are checked before anything is collected.
    pretrained::install(sc, &ph, &infos, true, None)?;
    let hooks = |phase: HookPhase, on: &mut dyn FnMut(Event<'_>)| {
        run_hooks(&sc.hooks, phase, &ph, &mut |m| on(Event::Phase(m)))
    };
    hooks(HookPhase::BeforeCollect, on)?;

    let collect_report = if sc.collect.collects() {
        Some(collect_phase(
            sc,
            opts,
            &cluster,
            &mut clients,
            &collect_key,
            on,
        )?)
    } else {
        None
    };
    let mut trained: Vec<(ModelKind, TrainReport)> = Vec::new();
    for &kind in &kinds {
        on(Event::Phase(&if kinds.len() > 1 {
            format!("training the {kind} models (trainer service)")
        } else {
            "training (trainer service)".to_string()
        }));
        for s in &sc.sims {
            let key = reuse::train_key(&collect_key, &job_config(sc, &s.id, kind)?);
            trained.push((kind, train_one(sc, opts, &cluster, &s.id, kind, &key, on)?));
        }
    }

    hooks(HookPhase::BeforeControl, on)?;
    let infos: Vec<&SimInfo> = clients.iter().map(|c| &c.info.sim).collect();
    let pretrained = pretrained::install(sc, &ph, &infos, false, Some(&opts.out_dir))?;
    let (mut controls, mut control_loop, mut aggregation) = (Vec::new(), None, Vec::new());
    // One pass per trained kind (its models' rows); the rows that need no trained model (a
    // baseline, a named model) run in the first pass only. No trained kind: one pass.
    let passes: Vec<Option<ModelKind>> = if kinds.is_empty() {
        vec![None]
    } else {
        kinds.iter().copied().map(Some).collect()
    };
    for (i, &kind) in passes.iter().enumerate().filter(|_| !sc.control.is_empty()) {
        on(Event::Phase(&match kind {
            Some(kind) if kinds.len() > 1 => format!(
                "closed-loop control with the {kind} models (MPC service: {})",
                kind.controller()
            ),
            _ => "closed-loop control (MPC service)".to_string(),
        }));
        // Aggregation (one kind only) records and retrains the first run.
        let record = extras.aggregate > 0 && i == 0;
        if record {
            aggregate::start_recording(sc, &cluster)?;
        }
        let model_of = |id: &str| kind.map(|k| sc.model_name(id, k));
        let (c, l) = control_phase(
            sc,
            &cluster.client,
            &cluster.live,
            &mut clients,
            &ph,
            &ControlPhase {
                model_of: &model_of,
                first_pass: i == 0,
                publish: record,
                baseline: extras.loop_baseline && i == 0,
                deprioritise: &|id| cluster.deprioritise_sim(id),
                view: &cluster.view,
            },
            on,
        )?;
        for w in c.iter().flat_map(ControlReport::warnings) {
            on(Event::Warning(&w));
            warnings.push(w);
        }
        if record {
            aggregation = aggregate::aggregate(
                sc,
                opts,
                &cluster,
                &mut clients,
                &ph,
                &c,
                extras.aggregate,
                on,
            )?;
        }
        if i == 0 {
            control_loop = Some(l);
        }
        controls.extend(c);
    }
    let replays = std::cell::RefCell::new(ReplayCache::default());
    let tracking = if sc.tracks.is_empty() {
        Vec::new()
    } else {
        tracking_phase(
            sc,
            &cluster.client,
            &cluster.live,
            &mut clients,
            &ph,
            &TrackingPhase {
                out_dir: &opts.out_dir,
                kinds: &kinds,
                model_of: &|id, kind| sc.model_name(id, kind),
                pretrained: &pretrained,
                aggregating: extras.aggregate > 0,
                replays: &replays,
                view: &cluster.view,
            },
            on,
        )?
    };
    let tracking_aggregation = if extras.aggregate > 0 && aggregate_tracks {
        aggregate_tracking(
            sc,
            opts,
            &cluster,
            &mut clients,
            &ph,
            (&tracking, &replays),
            &kinds,
            extras.aggregate,
            on,
        )?
    } else {
        Vec::new()
    };
    warnings.extend(aggregation.iter().flat_map(aggregate::round_warnings));
    let diagnoses = diagnose_controls(sc, &opts.out_dir, &controls, &mut clients, on);
    for d in &diagnoses {
        let c = controls
            .iter()
            .find(|c| c.sim == d.sim && c.model == d.model);
        if let Some(w) = c.and_then(|c| diagnose::missed_goal_warning(c, d)) {
            on(Event::Warning(&w));
            warnings.push(w);
        }
    }
    let view_file = match viewer.map(ViewerProc::finish) {
        Some(Err(w)) => {
            on(Event::Warning(&w));
            warnings.push(w);
            None
        }
        Some(Ok(path)) => Some(path),
        None => None,
    };
    let models = compare::side_by_side(&trained, &controls);
    let report = Report {
        scenario: sc.name.clone(),
        session: session_id,
        collect: collect_report,
        train: trained.into_iter().map(|(_, t)| t).collect(),
        control: controls.first().cloned(),
        controls,
        models,
        control_loop,
        aggregation,
        tracking,
        pretrained,
        tracking_aggregation,
        diagnoses,
        videos: match extras.view.as_ref().and_then(|v| v.video.as_ref()) {
            Some(_) => ViewerProc::videos(&opts.out_dir),
            None => Vec::new(),
        },
        view: view_file,
        warnings,
        wall_seconds: t0.elapsed().as_secs_f64(),
    };
    if !report.tracking.is_empty() {
        let dir = opts.out_dir.join("tracking");
        std::fs::create_dir_all(&dir).map_err(|e| Error::Io {
            path: dir.clone(),
            source: e,
        })?;
        let table = super::tracking::table(&report.tracking);
        crate::fsutil::write_atomic(&dir.join("table.md"), table.as_bytes())?;
    }
    let path = opts.out_dir.join("report.json");
    let bytes = serde_json::to_vec_pretty(&report).map_err(|e| Error::Config(e.to_string()))?;
    crate::fsutil::write_atomic(&path, &bytes)?;
    hooks(HookPhase::AfterControl, on)?;
    drop(cluster);
    Ok(report)
}

/// Collects the three splits from every simulator and saves them under `out_dir/data/{sim}/`,
/// or reuses what a previous run with the same `key` saved there.
fn collect_phase(
    sc: &Scenario,
    opts: &RunOptions,
    cluster: &Cluster,
    clients: &mut [SimClient],
    key: &serde_json::Value,
    on: &mut dyn FnMut(Event<'_>),
) -> Result<CollectReport> {
    let record = reuse::collect_record(&opts.out_dir);
    if let Some(mut r) = reuse::load::<CollectReport>(&record, key) {
        if r.files.iter().all(|f| f.is_file()) {
            on(Event::Phase(&format!(
                "reusing the data collected before in {} ([[sims]], [collect] and the simulators' info are unchanged)",
                opts.out_dir.join("data").display()
            )));
            r.reused = true;
            return Ok(r);
        }
    }
    reuse::forget(&record)?;
    let c = &sc.collect;
    on(Event::Phase(match c.policy {
        crate::scenario::Policy::Adapter { .. } => {
            "collecting data (collect requests: each simulator runs its windows in-process)"
        }
        _ => "collecting data (lockstep)",
    }));
    let x0_box = c.x0_box()?;
    let regions = (0..sc.sims.len())
        .map(|j| sc.sim_region(j))
        .collect::<Result<Vec<_>>>()?;
    let tc = Instant::now();
    let mut per_split: Vec<Vec<Dataset>> = Vec::new();
    for (split, name, n) in [
        (Split::Train, "train", c.train_windows),
        (Split::Val, "val", c.val_windows),
        (Split::Test, "test", c.test_windows),
    ] {
        let job = CollectJob {
            policy: &c.policy,
            windows: n,
            steps: c.steps,
            seed: c.seed,
            split,
            x0_box: x0_box.as_ref(),
        };
        let ds = collect_regions(clients, &job, &regions, Some(&cluster.live), &mut |d, t| {
            on(Event::Collect(name, d, t))
        })?;
        per_split.push(ds);
    }
    let seconds = tc.elapsed().as_secs_f64();
    let macro_steps = (c.train_windows + c.val_windows + c.test_windows) * c.steps;
    let mut files = Vec::new();
    for (j, s) in sc.sims.iter().enumerate() {
        for (i, name) in ["train", "val", "test"].iter().enumerate() {
            if per_split[i][j].n > 0 {
                files.push(save(
                    &per_split[i][j],
                    &opts
                        .out_dir
                        .join("data")
                        .join(&s.id)
                        .join(format!("{name}.npz")),
                )?);
            }
        }
    }
    let report = CollectReport {
        sims: sc.sims.iter().map(|s| s.id.clone()).collect(),
        windows: [c.train_windows, c.val_windows, c.test_windows],
        steps: c.steps,
        seconds,
        macro_steps_per_second: macro_steps as f64 / seconds.max(1e-9),
        files,
        reused: false,
    };
    reuse::store(&record, key, &report)?;
    Ok(report)
}

/// Trains simulator `sim`'s model of kind `kind` through the trainer service, or reuses the
/// model a previous run with the same `key` trained into the store.
fn train_one(
    sc: &Scenario,
    opts: &RunOptions,
    cluster: &Cluster,
    sim: &str,
    kind: ModelKind,
    key: &serde_json::Value,
    on: &mut dyn FnMut(Event<'_>),
) -> Result<TrainReport> {
    let model = sc.model_name(sim, kind);
    let record = reuse::train_record(&opts.out_dir, sim, kind);
    let stored = opts.out_dir.join("models").join(&model);
    if let Some(mut r) = reuse::load::<TrainReport>(&record, key) {
        if stored.join("config.json").is_file() {
            on(Event::Phase(&format!(
                "reusing model '{model}' trained before in {} (same data and [train])",
                stored.display()
            )));
            r.reused = true;
            return Ok(r);
        }
    }
    reuse::forget(&record)?;
    let dir = opts.out_dir.join("data").join(sim);
    let report = train_model_as(
        sc,
        opts,
        cluster,
        sim,
        kind,
        &model,
        &dir.join("train.npz"),
        on,
    )?;
    reuse::store(&record, key, &report)?;
    Ok(report)
}

/// The diagnosis of every control run with its model and its simulator's test windows (the
/// validation windows when the scenario keeps no test split); a run that cannot be diagnosed
/// (a missing file) is reported as a phase note and skipped.
fn diagnose_controls(
    sc: &Scenario,
    out: &std::path::Path,
    controls: &[ControlReport],
    clients: &mut [SimClient],
    on: &mut dyn FnMut(Event<'_>),
) -> Vec<ControlDiagnosis> {
    // Each simulator's windows are read once, however many model kinds controlled it.
    let mut windows: std::collections::HashMap<&str, Result<Dataset>> = Default::default();
    let mut all = Vec::new();
    for c in controls {
        let test = windows.entry(c.sim.as_str()).or_insert_with(|| {
            let data = out.join("data").join(&c.sim);
            ["test.npz", "val.npz"]
                .iter()
                .map(|f| data.join(f))
                .find(|p| p.is_file())
                .ok_or_else(|| {
                    Error::Config(format!(
                        "no test or validation windows in {}",
                        data.display()
                    ))
                })
                .and_then(|p| Dataset::load_npz(&p).map_err(|e| Error::Config(e.to_string())))
        });
        // The lifted model, read once (`None`: a kind without one, whose gain depends on the
        // state). The input authority and growth rates at the goal are measured on the
        // simulator; one that cannot be measured does not stop the rest of the diagnosis.
        let model = koopman::model::load_lifted(&out.join("models").join(&c.model)).ok();
        let mut noted = |what: &str, e: Error| {
            on(Event::Phase(&format!(
                "no {what} of '{}' with '{}': {e}",
                c.sim, c.model
            )))
        };
        let (authority, growth) = match (&model, sc.sims.iter().position(|s| s.id == c.sim)) {
            (Some(m), Some(j)) => (
                super::authority::input_authority(c, m.as_ref(), &mut clients[j]).unwrap_or_else(
                    |e| {
                        noted("input authority", e);
                        None
                    },
                ),
                super::growth::growth(c, m.as_ref(), &mut clients[j]).unwrap_or_else(|e| {
                    noted("growth rates", e);
                    None
                }),
            ),
            _ => (None, None),
        };
        let diagnosis = match test {
            Ok(test) => diagnose::diagnose(c, model.as_deref(), test, authority, growth),
            Err(e) => Err(Error::Config(e.to_string())),
        };
        match diagnosis {
            Ok(d) => all.push(d),
            Err(e) => on(Event::Phase(&format!(
                "no diagnosis of '{}' with '{}': {e}",
                c.sim, c.model
            ))),
        }
    }
    all
}
