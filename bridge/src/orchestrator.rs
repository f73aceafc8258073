//! `koopbridge run`: starts the scenario's simulators and services as child processes, passes
//! the readiness barrier, collects data in lockstep, trains through the trainer service and
//! closes the loop through the MPC service; returns a report.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use koopman::data::Dataset;
use serde::{Deserialize, Serialize};

use crate::client::{Client, Liveliness, SimClient};
use crate::codec::{SolveReply, SolveRequest};
use crate::collect::{collect, CollectJob, Split};
use crate::error::{Error, ErrorCode, Result};
use crate::keyexpr::{fresh_session_id, Keys, Role};
use crate::messages::ResetRequest;
use crate::procs::ChildProc;
use crate::scenario::{Scenario, SimSpec};
use crate::services::trainer::{submit_and_wait_watching, DatasetRef, JobSpec};
use crate::session::{free_loopback_endpoint, open_session, ZenohOptions};

/// Id of the services process started by the orchestrator.
pub const SERVICES_ID: &str = "main";

/// How to run a scenario.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// The `koopbridge` executable to start children with.
    pub exe: PathBuf,
    /// Output folder (`results/{scenario}`).
    pub out_dir: PathBuf,
    /// Zenoh options of the orchestrator (its children connect to it, and to `connect`).
    pub zenoh: ZenohOptions,
    /// Session id (fresh when `None`).
    pub session: Option<String>,
    /// Readiness timeout.
    pub ready_timeout: Duration,
}

