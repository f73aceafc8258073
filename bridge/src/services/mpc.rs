//! The MPC service: `configure` (model + MPC settings → controller built once), `solve`
//! (state + reference → input plan) and `attach` (free-run control of a simulator's stream).

mod attach;
mod controller;
mod workers;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use koopman::mpc::{MpcConfig, MpcController, OffsetFreeConfig, SolveStatus as KStatus};
use serde::{Deserialize, Serialize};
use zenoh::Session;

use super::{parse_json, query_json, serve_queries_handing_on, to_json, Inbox};
use crate::client::Client;
use crate::codec::{SolveRequest, SolveStatus};
use crate::error::{ErrorCode, ErrorReply, Result};
use crate::keyexpr::{validate_chunk, Keys, Role};

use attach::Attached;
pub use attach::{clamp_bounds_to_sim, AttachStats};
pub use controller::{LoadedModel, ServiceController, ServicePlan};
use workers::SolveWorkers;

/// `…/mpc/{id}/configure` request: build (or rebuild) the controller of a model.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConfigureRequest {
    /// Model name (in the service's store, or fetched from the session's model store).
    pub model: String,
    /// MPC settings (SPEC defaults for absent fields).
    #[serde(default)]
    pub mpc: Option<MpcConfig>,
    /// Offset-free correction of a bilinear or lifted-linear model's MPC (refused for a
    /// one-step NNDM and, for a lifted model, by a solve with a feed-forward). With it,
    /// consecutive solves for this model are one closed loop (configure again to start anew).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub offset_free: Option<OffsetFreeConfig>,
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

/// Sends `req` to the `configure` queryable of MPC service `id` and returns its reply.
pub fn configure(
    client: &Client,
    id: &str,
    req: &ConfigureRequest,
    timeout: Duration,
) -> Result<ConfigureReply> {
    let key = client.keys.mpc_configure(id)?;
    query_json(client, &key, req, timeout, &format!("MPC service '{id}'"))
}

/// Sends `req` (attach: `sim`, `model`, `reference`) to the `attach` queryable of MPC service
/// `id`; returns the simulator id it attached to.
pub fn attach(client: &Client, id: &str, req: &AttachRequest, timeout: Duration) -> Result<String> {
    #[derive(Deserialize)]
    struct AttachReply {
        attached: String,
    }
    let key = client.keys.mpc_attach(id)?;
    let r: AttachReply = query_json(client, &key, req, timeout, &format!("MPC service '{id}'"))?;
    Ok(r.attached)
}

/// Stops MPC service `id` controlling simulator `sim`; returns the attachment's statistics.
pub fn detach(client: &Client, id: &str, sim: &str, timeout: Duration) -> Result<AttachStats> {
    let req = AttachRequest {
        sim: sim.to_string(),
        model: String::new(),
        reference: Vec::new(),
        detach: true,
    };
    let key = client.keys.mpc_attach(id)?;
    query_json(client, &key, &req, timeout, &format!("MPC service '{id}'"))
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

/// Loads model `name` (local store, else fetched from the model store).
fn load_model(client: &Client, store: &Path, name: &str) -> Result<LoadedModel> {
    let dir = model_dir(client, store, name)?;
    Ok(LoadedModel::load(&dir)?)
}

fn build(
    client: &Client,
    store: &Path,
    req: &ConfigureRequest,
) -> Result<(ServiceController, ConfigureReply)> {
    let t = Instant::now();
    let model = load_model(client, store, &req.model)?;
    let cfg = req.mpc.clone().unwrap_or_default();
    let c = ServiceController::build(&model, &cfg, req.offset_free.as_ref())?;
    let reply = ConfigureReply {
        model: req.model.clone(),
        nx: c.nx(),
        nu: c.nu(),
        horizon: c.horizon(),
        build_ms: t.elapsed().as_secs_f64() * 1e3,
    };
    Ok((c, reply))
}

/// Serves the MPC service `id` until `stop` is set. Queries arrive on this thread, which loads
/// models and builds controllers; each model's solves run on that model's own thread
/// ([`workers`]), so the closed loops of several simulators are solved side by side;
/// attachments run on their own threads with their own controller.
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
    let mut solvers = SolveWorkers::default();
    let mut configs: HashMap<String, ConfigureRequest> = HashMap::new();
    let mut default_model: Option<String> = None;
    let mut attached: HashMap<String, Attached> = HashMap::new();
    serve_queries_handing_on(
        session,
        keys,
        Role::Mpc,
        id,
        &inbox,
        stop,
        |op, q, body| match op {
            Op::Solve => {
                let handed_on = (|| {
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
                    if !solvers.has(&name) {
                        solvers.admit(&name)?;
                        let creq = ConfigureRequest {
                            model: name.clone(),
                            mpc: None,
                            offset_free: None,
                        };
                        let (c, _) = build(&client, store, &creq).map_err(|e| e.to_reply())?;
                        solvers.install(&name, c)?;
                        configs.insert(name.clone(), creq);
                    }
                    solvers.solve(&name, q.clone(), req)
                })();
                handed_on.err().map(Err)
            }
            Op::Configure => Some((|| {
                let req: ConfigureRequest = parse_json("configure", &body)?;
                solvers.admit(&req.model)?;
                let (c, reply) = build(&client, store, &req).map_err(|e| e.to_reply())?;
                solvers.install(&req.model, c)?;
                configs.insert(req.model.clone(), req.clone());
                default_model = Some(req.model.clone());
                to_json(&reply)
            })()),
            Op::Attach => Some((|| {
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
                if attached.len() >= attach::MAX_ATTACHED {
                    return Err(ErrorReply::new(
                        ErrorCode::Busy,
                        format!("attached to {} simulators (the most)", attached.len()),
                    ));
                }
                // The configured settings of the model (SPEC defaults if none), with the
                // simulator's input bounds intersected in, always.
                let cfg = configs
                    .get(&req.model)
                    .and_then(|c| c.mpc.clone())
                    .unwrap_or_default();
                // Loaded before attaching: the controller is then built in microseconds once
                // the simulator's bounds are known, while its states already arrive.
                let model = match load_model(&client, store, &req.model) {
                    Ok(LoadedModel::Lifted(m)) => m,
                    Ok(other) => {
                        let kind = match other {
                            LoadedModel::Bilinear(_) => "bilinear",
                            _ => "a one-step NNDM",
                        };
                        return Err(ErrorReply::new(
                            ErrorCode::Unsupported,
                            format!(
                                "model '{}' is {kind}: free-run attach controls lifted-linear \
                                 models only (use lockstep solves)",
                                req.model
                            ),
                        ));
                    }
                    Err(e) => return Err(e.to_reply()),
                };
                let a = attach::start(&client, &req.sim, &req.reference, cfg, |cfg| {
                    Ok(MpcController::from_shared(model, cfg)?)
                })?;
                attached.insert(req.sim.clone(), a);
                to_json(&serde_json::json!({"attached": req.sim}))
            })()),
        },
    )?;
    solvers.shut_down();
    for (_, a) in attached {
        a.stop.store(true, Ordering::Relaxed);
        let _ = a.thread.join();
    }
    Ok(())
}
