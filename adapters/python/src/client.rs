//! `koopbridge.Client`: the querying side from Python, through bridge's Rust client — simulators
//! (info, reset, step with idempotent retries), MPC solves and configuration, training jobs, the
//! model store (`control`), and raw queries.

use std::collections::HashMap;
use std::sync::Mutex;
use std::time::Duration;

use bridge::client::{Client as Inner, Liveliness, SimClient};
use bridge::codec::{SolveReply, SolveRequest, SolveStatus, StepReply, StepRequest, StepStatus};
use bridge::collect::blocks::collect_block;
use bridge::keyexpr::{Keys, SimLeaf};
use bridge::messages::{CollectRequest, ResetRequest};
use bridge::session::open_session;
use bridge::zenoh::Wait;
use numpy::{PyArray1, PyArray3, PyArrayMethods};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyTuple};

use crate::control;
use crate::convert::{array1, array2, check_finite, from_py_json, rows_f64, to_py_json, vec_f64};
use crate::errors::{bridge_err, KoopbridgeError};
use crate::zenoh_args::zenoh_options;

/// A client of one koopbridge session over Zenoh.
///
/// ``Client(session="default", connect=[], listen=[], mode="peer", zenoh_config=None)`` opens
/// a Zenoh session (embedded peer on loopback by default; pass ``connect=["tcp/HOST:PORT"]`` to
/// join a running koopbridge or router). Simulators are addressed by id, services by their id.
#[pyclass(subclass, module = "koopbridge._native")]
pub struct Client {
    inner: Inner,
    live: Liveliness,
    sims: Mutex<HashMap<String, SimClient>>,
}

#[pymethods]
impl Client {
    #[new]
    #[pyo3(signature = (session="default", connect=None, listen=None, mode="peer", zenoh_config=None))]
    fn new(
        py: Python<'_>,
        session: &str,
        connect: Option<Vec<String>>,
        listen: Option<Vec<String>>,
        mode: &str,
        zenoh_config: Option<std::path::PathBuf>,
    ) -> PyResult<Self> {
        let opts = zenoh_options(connect, listen, mode, zenoh_config)?;
        let keys = Keys::new(session).map_err(bridge_err)?;
        let s = py.detach(|| open_session(&opts)).map_err(bridge_err)?;
        let inner = Inner::new(s, keys);
        let live = py.detach(|| Liveliness::new(&inner)).map_err(bridge_err)?;
        Ok(Client {
            inner,
            live,
            sims: Mutex::new(HashMap::new()),
        })
    }

    /// The koopbridge session id.
    #[getter]
    fn session(&self) -> String {
        self.inner.keys.session().to_string()
    }

    /// Waits (readiness barrier) until simulator ``id`` answers ``info``; returns that reply as a
    /// dict (names, dims, dt, bounds, kind, counters).
    #[pyo3(signature = (id, timeout=10.0))]
    fn connect_sim(&self, py: Python<'_>, id: &str, timeout: f64) -> PyResult<Py<PyAny>> {
        let t = secs(timeout)?;
        let sim = py
            .detach(|| SimClient::connect(&self.inner, id, t))
            .map_err(bridge_err)?;
        let info = to_py_json(py, &sim.info)?;
        self.sims
            .lock()
            .map_err(poisoned)?
            .insert(id.to_string(), sim);
        Ok(info)
    }

