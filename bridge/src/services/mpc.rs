//! The MPC service: `configure` (model + MPC settings → controller built once), `solve`
//! (state + reference → input plan) and `attach` (free-run control of a simulator's stream).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use koopman::mpc::{MpcConfig, MpcController, SolveStatus as KStatus};
use serde::{Deserialize, Serialize};
use zenoh::{Session, Wait};

use super::{parse_json, serve_queries, to_json, Inbox};
use crate::client::Client;
use crate::codec::{CommandMsg, SolveReply, SolveRequest, SolveStatus, StateMsg};
use crate::error::{Error, ErrorCode, ErrorReply, Result};
use crate::keyexpr::{validate_chunk, Keys, Role, SimLeaf};

/// `…/mpc/{id}/configure` request: build (or rebuild) the controller of a model.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConfigureRequest {
    /// Model name (in the service's store, or fetched from the session's model store).
    pub model: String,
    /// MPC settings (SPEC defaults for absent fields).
    #[serde(default)]
    pub mpc: Option<MpcConfig>,
}

/// `…/mpc/{id}/configure` reply.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ConfigureReply {
    /// Model name.
    pub model: String,
    /// State dimension.
    pub nx: usize,
    /// Input dimension.
    pub nu: usize,
    /// Horizon H.
    pub horizon: usize,
    /// Time spent loading the model and building the controller, in milliseconds.
    pub build_ms: f64,
}

/// `…/mpc/{id}/attach` request: control simulator `sim` in free-run mode (or stop doing so).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AttachRequest {
    /// Simulator id.
    pub sim: String,
    /// Model name (must have been configured) — ignored when detaching.
    #[serde(default)]
    pub model: String,
    /// Reference state (`nx`) or stacked horizon.
    #[serde(default)]
    pub reference: Vec<f64>,
    /// `true` to stop controlling `sim` and get the statistics.
    #[serde(default)]
    pub detach: bool,
}

/// Statistics of an attachment (the `attach` reply when detaching).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct AttachStats {
    /// States received.
    pub states: u64,
    /// Commands published.
    pub commands: u64,
    /// Sequence numbers missing in the state stream.
    pub gaps: u64,
    /// State→command latency inside the service: histogram bucket upper bounds in µs.
    pub latency_bounds_us: Vec<u64>,
    /// Counts per bucket (last bucket: everything above the last bound).
    pub latency_counts: Vec<u64>,
    /// Median latency in µs.
    pub latency_median_us: f64,
    /// 99th percentile latency in µs.
    pub latency_p99_us: f64,
}

/// Sends `req` to the `configure` queryable of MPC service `id` and returns its reply.
pub fn configure(
    client: &Client,
    id: &str,
    req: &ConfigureRequest,
    timeout: Duration,
) -> Result<ConfigureReply> {
    let who = format!("MPC service '{id}'");
    let body = serde_json::to_vec(req).map_err(|e| Error::Config(e.to_string()))?;
    let b = client.query(&client.keys.mpc_configure(id)?, body, timeout, &who)?;
    serde_json::from_slice(&b).map_err(|e| {
        Error::protocol(
            ErrorCode::BadRequest,
            format!("{who}: configure reply is not valid: {e}"),
        )
    })
}

/// Maps the controller's status to the wire status.
pub fn wire_status(s: &KStatus) -> SolveStatus {
    match s {
        KStatus::Solved => SolveStatus::Solved,
        KStatus::Inaccurate => SolveStatus::Inaccurate,
        KStatus::Suboptimal => SolveStatus::Suboptimal,
        KStatus::Fallback(_) => SolveStatus::Fallback,
    }
}

#[derive(Clone, Copy)]
enum Op {
    Solve,
    Configure,
    Attach,
}

struct Attached {
    stop: Arc<AtomicBool>,
    thread: std::thread::JoinHandle<AttachStats>,
}

/// Resolves model `name` to a directory: `store/{name}`, else fetched from the model store.
fn model_dir(client: &Client, store: &Path, name: &str) -> Result<PathBuf> {
    validate_chunk("model name", name)?;
    let local = store.join(name);
    if local.join("config.json").is_file() {
        return Ok(local);
    }
    let cache = store.join(".fetched");
    super::models::fetch(client, name, &cache, Duration::from_secs(30))
}