/// What the progress callback is told.
pub enum Event<'a> {
    /// A phase starts.
    Phase(&'a str),
    /// Collection progress: (split, done, total).
    Collect(&'static str, usize, usize),
    /// A training progress message from the trainer.
    Train(&'a serde_json::Value),
    /// A control step: (k, total).
    Control(usize, usize),
}

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
    /// First step from which the state stays within 0.05 (angles) / 0.1 (others) of the
    /// reference for 50 steps; `None` if never.
    pub time_to_goal_steps: Option<usize>,
    /// Median solve time inside the service in µs.
    pub solve_median_us: f64,
    /// Median solve round trip (query to reply) in µs.
    pub solve_round_trip_median_us: f64,
    /// Solves whose status was not `solved`.
    pub not_solved: usize,
}

fn wrap(a: f64) -> f64 {
    let tau = std::f64::consts::TAU;
    let r = (a + std::f64::consts::PI).rem_euclid(tau) - std::f64::consts::PI;
    if r <= -std::f64::consts::PI {
        r + tau
    } else {
        r
    }
}

/// State error with angle components wrapped to (−π, π].
pub fn state_error(x: &[f64], r: &[f64], angles: &[usize]) -> Vec<f64> {
    x.iter()
        .zip(r)
        .enumerate()
        .map(|(i, (a, b))| {
            if angles.contains(&i) {
                wrap(a - b)
            } else {
                a - b
            }
        })
        .collect()
}

/// The program of an external adapter command: `{python}` is the project's venv Python if it
/// exists (`.venv/bin/python`), else `python3` from `PATH`.
fn external_program(first: &str) -> PathBuf {
    if first == "{python}" {
        let venv = Path::new(".venv/bin/python");
        if venv.exists() {
            return venv.to_path_buf();
        }
        return PathBuf::from("python3");
    }
    PathBuf::from(first)
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// Everything the orchestrator started, killed on drop.
pub struct Cluster {
    /// Child processes.
    pub children: Vec<ChildProc>,
    /// The orchestrator's client.
    pub client: Client,
    /// Liveliness of the session.
    pub live: Liveliness,
    /// The endpoint children connect to.
    pub endpoint: String,
}

impl Cluster {
    /// Opens the orchestrator's session on a free loopback port and starts `sims` (id, env) and,
    /// if `services` is non-empty, one `koopbridge serve` process with them.
    pub fn start(
        opts: &RunOptions,
        session_id: &str,
        sims: &[(String, String)],
        services: &[&str],
    ) -> Result<Self> {
        let specs: Vec<SimSpec> = sims
            .iter()
            .map(|(id, env)| SimSpec::builtin(id, env))
            .collect();
        Self::start_sims(opts, session_id, &specs, services)
    }

    /// Like [`Cluster::start`], with simulators that may be external adapter commands.
    pub fn start_sims(
        opts: &RunOptions,
        session_id: &str,
        sims: &[SimSpec],
        services: &[&str],
    ) -> Result<Self> {
        let keys = Keys::new(session_id)?;
        let mut z = opts.zenoh.clone();
        let endpoint = match z.listen.first() {
            Some(l) => l.clone(),
            None => {
                let ep = free_loopback_endpoint()?;
                z.listen = vec![ep.clone()];
                ep
            }
        };
        let session = open_session(&z)?;
        let client = Client::new(session, keys);
        let live = Liveliness::new(&client)?;
        let mut child_connect: Vec<String> = vec![endpoint.clone()];
        child_connect.extend(opts.zenoh.connect.iter().cloned());
        let zargs = |extra: &mut Vec<String>| {
            for c in &child_connect {
                extra.push("--connect".into());
                extra.push(c.clone());
            }
            if let Some(p) = &opts.zenoh.zenoh_config {
                extra.push("--zenoh-config".into());
                extra.push(p.display().to_string());
            }
        };
        let mut children = Vec::new();
        let logs = opts.out_dir.join("logs");
        for spec in sims {
            let id = &spec.id;
            let (program, mut a) = match &spec.command {
                Some(cmd) => match cmd.split_first() {
                    Some((first, rest)) => (external_program(first), rest.to_vec()),
                    None => return Err(Error::Config(format!("simulator '{id}': empty command"))),
                },
                None => (
                    opts.exe.clone(),
                    vec!["sim".into(), "--env".into(), spec.env.clone()],
                ),
            };
            a.extend(["--id", id, "--session", session_id, "--stdin-lifeline"].map(String::from));
            zargs(&mut a);
            children.push(ChildProc::spawn(
                &format!("simulator '{id}'"),
                &program,
                &a,
                &logs.join(format!("sim-{id}.log")),
            )?);
        }
        if !services.is_empty() {
            let mut a: Vec<String> = vec!["serve".into()];
            a.extend(services.iter().map(|s| s.to_string()));
            for (k, v) in [
                ("--session", session_id.to_string()),
                ("--id", SERVICES_ID.to_string()),
                ("--store", opts.out_dir.join("models").display().to_string()),
                (
                    "--state-dir",
                    opts.out_dir.join("state").display().to_string(),
                ),
                (
                    "--data-root",
                    opts.out_dir.join("data").display().to_string(),
                ),
            ] {
                a.push(k.into());
                a.push(v);
            }
            a.push("--stdin-lifeline".into());
            zargs(&mut a);
            children.push(ChildProc::spawn(
                "services",
                &opts.exe,
                &a,
                &logs.join("services.log"),
            )?);
        }
        let mut c = Cluster {
            children,
            client,
            live,
            endpoint,
        };
        let mut who: Vec<(Role, String)> = sims.iter().map(|s| (Role::Sim, s.id.clone())).collect();
        for s in services {
            let role = match *s {
                "trainer" => Role::Trainer,
                "mpc" => Role::Mpc,
                "recorder" => Role::Recorder,
                _ => Role::Models,
            };
            who.push((role, SERVICES_ID.to_string()));
        }
        c.wait_ready(&who, opts.ready_timeout)?;
        Ok(c)
    }

    /// Waits for the liveliness tokens of `who`, failing early if a child exits.
    pub fn wait_ready(&mut self, who: &[(Role, String)], timeout: Duration) -> Result<()> {
        let deadline = Instant::now() + timeout;
        loop {
            match self.live.wait_for(who, Duration::from_millis(200)) {
                Ok(()) => return Ok(()),
                Err(e) if Instant::now() > deadline => return Err(e),
                Err(_) => {}
            }
            for ch in &mut self.children {
                if let Some(msg) = ch.exited() {
                    return Err(Error::Config(msg));
                }
            }
        }
    }
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
        if r.status != crate::codec::SolveStatus::Solved {
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
        .map(|x| state_error(x, reference, &info.angle_indices))
        .collect();
    let final_error = errs
        .last()
        .map(|e| e.iter().map(|v| v * v).sum::<f64>().sqrt())
        .unwrap_or(f64::NAN);
    let ok: Vec<bool> = errs
        .iter()
        .map(|e| {
            e.iter().enumerate().all(|(i, v)| {
                v.abs()
                    <= if info.angle_indices.contains(&i) {
                        0.05
                    } else {
                        0.1
                    }
            })
        })
        .collect();
    let hold = 50;
    let time_to_goal_steps =
        (0..ok.len().saturating_sub(hold - 1)).find(|&s| ok[s..s + hold].iter().all(|&b| b));
    Ok(ControlReport {
        sim: sim.id.clone(),
        model: model.to_string(),
        state_names: info.state_names.clone(),
        input_names: info.input_names.clone(),
        dt: info.dt,
        reference: reference.to_vec(),
        x: xs,
        u: us,
        final_error,
        time_to_goal_steps,
        solve_median_us: median(&mut solve_us),
        solve_round_trip_median_us: median(&mut rt_us),
        not_solved,
    })
}

fn save(d: &Dataset, p: &Path) -> Result<PathBuf> {
    d.save_npz(p)?;
    Ok(p.to_path_buf())
}

/// Runs a whole scenario. `on` receives progress events.
pub fn run_scenario(
    sc: &Scenario,
    opts: &RunOptions,
    on: &mut dyn FnMut(Event<'_>),
) -> Result<Report> {
    let t0 = Instant::now();
    let session_id = opts.session.clone().unwrap_or_else(fresh_session_id);
    let mut services = Vec::new();
    if sc.train.is_some() {
        services.extend(["trainer", "models"]);
    }
    if sc.control.is_some() {
        services.push("mpc");
    }
    on(Event::Phase("starting simulators and services"));
    let cluster = Cluster::start_sims(opts, &session_id, &sc.sims, &services)?;
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
        let info = clients[j].info.sim.clone();
        let mut mpc_cfg = serde_json::to_value(koopman::mpc::MpcConfig::with_bounds(
            info.u_min.clone(),
            info.u_max.clone(),
        ))
        .map_err(|e| Error::Config(e.to_string()))?;
        if let Some(o) = mpc_cfg.as_object_mut() {
            for (k, v) in &ctrl.mpc {
                o.insert(k.clone(), v.clone());
            }
        }
        let body = serde_json::to_vec(&serde_json::json!({"model": model, "mpc": mpc_cfg}))
            .map_err(|e| Error::Config(e.to_string()))?;
        client.query(
            &client.keys.under(&["mpc", SERVICES_ID, "configure"]),
            body,
            Duration::from_secs(60),
            "MPC service",
        )?;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angle_errors_are_wrapped() {
        let e = state_error(&[std::f64::consts::TAU + 0.1, 3.0], &[0.0, 1.0], &[0]);
        assert!((e[0] - 0.1).abs() < 1e-12 && (e[1] - 2.0).abs() < 1e-12);
        let e = state_error(&[3.0], &[-3.0], &[0]);
        assert!((e[0] - (6.0 - std::f64::consts::TAU)).abs() < 1e-12);
    }
}