    /// Resets simulator ``id`` (``seed`` for a random initial state, ``x0`` for a given one;
    /// ``perturbation``: a dict of ``mass_scale``, ``friction_scale``, ``push`` = ``{"step": k,
    /// "velocity": [vx, vy]}`` for the episode, PROTOCOL.md "reset"); returns the first state.
    #[pyo3(signature = (id, seed=None, x0=None, perturbation=None))]
    fn reset<'py>(
        &self,
        py: Python<'py>,
        id: &str,
        seed: Option<u64>,
        x0: Option<&Bound<'py, PyAny>>,
        perturbation: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let x0 = match x0 {
            Some(x) => Some(vec_f64(x, "x0")?),
            None => None,
        };
        let perturbation = perturbation.map(crate::convert::perturbation).transpose()?;
        let req = ResetRequest {
            seed,
            x0,
            perturbation,
        };
        let r = self.with_sim(py, id, |s| s.reset(&req))?;
        Ok(array1(py, &r.x))
    }

    /// One lockstep step of simulator ``id`` with input ``u``: returns ``(k, t, x)``, the new
    /// step index, its time and state; with ``with_status=True``, ``(k, t, x, status)`` where
    /// ``status`` is the dict of the step's flags (``terminated``, ``truncated``, ``clipped``:
    /// booleans, all ``False`` when the simulator reported none; PROTOCOL.md §4). A timed-out
    /// request is re-sent (answered from the adapter's cache, never stepped twice); a simulator
    /// whose liveliness token disappears raises ``GoneError`` naming it.
    #[pyo3(signature = (id, u, *, with_status=false))]
    fn step<'py>(
        &self,
        py: Python<'py>,
        id: &str,
        u: &Bound<'py, PyAny>,
        with_status: bool,
    ) -> PyResult<Bound<'py, PyTuple>> {
        let u = vec_f64(u, "u")?;
        let live = &self.live;
        let r: StepReply = self.with_sim(py, id, |s| s.step(&u, Some(live)))?;
        step_tuple(py, &r, with_status)
    }

    /// Sends one step request for an explicit step index ``k`` of simulator ``id`` (connected
    /// first with ``connect_sim``) and returns the reply's ``(k, t, x)`` (with
    /// ``with_status=True``: ``(k, t, x, status)``, as ``step``) without retries and
    /// without moving this client's own step index. For checking lockstep semantics: a ``k``
    /// already taken with the same ``u`` is answered from the adapter's cache (the simulator is
    /// not stepped again); with another ``u`` it is a ``conflict`` error reply.
    #[pyo3(signature = (id, k, u, timeout=10.0, *, with_status=false))]
    fn step_at<'py>(
        &self,
        py: Python<'py>,
        id: &str,
        k: u64,
        u: &Bound<'py, PyAny>,
        timeout: f64,
        with_status: bool,
    ) -> PyResult<Bound<'py, PyTuple>> {
        let body = StepRequest {
            k,
            u: vec_f64(u, "u")?,
        }
        .encode();
        let key = self.inner.keys.sim(id, SimLeaf::Step).map_err(bridge_err)?;
        let t = secs(timeout)?;
        let who = format!("simulator '{id}'");
        let bytes = py
            .detach(|| self.inner.query(&key, body, t, &who))
            .map_err(bridge_err)?;
        let r = StepReply::decode(&bytes).map_err(bridge_err)?;
        step_tuple(py, &r, with_status)
    }

    /// Asks simulator ``id`` for block ``block`` of a collection of windows it runs in its own
    /// process (the ``collect`` request, PROTOCOL.md): blocks of ``block_windows`` windows of
    /// ``steps`` transitions, the first ``windows`` of them (default all), inputs drawn from
    /// ``policy`` (a dict, default ``{"kind": "uniform"}`` within the simulator's bounds) with
    /// ``seed``. Returns ``(x, u)`` of shapes ``(n, steps + 1, nx)`` and ``(n, steps, nu)``; the
    /// same arguments give the same arrays, bit for bit. A refused request raises
    /// ``RemoteError`` with its code (``bad_request``, ``dimension``, ``too_large``, ...).
    #[pyo3(signature = (id, seed, block, block_windows, steps, windows=None, policy=None, timeout=600.0))]
    #[allow(clippy::too_many_arguments, clippy::type_complexity)]
    fn collect<'py>(
        &self,
        py: Python<'py>,
        id: &str,
        seed: u64,
        block: u64,
        block_windows: u32,
        steps: u32,
        windows: Option<u32>,
        policy: Option<&Bound<'py, PyAny>>,
        timeout: f64,
    ) -> PyResult<(Bound<'py, PyArray3<f64>>, Bound<'py, PyArray3<f64>>)> {
        let policy = match policy {
            Some(p) => serde_json::from_value(from_py_json(p, "policy")?)
                .map_err(|e| PyValueError::new_err(format!("policy: {e}")))?,
            None => Default::default(),
        };
        let req = CollectRequest {
            policy,
            seed,
            block,
            block_windows,
            windows,
            steps,
        };
        let t = secs(timeout)?;
        let live = &self.live;
        let b = py
            .detach(|| collect_block(&self.inner, id, &req, t, Some(live)))
            .map_err(bridge_err)?;
        let x = PyArray1::from_vec(py, b.x).reshape([b.windows, b.steps + 1, b.nx])?;
        let u = PyArray1::from_vec(py, b.u).reshape([b.windows, b.steps, b.nu])?;
        Ok((x, u))
    }

    /// Asks the MPC service ``mpc_id`` for a plan at state ``x`` towards ``reference`` (one
    /// state or H stacked states) with its model ``model`` (empty: the service's default).
    /// With ``feedforward`` (the plan's inputs at this and the next H−1 steps, (H, nu) or
    /// flat), ``reference`` is the planned state at this step and the service plans the
    /// deviation from the plan (error-state MPC). Returns a dict: ``u`` (H, nu) when ``nu`` is
    /// given, else flat; ``status``; ``iterations``; ``solve_time`` (seconds, inside the
    /// service).
    #[pyo3(signature = (mpc_id, x, reference, model="", nu=None, timeout=10.0, feedforward=None))]
    #[allow(clippy::too_many_arguments)]
    fn solve<'py>(
        &self,
        py: Python<'py>,
        mpc_id: &str,
        x: &Bound<'py, PyAny>,
        reference: &Bound<'py, PyAny>,
        model: &str,
        nu: Option<usize>,
        timeout: f64,
        feedforward: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let np = py.import("numpy")?;
        let req = SolveRequest {
            model: model.to_string(),
            x: vec_f64(x, "x")?,
            reference: vec_f64(&np.call_method1("ravel", (reference,))?, "reference")?,
            feedforward: match feedforward {
                Some(f) => vec_f64(&np.call_method1("ravel", (f,))?, "feedforward")?,
                None => Vec::new(),
            },
        };
        let key = self.inner.keys.mpc_solve(mpc_id).map_err(bridge_err)?;
        let t = secs(timeout)?;
        let who = format!("MPC service '{mpc_id}'");
        let bytes = py
            .detach(|| self.inner.query(&key, req.encode(), t, &who))
            .map_err(bridge_err)?;
        let r = SolveReply::decode(&bytes).map_err(bridge_err)?;
        let d = PyDict::new(py);
        match nu {
            Some(n) if n > 0 && r.u.len() % n == 0 => {
                d.set_item("u", array2(py, r.u.len() / n, n, &r.u)?)?
            }
            Some(n) => {
                return Err(KoopbridgeError::new_err(format!(
                    "{who} returned {} input values, not a multiple of nu = {n}",
                    r.u.len()
                )))
            }
            None => d.set_item("u", array1(py, &r.u))?,
        }
        let status = match r.status {
            SolveStatus::Solved => "solved",
            SolveStatus::Suboptimal => "suboptimal",
            SolveStatus::Fallback => "fallback",
            SolveStatus::Inaccurate => "inaccurate",
        };
        d.set_item("status", status)?;
        d.set_item("iterations", r.iterations)?;
        d.set_item("solve_time", r.solve_time_ns as f64 * 1e-9)?;
        Ok(d)
    }

    /// Loads ``model`` into MPC service ``mpc_id`` and builds its controller once; ``mpc``
    /// holds ``MpcConfig`` fields (``horizon``, ``u_min``, ...; an unknown one is refused here),
    /// and for a bilinear model optionally ``offset_free={"mode": "trajectory", "radius": 1.0,
    /// "gain": [...], "angles": [...]}`` (the service then keeps the correction across solves).
    /// Returns the service's reply (``model``, ``nx``, ``nu``, ``horizon``, ``build_ms``).
    #[pyo3(signature = (mpc_id, model, timeout=60.0, **mpc))]
    fn configure_mpc(
        &self,
        py: Python<'_>,
        mpc_id: &str,
        model: &str,
        timeout: f64,
        mpc: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Py<PyAny>> {
        let cfg = match mpc {
            Some(d) => from_py_json(d.as_any(), "the MPC configuration")?,
            None => serde_json::Value::Object(Default::default()),
        };
        let t = secs(timeout)?;
        let r = py
            .detach(|| control::configure_mpc(&self.inner, mpc_id, model, cfg, t))
            .map_err(bridge_err)?;
        to_py_json(py, &r)
    }

    /// Submits a training job to trainer ``trainer_id``: the finished model is stored as
    /// ``model``; datasets are ``.npz`` paths inside the trainer's data root (``koopbridge serve
    /// --data-root``; others are refused with ``forbidden``) or ``recording:NAME`` for a
    /// recorder's dataset; ``config`` holds ``TrainConfig`` fields. Returns the job id.
    #[pyo3(signature = (trainer_id, model, train, val, test=None, config=None, timeout=30.0))]
    #[allow(clippy::too_many_arguments)]
    fn submit_job(
        &self,
        py: Python<'_>,
        trainer_id: &str,
        model: &str,
        train: &str,
        val: &str,
        test: Option<&str>,
        config: Option<&Bound<'_, PyDict>>,
        timeout: f64,
    ) -> PyResult<String> {
        let config = match config {
            Some(d) => match from_py_json(d.as_any(), "the training configuration")? {
                serde_json::Value::Object(m) => m,
                other => {
                    return Err(PyValueError::new_err(format!(
                        "the training configuration must be a JSON object, got {other}"
                    )))
                }
            },
            None => Default::default(),
        };
        let spec = bridge::services::trainer::JobSpec {
            model: model.to_string(),
            train: control::dataset(train).map_err(bridge_err)?,
            val: control::dataset(val).map_err(bridge_err)?,
            test: test.map(control::dataset).transpose().map_err(bridge_err)?,
            config,
        };
        let t = secs(timeout)?;
        py.detach(|| control::submit_job(&self.inner, trainer_id, &spec, t))
            .map_err(bridge_err)
    }

    /// The record of training job ``job`` on trainer ``trainer_id`` (``state``, ``progress``,
    /// ``metrics``, ``error``, ...).
    #[pyo3(signature = (trainer_id, job, timeout=10.0))]
    fn job(
        &self,
        py: Python<'_>,
        trainer_id: &str,
        job: &str,
        timeout: f64,
    ) -> PyResult<Py<PyAny>> {
        let t = secs(timeout)?;
        let r = py
            .detach(|| control::job(&self.inner, trainer_id, job, t))
            .map_err(bridge_err)?;
        to_py_json(py, &r)
    }

    /// Polls a job every ``poll`` seconds until it is done (returns its record); raises
    /// ``KoopbridgeError`` if it failed or was cancelled, ``BridgeTimeout`` after ``timeout``.
    #[pyo3(signature = (trainer_id, job, timeout=3600.0, poll=0.5))]
    fn wait_job(
        &self,
        py: Python<'_>,
        trainer_id: &str,
        job: &str,
        timeout: f64,
        poll: f64,
    ) -> PyResult<Py<PyAny>> {
        let (t, every) = (secs(timeout)?, secs(poll)?);
        let started = std::time::Instant::now();
        loop {
            let waited = started.elapsed();
            let r = py
                .detach(|| control::poll_job(&self.inner, trainer_id, job, started + t, waited))
                .map_err(bridge_err)?;
            if let Some(rec) = r {
                return to_py_json(py, &rec);
            }
            py.detach(|| std::thread::sleep(every));
            py.check_signals()?;
        }
    }

    /// Fetches model ``name`` from the model store into directory ``dest`` (unpacked by the
    /// bridge into a temporary folder beside it, then renamed; an older ``dest`` is replaced);
    /// returns ``dest``. Load it with ``KoopmanModel.load``.
    #[pyo3(signature = (name, dest, timeout=60.0))]
    fn fetch_model(
        &self,
        py: Python<'_>,
        name: &str,
        dest: std::path::PathBuf,
        timeout: f64,
    ) -> PyResult<String> {
        let t = secs(timeout)?;
        let p = py
            .detach(|| control::fetch_model(&self.inner, name, &dest, t))
            .map_err(bridge_err)?;
        Ok(p.to_string_lossy().into_owned())
    }

    /// Binds MPC service ``mpc_id`` (configured with ``model``, see ``configure_mpc``) to the
    /// free-running simulator ``sim``: from now on it answers each published state with a
    /// command towards ``reference`` (``nx`` values, or a stacked horizon), within the
    /// simulator's own input bounds. Typed errors: ``not_found`` (no such simulator),
    /// ``busy`` (a lockstep simulator, or already attached), ``dimension`` (wrong reference).
    #[pyo3(signature = (mpc_id, sim, model, reference, timeout=30.0))]
    fn attach(
        &self,
        py: Python<'_>,
        mpc_id: &str,
        sim: &str,
        model: &str,
        reference: &Bound<'_, PyAny>,
        timeout: f64,
    ) -> PyResult<String> {
        let req = bridge::services::mpc::AttachRequest {
            sim: sim.to_string(),
            model: model.to_string(),
            reference: vec_f64(reference, "reference")?,
            detach: false,
        };
        let t = secs(timeout)?;
        py.detach(|| bridge::services::mpc::attach(&self.inner, mpc_id, &req, t))
            .map_err(bridge_err)
    }

    /// Stops MPC service ``mpc_id`` controlling ``sim``; returns the attachment's statistics
    /// (``AttachStats`` in PROTOCOL.md: ``states``, ``commands``, ``gaps``, ``skipped``,
    /// latencies, ...).
    #[pyo3(signature = (mpc_id, sim, timeout=30.0))]
    fn detach(&self, py: Python<'_>, mpc_id: &str, sim: &str, timeout: f64) -> PyResult<Py<PyAny>> {
        let t = secs(timeout)?;
        let r = py
            .detach(|| bridge::services::mpc::detach(&self.inner, mpc_id, sim, t))
            .map_err(bridge_err)?;
        to_py_json(py, &r)
    }

    /// Asks recorder ``recorder_id`` to record the state stream of free-running simulator
    /// ``sim`` in windows of ``window_steps`` transitions (default 15). ``reference`` (``nx``
    /// values, or an array of rows of ``nx``: row ``k`` at step ``k``) goes to the MCAP file's
    /// ``reference`` channel.
    #[pyo3(signature = (recorder_id, sim, window_steps=None, reference=None, timeout=10.0))]
    fn record_start(
        &self,
        py: Python<'_>,
        recorder_id: &str,
        sim: &str,
        window_steps: Option<usize>,
        reference: Option<&Bound<'_, PyAny>>,
        timeout: f64,
    ) -> PyResult<()> {
        let t = secs(timeout)?;
        let reference = match reference {
            None => None,
            Some(r) => {
                let (_, _, v) = rows_f64(r, "reference")?;
                check_finite(&v, "reference")?;
                Some(v)
            }
        };
        py.detach(|| {
            bridge::services::recorder::record_start(
                &self.inner,
                recorder_id,
                sim,
                window_steps,
                reference,
                t,
            )
        })
        .map_err(bridge_err)
    }

    /// Stops recording ``sim`` and writes the windows as dataset ``name`` (served at
    /// ``…/data/{name}``, usable as ``recording:NAME`` in ``submit_job``); returns the summary
    /// (``name``, ``states``, ``gaps``, ``out_of_order``, ``windows``).
    #[pyo3(signature = (recorder_id, sim, name, timeout=30.0))]
    fn record_stop(
        &self,
        py: Python<'_>,
        recorder_id: &str,
        sim: &str,
        name: &str,
        timeout: f64,
    ) -> PyResult<Py<PyAny>> {
        let t = secs(timeout)?;
        let r = py
            .detach(|| {
                bridge::services::recorder::record_stop(&self.inner, recorder_id, sim, name, t)
            })
            .map_err(bridge_err)?;
        to_py_json(py, &r)
    }

    /// A raw query of ``koopbridge/{session}/{key}`` (e.g. ``"trainer/t0/jobs"`` or
    /// ``"models/NAME"``) with ``payload``; returns the reply's bytes or raises ``RemoteError``
    /// with the service's typed error. For the JSON control plane described in PROTOCOL.md.
    #[pyo3(signature = (key, payload=Vec::new(), timeout=10.0))]
    fn query<'py>(
        &self,
        py: Python<'py>,
        key: &str,
        payload: Vec<u8>,
        timeout: f64,
    ) -> PyResult<Bound<'py, PyBytes>> {
        let parts: Vec<&str> = key.split('/').collect();
        for p in &parts {
            bridge::keyexpr::validate_chunk("key", p).map_err(bridge_err)?;
        }
        let full = self.inner.keys.under(&parts);
        let t = secs(timeout)?;
        let bytes = py
            .detach(|| self.inner.query(&full, payload, t, key))
            .map_err(bridge_err)?;
        Ok(PyBytes::new(py, &bytes))
    }

    /// Closes the Zenoh session (also done when the client is garbage-collected).
    fn close(&self, py: Python<'_>) -> PyResult<()> {
        self.sims.lock().map_err(poisoned)?.clear();
        py.detach(|| self.inner.session.close().wait())
            .map_err(|e| KoopbridgeError::new_err(format!("closing the session: {e}")))
    }

    fn __enter__(slf: Py<Self>) -> Py<Self> {
        slf
    }

    fn __exit__(
        &self,
        py: Python<'_>,
        _t: Py<PyAny>,
        _v: Py<PyAny>,
        _tb: Py<PyAny>,
    ) -> PyResult<bool> {
        self.close(py)?;
        Ok(false)
    }
}