fn build(
    client: &Client,
    store: &Path,
    req: &ConfigureRequest,
) -> Result<(MpcController<'static>, ConfigureReply)> {
    let t = Instant::now();
    let dir = model_dir(client, store, &req.model)?;
    let model: Arc<dyn koopman::model::LiftedModel> = Arc::from(koopman::model::load_lifted(&dir)?);
    let cfg = req.mpc.clone().unwrap_or_default();
    let c = MpcController::from_shared(model, &cfg)?;
    let reply = ConfigureReply {
        model: req.model.clone(),
        nx: c.nx(),
        nu: c.nu(),
        horizon: c.horizon(),
        build_ms: t.elapsed().as_secs_f64() * 1e3,
    };
    Ok((c, reply))
}

/// Serves the MPC service `id` until `stop` is set. Controllers are built and used on this
/// thread only; attachments run on their own threads with their own controller.
pub fn serve(
    session: &Session,
    keys: &Keys,
    id: &str,
    store: &Path,
    stop: &AtomicBool,
) -> Result<()> {
    let client = Client::new(session.clone(), keys.clone());
    let mut inbox = Inbox::new();
    inbox.declare(session, &keys.mpc_solve(id)?, Op::Solve)?;
    inbox.declare(session, &keys.mpc_configure(id)?, Op::Configure)?;
    inbox.declare(session, &keys.mpc_attach(id)?, Op::Attach)?;
    let mut controllers: HashMap<String, MpcController<'static>> = HashMap::new();
    let mut configs: HashMap<String, ConfigureRequest> = HashMap::new();
    let mut default_model: Option<String> = None;
    let mut attached: HashMap<String, Attached> = HashMap::new();
    serve_queries(
        session,
        keys,
        Role::Mpc,
        id,
        &inbox,
        stop,
        |op, _q, body| match op {
            Op::Solve => {
                let req = SolveRequest::decode(&body).map_err(|e| e.to_reply())?;
                let name = if req.model.is_empty() {
                    default_model.clone().ok_or_else(|| {
                        ErrorReply::new(
                            ErrorCode::NotFound,
                            "no model configured; send `configure` first",
                        )
                    })?
                } else {
                    req.model.clone()
                };
                if !controllers.contains_key(&name) {
                    let creq = ConfigureRequest {
                        model: name.clone(),
                        mpc: None,
                    };
                    let (c, _) = build(&client, store, &creq).map_err(|e| e.to_reply())?;
                    controllers.insert(name.clone(), c);
                    configs.insert(name.clone(), creq);
                }
                let c = controllers
                    .get_mut(&name)
                    .ok_or_else(|| ErrorReply::new(ErrorCode::Internal, "controller vanished"))?;
                let sol = c
                    .solve(&req.x, &req.reference)
                    .map_err(|e| Error::from(e).to_reply())?;
                Ok(SolveReply {
                    status: wire_status(&sol.status),
                    iterations: sol.iterations as u32,
                    solve_time_ns: sol.solve_time.as_nanos() as u64,
                    u: sol.u,
                }
                .encode())
            }
            Op::Configure => {
                let req: ConfigureRequest = parse_json("configure", &body)?;
                let (c, reply) = build(&client, store, &req).map_err(|e| e.to_reply())?;
                controllers.insert(req.model.clone(), c);
                configs.insert(req.model.clone(), req.clone());
                default_model = Some(req.model.clone());
                to_json(&reply)
            }
            Op::Attach => {
                let req: AttachRequest = parse_json("attach", &body)?;
                validate_chunk("sim id", &req.sim).map_err(|e| e.to_reply())?;
                if req.detach {
                    let a = attached.remove(&req.sim).ok_or_else(|| {
                        ErrorReply::new(
                            ErrorCode::NotFound,
                            format!("not attached to '{}'", req.sim),
                        )
                    })?;
                    a.stop.store(true, Ordering::Relaxed);
                    let stats = a.thread.join().map_err(|_| {
                        ErrorReply::new(ErrorCode::Internal, "attachment thread panicked")
                    })?;
                    return to_json(&stats);
                }
                if attached.contains_key(&req.sim) {
                    return Err(ErrorReply::new(
                        ErrorCode::Busy,
                        format!("already attached to '{}'", req.sim),
                    ));
                }
                let creq = configs
                    .get(&req.model)
                    .cloned()
                    .unwrap_or(ConfigureRequest {
                        model: req.model.clone(),
                        mpc: None,
                    });
                let (c, _) = build(&client, store, &creq).map_err(|e| e.to_reply())?;
                let flag = Arc::new(AtomicBool::new(false));
                let thread = attach(
                    session.clone(),
                    keys.clone(),
                    req.sim.clone(),
                    c,
                    req.reference.clone(),
                    flag.clone(),
                )
                .map_err(|e| e.to_reply())?;
                attached.insert(req.sim.clone(), Attached { stop: flag, thread });
                to_json(&serde_json::json!({"attached": req.sim}))
            }
        },
    )?;
    for (_, a) in attached {
        a.stop.store(true, Ordering::Relaxed);
        let _ = a.thread.join();
    }
    Ok(())
}

