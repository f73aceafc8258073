//! `koopbridge.PlannerService`: a trajectory planner written in Python (a callable), served at
//! `…/planner/{id}/plan` by Rust with `bridge`'s payload limit, error replies and liveliness.
//!
//! One plan at a time: a request that arrives while another is being planned is answered at
//! once with `busy` from Zenoh's callback; the planning itself runs on the worker thread with the
//! GIL held only inside the callable. A Python exception becomes a typed error reply and serving
//! goes on.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc};
use std::time::Duration;

use bridge::keyexpr::{Keys, Role};
use bridge::services::{payload, respond, DEFAULT_MAX_PAYLOAD};
use bridge::session::{open_session, ZenohOptions};
use bridge::zenoh::query::Query;
use bridge::zenoh::Wait;
use bridge::{Error, ErrorCode, ErrorReply};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use serde_json::Value;

use crate::errors::{bridge_err, InvalidInput, Unsupported};
use crate::zenoh_args::zenoh_options;

/// A failed plan request: the reply's code (an `ErrorCode` or a planner code such as
/// `infeasible`) and message.
struct Failure {
    code: String,
    message: String,
}

impl Failure {
    fn new(code: ErrorCode, message: impl Into<String>) -> Self {
        Failure {
            code: code.to_string(),
            message: message.into(),
        }
    }

    /// The error reply body `{"code", "message"}`, through `ErrorReply` for the protocol's codes.
    fn to_json(&self) -> Vec<u8> {
        match serde_json::from_value::<ErrorCode>(Value::String(self.code.clone())) {
            Ok(code) => ErrorReply::new(code, self.message.clone()).to_json(),
            Err(_) => {
                serde_json::to_vec(&serde_json::json!({"code": self.code, "message": self.message}))
                    .unwrap_or_else(|_| b"{\"code\":\"internal\"}".to_vec())
            }
        }
    }
}

/// Counters of a serving planner.
#[derive(Default)]
struct Counters {
    plans: AtomicU64,
    errors: AtomicU64,
    busy: AtomicU64,
}

/// Serves a planner written in Python at ``koopbridge/{session}/planner/{id}/plan``.
///
/// ``PlannerService(plan, nq)``: ``plan(start, goal, dt) -> dict`` is called with two lists of
/// ``nq`` floats and a positive ``dt``; its dict (JSON-serialisable: the sampled trajectory) is
/// the reply. Requests are JSON ``{"start": [nq], "goal": [nq], "dt": s}``; malformed JSON,
/// unknown fields, non-numbers, a non-positive ``dt`` → ``bad_request``; wrong lengths →
/// ``dimension``; a request while a plan runs → ``busy``. Exceptions from ``plan``: one with a
/// string attribute ``code`` (e.g. ``"infeasible"``) is answered with that code,
/// ``koopbridge.InvalidInput`` with ``bad_request``, ``koopbridge.Unsupported`` with
/// ``unsupported``, anything else with ``internal``; serving goes on.
#[pyclass(module = "koopbridge._native")]
pub struct PlannerService {
    plan: Py<PyAny>,
    nq: usize,
    stop: Arc<AtomicBool>,
    serving: Arc<AtomicBool>,
}

#[pymethods]
impl PlannerService {
    #[new]
    fn new(plan: Py<PyAny>, nq: usize) -> PyResult<Self> {
        if nq == 0 {
            return Err(PyValueError::new_err("nq must be at least 1"));
        }
        Ok(PlannerService {
            plan,
            nq,
            stop: Arc::new(AtomicBool::new(false)),
            serving: Arc::new(AtomicBool::new(false)),
        })
    }

