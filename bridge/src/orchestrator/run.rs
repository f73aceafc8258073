//! A whole scenario: start the cluster, collect in lockstep, train through the trainer service,
//! regulate through the MPC service, and the report of it all.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use koopman::data::Dataset;
use koopman::mpc::MpcConfig;
use serde::{Deserialize, Serialize};

use super::{closed_loop, Cluster, ControlReport, ControlTask, Event, RunOptions, SERVICES_ID};
use crate::client::SimClient;
use crate::collect::{collect, CollectJob, Split};
use crate::error::{Error, Result};
use crate::keyexpr::{fresh_session_id, Role};
use crate::messages::SimInfo;
use crate::scenario::Scenario;
use crate::services::mpc::{configure, ConfigureRequest};
use crate::services::trainer::{submit_and_wait_watching, DatasetRef, JobSpec};
use crate::services::Service;

/// The outcome of one scenario run (written as `report.json`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Report {
    /// Scenario name.
    pub scenario: String,
    /// Session id used.
    pub session: String,
    /// Collection summary.
    pub collect: CollectReport,
    /// Training results, one per simulator.
    pub train: Vec<TrainReport>,
    /// Closed-loop control result.
    pub control: Option<ControlReport>,
    /// Total wall time in seconds.
    pub wall_seconds: f64,
}

/// Collection summary.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct CollectReport {
    /// Simulators stepped.
    pub sims: Vec<String>,
    /// Windows per split (train, val, test) and simulator.
    pub windows: [usize; 3],
    /// Transitions per window.
    pub steps: usize,
    /// Seconds spent collecting.
    pub seconds: f64,
    /// Lockstep macro steps per second (all simulators stepped once = one macro step).
    pub macro_steps_per_second: f64,
    /// Dataset files written.
    pub files: Vec<PathBuf>,
}

/// Training result of one simulator's model.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TrainReport {
    /// Simulator id.
    pub sim: String,
    /// Model name in the store.
    pub model: String,
    /// Trainer job id.
    pub job: String,
    /// Metrics reported by the trainer.
    pub metrics: serde_json::Value,
}

fn save(d: &Dataset, p: &Path) -> Result<PathBuf> {
    d.save_npz(p)?;
    Ok(p.to_path_buf())
}

/// The MPC settings of a scenario's `[control].mpc` for a simulator: SPEC defaults with the
/// simulator's input bounds, overlaid with the scenario's fields (unknown fields are an error).
pub fn mpc_config(
    info: &SimInfo,
    overrides: &serde_json::Map<String, serde_json::Value>,
) -> Result<MpcConfig> {
    let mut v = serde_json::to_value(MpcConfig::with_bounds(
        info.u_min.clone(),
        info.u_max.clone(),
    ))
    .map_err(|e| Error::Config(e.to_string()))?;
    if let Some(o) = v.as_object_mut() {
        for (k, val) in overrides {
            o.insert(k.clone(), val.clone());
        }
    }
    serde_json::from_value(v).map_err(|e| Error::Config(format!("[control].mpc: {e}")))
}

/// The services a scenario needs.
fn services_of(sc: &Scenario) -> Vec<Service> {
    let mut services = Vec::new();
    if sc.train.is_some() {
        services.extend([Service::Trainer, Service::Models]);
    }
    if sc.control.is_some() {
        services.push(Service::Mpc);
    }
    services
}

/// Runs a whole scenario. `on` receives progress events.
pub fn run_scenario(
    sc: &Scenario,
    opts: &RunOptions,
    on: &mut dyn FnMut(Event<'_>),
) -> Result<Report> {
    let t0 = Instant::now();
    let session_id = opts.session.clone().unwrap_or_else(fresh_session_id);
    on(Event::Phase("starting simulators and services"));
    let cluster = Cluster::launch(opts, &session_id, &sc.sims, &services_of(sc))?;
    let (client, live) = (&cluster.client, &cluster.live);
    let mut clients: Vec<SimClient> = sc
        .sims
        .iter()
        .map(|s| SimClient::connect(client, &s.id, opts.ready_timeout))
        .collect::<Result<_>>()?;

    on(Event::Phase("collecting data (lockstep)"));
    let c = &sc.collect;
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
        };
        let ds = collect(&mut clients, &job, Some(live), &mut |d, t| {
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
    let collect_report = CollectReport {
        sims: sc.sims.iter().map(|s| s.id.clone()).collect(),
        windows: [c.train_windows, c.val_windows, c.test_windows],
        steps: c.steps,
        seconds,
        macro_steps_per_second: macro_steps as f64 / seconds.max(1e-9),
        files,
    };

    let mut train_reports = Vec::new();
    if let Some(t) = &sc.train {
        on(Event::Phase("training (trainer service)"));
        for s in &sc.sims {
            let dir = opts.out_dir.join("data").join(&s.id);
            let abs = |n: &str| -> DatasetRef {
                let p = dir.join(format!("{n}.npz"));
                DatasetRef::Path {
                    path: std::fs::canonicalize(&p).unwrap_or(p),
                }
            };
            let model = format!("{}-{}", sc.name, s.id);
            let spec = JobSpec {
                model: model.clone(),
                train: abs("train"),
                val: abs("val"),
                test: (c.test_windows > 0).then(|| abs("test")),
                config: t.config.clone(),
            };
            // The simulators are needed again after training: a lost one ends the run now.
            let sims: Vec<(Role, String)> =
                sc.sims.iter().map(|s| (Role::Sim, s.id.clone())).collect();
            let rec =
                submit_and_wait_watching(client, live, SERVICES_ID, &spec, &sims, &mut |p| {
                    on(Event::Train(p))
                })?;
            train_reports.push(TrainReport {
                sim: s.id.clone(),
                model,
                job: rec.job,
                metrics: rec.metrics.unwrap_or_default(),
            });
        }
    }

    let mut control = None;
    if let Some(ctrl) = &sc.control {
        on(Event::Phase("closed-loop control (MPC service)"));
        let sim_id = ctrl.sim.clone().unwrap_or_else(|| sc.sims[0].id.clone());
        let j = sc.sims.iter().position(|s| s.id == sim_id).unwrap_or(0);
        let model = format!("{}-{}", sc.name, sim_id);
        let req = ConfigureRequest {
            model: model.clone(),
            mpc: Some(mpc_config(&clients[j].info.sim, &ctrl.mpc)?),
        };
        configure(client, SERVICES_ID, &req, Duration::from_secs(60))?;
        control = Some(closed_loop(
            client,
            live,
            &mut clients[j],
            &ControlTask {
                mpc_id: SERVICES_ID,
                model: &model,
                x0: &ctrl.x0,
                reference: &ctrl.reference,
                steps: ctrl.steps,
            },
            &mut |k, n| on(Event::Control(k, n)),
        )?);
    }
    drop(cluster);
    Ok(Report {
        scenario: sc.name.clone(),
        session: session_id,
        collect: collect_report,
        train: train_reports,
        control,
        wall_seconds: t0.elapsed().as_secs_f64(),
    })
}