const LATENCY_BOUNDS_US: [u64; 12] = [
    50, 100, 200, 500, 1000, 2000, 5000, 10_000, 20_000, 50_000, 100_000, 1_000_000,
];

fn attach(
    session: Session,
    keys: Keys,
    sim: String,
    controller: MpcController<'static>,
    reference: Vec<f64>,
    stop: Arc<AtomicBool>,
) -> Result<std::thread::JoinHandle<AttachStats>> {
    let (tx, rx) = std::sync::mpsc::channel::<(Instant, Vec<u8>)>();
    let sub = session
        .declare_subscriber(keys.sim(&sim, SimLeaf::State)?)
        .callback(move |s| {
            let _ = tx.send((Instant::now(), s.payload().to_bytes().into_owned()));
        })
        .wait()
        .map_err(Error::zenoh)?;
    let publisher = session
        .declare_publisher(keys.sim(&sim, SimLeaf::Command)?)
        .wait()
        .map_err(Error::zenoh)?;
    Ok(std::thread::spawn(move || {
        let _sub = sub;
        let mut c = controller;
        let nu = c.nu();
        let mut stats = AttachStats {
            latency_bounds_us: LATENCY_BOUNDS_US.to_vec(),
            latency_counts: vec![0; LATENCY_BOUNDS_US.len() + 1],
            ..Default::default()
        };
        let mut lat = Vec::new();
        let mut last_seq: Option<u64> = None;
        let mut seq = 0u64;
        while !stop.load(Ordering::Relaxed) {
            let Ok((arrived, bytes)) = rx.recv_timeout(Duration::from_millis(100)) else {
                continue;
            };
            // Skip to the newest state if several are queued.
            let (arrived, bytes) = rx.try_iter().last().unwrap_or((arrived, bytes));
            let Ok(s) = StateMsg::decode(&bytes) else {
                continue;
            };
            stats.states += 1;
            if let Some(l) = last_seq {
                if s.seq > l + 1 {
                    stats.gaps += s.seq - l - 1;
                }
            }
            last_seq = Some(s.seq);
            let Ok(sol) = c.solve(&s.x, &reference) else {
                continue;
            };
            let cmd = CommandMsg {
                seq,
                k: s.k,
                u: sol.u[..nu].to_vec(),
            };
            seq += 1;
            if publisher.put(cmd.encode()).wait().is_ok() {
                stats.commands += 1;
            }
            let us = arrived.elapsed().as_micros() as u64;
            lat.push(us as f64);
            let b = LATENCY_BOUNDS_US
                .iter()
                .position(|&x| us <= x)
                .unwrap_or(LATENCY_BOUNDS_US.len());
            stats.latency_counts[b] += 1;
        }
        lat.sort_by(|a, b| a.total_cmp(b));
        if !lat.is_empty() {
            stats.latency_median_us = lat[lat.len() / 2];
            stats.latency_p99_us = lat[((lat.len() as f64 * 0.99) as usize).min(lat.len() - 1)];
        }
        stats
    }))
}