    /// Serves until ``stop()`` (from another thread) or Ctrl-C; returns the counters
    /// (``plans``, ``errors``, ``busy``). Arguments as ``Adapter.serve``: ``session``, ``id``,
    /// Zenoh ``connect``/``listen`` lists, ``mode``, ``zenoh_config``.
    #[pyo3(signature = (*, session="default", id="planner0", connect=None, listen=None, mode="peer", zenoh_config=None))]
    #[allow(clippy::too_many_arguments)]
    fn serve(
        &self,
        py: Python<'_>,
        session: &str,
        id: &str,
        connect: Option<Vec<String>>,
        listen: Option<Vec<String>>,
        mode: &str,
        zenoh_config: Option<std::path::PathBuf>,
    ) -> PyResult<Py<PyAny>> {
        let zopts = zenoh_options(connect, listen, mode, zenoh_config)?;
        let keys = Keys::new(session).map_err(bridge_err)?;
        let key = keys.planner_plan(id).map_err(bridge_err)?;
        let alive = keys.alive(Role::Planner, id).map_err(bridge_err)?;
        if self.serving.swap(true, Ordering::SeqCst) {
            return Err(PyRuntimeError::new_err("this planner is already serving"));
        }
        self.stop.store(false, Ordering::SeqCst);
        let counters = Arc::new(Counters::default());
        let interrupted: std::sync::Mutex<Option<PyErr>> = std::sync::Mutex::new(None);
        let idle = || {
            Python::attach(|py| match py.check_signals() {
                Ok(()) => false,
                Err(e) => {
                    if let Ok(mut slot) = interrupted.lock() {
                        *slot = Some(e);
                    }
                    true
                }
            })
        };
        let result = py.detach(|| {
            serve_loop(
                &zopts,
                &key,
                &alive,
                &self.stop,
                &counters,
                &idle,
                &|q: &Query| Python::attach(|py| self.answer(py, q)),
            )
        });
        self.serving.store(false, Ordering::SeqCst);
        if let Some(e) = interrupted.lock().ok().and_then(|mut s| s.take()) {
            return Err(e);
        }
        result.map_err(bridge_err)?;
        let d = PyDict::new(py);
        d.set_item("plans", counters.plans.load(Ordering::SeqCst))?;
        d.set_item("errors", counters.errors.load(Ordering::SeqCst))?;
        d.set_item("busy", counters.busy.load(Ordering::SeqCst))?;
        Ok(d.into_any().unbind())
    }

    /// Asks a running ``serve()`` to return (within about 0.1 s). Safe from any thread.
    fn stop(&self) {
        self.stop.store(true, Ordering::SeqCst);
    }

    /// True while ``serve()`` runs.
    #[getter]
    fn serving(&self) -> bool {
        self.serving.load(Ordering::SeqCst)
    }
}

/// The queryable, the liveliness token and the loop: queries are answered one at a time by
/// `answer`; one that arrives while another is answered gets `busy` from the callback. `idle`
/// runs every 100 ms without a query and stops the loop by returning true.
fn serve_loop(
    zopts: &ZenohOptions,
    key: &str,
    alive: &str,
    stop: &AtomicBool,
    counters: &Arc<Counters>,
    idle: &(dyn Fn() -> bool + Sync),
    answer: &(dyn Fn(&Query) -> Result<Vec<u8>, Failure> + Sync),
) -> bridge::Result<()> {
    let session = open_session(zopts)?;
    let busy = Arc::new(AtomicBool::new(false));
    let (tx, rx) = mpsc::channel::<Query>();
    let busy_cb = busy.clone();
    let counters_cb = counters.clone();
    let queryable = session
        .declare_queryable(key)
        .callback(move |q| {
            if busy_cb.swap(true, Ordering::SeqCst) {
                counters_cb.busy.fetch_add(1, Ordering::SeqCst);
                respond(
                    &q,
                    Err(ErrorReply::new(
                        ErrorCode::Busy,
                        "another plan is being computed; this planner plans one at a time",
                    )),
                );
            } else if let Err(mpsc::SendError(q)) = tx.send(q) {
                respond(
                    &q,
                    Err(ErrorReply::new(
                        ErrorCode::Internal,
                        "the planner is stopping",
                    )),
                );
            }
        })
        .wait()
        .map_err(Error::zenoh)?;
    let token = session
        .liveliness()
        .declare_token(alive)
        .wait()
        .map_err(Error::zenoh)?;
    while !stop.load(Ordering::SeqCst) {
        let Ok(q) = rx.recv_timeout(Duration::from_millis(100)) else {
            if idle() {
                break;
            }
            continue;
        };
        let outcome = payload(&q, DEFAULT_MAX_PAYLOAD)
            .map_err(|e| Failure {
                code: e.code.to_string(),
                message: e.message,
            })
            .and_then(|_| answer(&q));
        // Free before replying: a client that sends its next request as soon as it has the
        // reply must not find the planner still busy.
        busy.store(false, Ordering::SeqCst);
        match outcome {
            Ok(bytes) => {
                counters.plans.fetch_add(1, Ordering::SeqCst);
                respond(&q, Ok(bytes));
            }
            Err(f) => {
                counters.errors.fetch_add(1, Ordering::SeqCst);
                if let Err(e) = q.reply_err(f.to_json()).wait() {
                    eprintln!("koopbridge planner: could not send a reply: {e}");
                }
            }
        }
    }
    drop(queryable);
    drop(token);
    let _ = session.close().wait();
    Ok(())
}