impl Client {
    /// Runs `f` on the simulator client of `id` (connecting it first if needed), GIL released.
    fn with_sim<T: Send>(
        &self,
        py: Python<'_>,
        id: &str,
        f: impl FnOnce(&mut SimClient) -> bridge::Result<T> + Send,
    ) -> PyResult<T> {
        py.detach(|| {
            let mut sims = self.sims.lock().map_err(poisoned)?;
            if !sims.contains_key(id) {
                let s = SimClient::connect(&self.inner, id, Duration::from_secs(10))
                    .map_err(bridge_err)?;
                sims.insert(id.to_string(), s);
            }
            let sim = sims
                .get_mut(id)
                .ok_or_else(|| PyRuntimeError::new_err("simulator client missing"))?;
            f(sim).map_err(bridge_err)
        })
    }
}

fn secs(t: f64) -> PyResult<Duration> {
    if t.is_finite() && t > 0.0 {
        Ok(Duration::from_secs_f64(t))
    } else {
        Err(PyValueError::new_err(format!(
            "timeout must be positive seconds, got {t}"
        )))
    }
}

fn poisoned<T>(_: T) -> PyErr {
    PyRuntimeError::new_err("client state poisoned by an earlier panic")
}

/// A step reply as Python gets it: `(k, t, x)`, or `(k, t, x, status)` with `with_status`.
fn step_tuple<'py>(
    py: Python<'py>,
    r: &StepReply,
    with_status: bool,
) -> PyResult<Bound<'py, PyTuple>> {
    let (k, t, x) = (
        r.k.into_pyobject(py)?.into_any(),
        r.t.into_pyobject(py)?.into_any(),
        array1(py, &r.x).into_any(),
    );
    if with_status {
        PyTuple::new(py, [k, t, x, status_dict(py, r.status)?.into_any()])
    } else {
        PyTuple::new(py, [k, t, x])
    }
}

/// A step status as the dict `{"terminated": bool, "truncated": bool, "clipped": bool}`.
pub(crate) fn status_dict(py: Python<'_>, s: StepStatus) -> PyResult<Bound<'_, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("terminated", s.terminated())?;
    d.set_item("truncated", s.truncated())?;
    d.set_item("clipped", s.clipped())?;
    Ok(d)
}