impl PlannerService {
    /// Parses and checks one request, calls the Python planner and encodes its reply.
    fn answer(&self, py: Python<'_>, q: &Query) -> Result<Vec<u8>, Failure> {
        let body = q
            .payload()
            .map(|p| p.to_bytes().into_owned())
            .unwrap_or_default();
        let (start, goal, dt) = parse_request(&body, self.nq)?;
        let reply = self
            .plan
            .bind(py)
            .call1((start, goal, dt))
            .map_err(|e| failure_of(py, e))?;
        let json = py.import("json").map_err(|e| failure_of(py, e))?;
        let kwargs = PyDict::new(py);
        let text = kwargs
            .set_item("allow_nan", false)
            .and_then(|_| json.getattr("dumps")?.call((reply,), Some(&kwargs)))
            .and_then(|t| t.extract::<String>())
            .map_err(|e| {
                Failure::new(
                    ErrorCode::Internal,
                    format!("the planner's reply is not JSON-serialisable: {e}"),
                )
            })?;
        Ok(text.into_bytes())
    }
}

/// `{"start": [nq], "goal": [nq], "dt": s}` checked: numbers, lengths, a positive finite `dt`.
fn parse_request(body: &[u8], nq: usize) -> Result<(Vec<f64>, Vec<f64>, f64), Failure> {
    let bad = |m: String| Failure::new(ErrorCode::BadRequest, m);
    let v: Value = serde_json::from_slice(body)
        .map_err(|e| bad(format!("plan request: invalid JSON: {e}")))?;
    let obj = v
        .as_object()
        .ok_or_else(|| bad("plan request: expected a JSON object {start, goal, dt}".into()))?;
    if let Some(k) = obj
        .keys()
        .find(|k| !["start", "goal", "dt"].contains(&k.as_str()))
    {
        return Err(bad(format!(
            "plan request: unknown field '{k}' (expected start, goal, dt)"
        )));
    }
    let vector = |name: &str| -> Result<Vec<f64>, Failure> {
        let a = obj.get(name).and_then(Value::as_array).ok_or_else(|| {
            bad(format!(
                "plan request: '{name}' must be an array of numbers"
            ))
        })?;
        let out: Option<Vec<f64>> = a.iter().map(Value::as_f64).collect();
        let out =
            out.ok_or_else(|| bad(format!("plan request: '{name}' must hold numbers only")))?;
        if out.len() != nq {
            return Err(Failure::new(
                ErrorCode::Dimension,
                format!(
                    "plan request: '{name}' has {} values, the planner's robot has {nq}",
                    out.len()
                ),
            ));
        }
        Ok(out)
    };
    let start = vector("start")?;
    let goal = vector("goal")?;
    let dt = obj
        .get("dt")
        .and_then(Value::as_f64)
        .ok_or_else(|| bad("plan request: 'dt' must be a number of seconds".into()))?;
    if !(dt > 0.0 && dt.is_finite()) {
        return Err(bad(format!("plan request: dt must be positive, got {dt}")));
    }
    Ok((start, goal, dt))
}

/// A Python exception from the planner as the reply it gets.
fn failure_of(py: Python<'_>, e: PyErr) -> Failure {
    let msg = e.value(py).to_string();
    let code: Option<String> = e
        .value(py)
        .getattr("code")
        .ok()
        .and_then(|c| c.extract::<String>().ok())
        .filter(|c| {
            !c.is_empty()
                && c.len() <= 32
                && c.chars().all(|ch| ch.is_ascii_lowercase() || ch == '_')
        });
    if let Some(code) = code {
        return Failure { code, message: msg };
    }
    if e.is_instance_of::<InvalidInput>(py) {
        return Failure::new(ErrorCode::BadRequest, msg);
    }
    if e.is_instance_of::<Unsupported>(py) {
        return Failure::new(ErrorCode::Unsupported, msg);
    }
    let ty = e
        .get_type(py)
        .name()
        .map(|n| n.to_string())
        .unwrap_or_else(|_| "Exception".into());
    e.display(py);
    Failure::new(ErrorCode::Internal, format!("plan() raised {ty}: {msg}"))
}
