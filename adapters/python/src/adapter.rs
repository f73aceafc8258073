//! `koopbridge.Adapter`: a simulator written in Python, served over Zenoh by `bridge::adapter`.
//!
//! The Python subclass implements `info()`, `reset(seed=None, x0=None)` and `step(u)`; `serve()`
//! runs the one Rust implementation of the simulator side of the protocol on a worker thread.
//! The GIL is released while that thread waits on Zenoh and taken only inside the callbacks; a
//! Python exception becomes a typed error reply carrying its message and serving goes on.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::Duration;

use bridge::adapter::{
    AdapterOptions, AdapterStats, CollectPlan, FreeRunOptions, ResetRequest, SimBackend, SimError,
    SimInfo, Windows,
};
use bridge::codec::StepStatus;
use bridge::session::open_session;
use bridge::zenoh::Wait;
use pyo3::exceptions::{PyNotImplementedError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};

use crate::convert::{array1, from_py_json, to_py_json, vec_f64};
use crate::errors::{bridge_err, InvalidInput, Unsupported};
use crate::zenoh_args::zenoh_options;

/// Base class of simulators written in Python. Subclass it and implement:
///
/// - ``info(self) -> dict`` with keys ``env``, ``dt``, ``state_names``, ``input_names``,
///   ``u_min``, ``u_max`` and optionally ``kind``, ``version``, ``angle_indices``; any other key
///   (e.g. ``fmu``: units, start values, FMI version) must hold JSON-serialisable values and
///   travels in the ``info`` reply's ``extra`` object;
/// - ``reset(self, seed=None, x0=None) -> array`` returning the first state (``nx`` values);
///   ``seed`` asks for a random initial state, ``x0`` for a given one, neither for the default;
/// - ``step(self, u) -> array`` applying ``u`` (``nu`` values, held over one ``dt``) and
///   returning the next state.
///
/// Optionally ``step_status()``, called right after every lockstep ``step`` that returned,
/// returning ``None`` (nothing to report) or a dict of flags for that step, each optional
/// (absent = ``False``): ``terminated`` (the task says the episode has ended at this state: a
/// fall, a Gymnasium termination), ``truncated`` (a time limit cut it), ``clipped`` (the input
/// was clipped into the bounds). They travel in the step reply (PROTOCOL.md §4, type ``0x09``;
/// ``Client.step(id, u, with_status=True)`` returns them) and never stop serving. Another key
/// or an exception there is a ``sim_failure`` reply for that step. Without the method every
/// reply is the plain one, as before.
///
/// Optionally ``collect(policy, seed, n_windows, T, start)`` returning an object with arrays
/// ``x`` ``(n_windows, T+1, nx)`` and ``u`` ``(n_windows, T, nu)`` (``koopbridge.collect.Windows``;
/// ``policy`` is the request's JSON policy with explicit bounds) answers ``collect`` requests;
/// without it they are run with ``reset`` and ``step``, window by window.
///
/// Then call ``serve(session=..., id=...)``: it blocks, answering the protocol's ``info``,
/// ``reset``, ``step`` and ``collect`` queries (lockstep) or publishing states at a fixed rate (free-run)
/// until ``stop()`` is called from another thread, Ctrl-C, or the free-run step limit.
/// Raise ``koopbridge.InvalidInput`` or ``koopbridge.Unsupported`` for a ``bad_request`` or
/// ``unsupported`` reply; any other exception gives a ``sim_failure`` reply with its message,
/// its traceback is printed, and the adapter keeps serving.
///
/// Example::
///
///     class Decay(koopbridge.Adapter):
///         def info(self):
///             return dict(env="decay", dt=0.1, state_names=["x"], input_names=["u"],
///                         u_min=[-1.0], u_max=[1.0])
///         def reset(self, seed=None, x0=None):
///             self.x = np.zeros(1) if x0 is None else np.asarray(x0, float)
///             return self.x
///         def step(self, u):
///             self.x = 0.9 * self.x + u
///             return self.x
///
///     Decay().serve(session="demo", id="decay0", listen=["tcp/127.0.0.1:7501"])
#[pyclass(subclass, module = "koopbridge._native")]
pub struct Adapter {
    stop: Arc<AtomicBool>,
    serving: Arc<AtomicBool>,
    /// The counters of the last `serve()` that returned them, also one ended by Ctrl-C.
    last_stats: Arc<Mutex<Option<AdapterStats>>>,
}

#[pymethods]
impl Adapter {
    /// Accepts and ignores any arguments so that subclasses may define their own ``__init__``.
    #[new]
    #[pyo3(signature = (*_args, **_kwargs))]
    fn new(_args: &Bound<'_, PyTuple>, _kwargs: Option<&Bound<'_, PyDict>>) -> Self {
        Adapter {
            stop: Arc::new(AtomicBool::new(false)),
            serving: Arc::new(AtomicBool::new(false)),
            last_stats: Arc::new(Mutex::new(None)),
        }
    }

    /// What the simulator is (override): a dict, see the class documentation.
    fn info(&self) -> PyResult<Py<PyAny>> {
        Err(PyNotImplementedError::new_err(
            "Adapter subclasses must implement info()",
        ))
    }

    /// Resets the simulator and returns the first state (override).
    #[pyo3(signature = (seed=None, x0=None))]
    fn reset(&self, seed: Option<u64>, x0: Option<Py<PyAny>>) -> PyResult<Py<PyAny>> {
        let _ = (seed, x0);
        Err(PyNotImplementedError::new_err(
            "Adapter subclasses must implement reset(seed=None, x0=None)",
        ))
    }

    /// Applies ``u`` for one ``dt`` and returns the next state (override).
    fn step(&self, u: Py<PyAny>) -> PyResult<Py<PyAny>> {
        let _ = u;
        Err(PyNotImplementedError::new_err(
            "Adapter subclasses must implement step(u)",
        ))
    }

    /// Serves this simulator over Zenoh until stopped; returns the adapter's counters as a dict.
    ///
    /// Arguments: ``session`` (koopbridge session id, the ``koopbridge/{session}/`` root),
    /// ``id`` (simulator id), Zenoh ``connect``/``listen`` endpoint lists, ``mode`` (``peer``,
    /// ``client`` or ``router``), ``zenoh_config`` (a JSON5 file); ``free_run=True`` with
    /// ``rate_hz`` (default real time, ``1/dt``), ``steps`` (default unlimited), the initial
    /// ``seed``/``x0`` and ``wait_subscriber`` (seconds to wait for a subscriber of the state
    /// stream before the first step, so that nobody misses its start; default: start at once).
    #[pyo3(signature = (*, session="default", id="sim0", connect=None, listen=None, mode="peer",
                        zenoh_config=None, free_run=false, rate_hz=None, steps=None, seed=None, x0=None,
                        wait_subscriber=None))]
    #[allow(clippy::too_many_arguments)]
    fn serve(
        slf: &Bound<'_, Self>,
        session: &str,
        id: &str,
        connect: Option<Vec<String>>,
        listen: Option<Vec<String>>,
        mode: &str,
        zenoh_config: Option<std::path::PathBuf>,
        free_run: bool,
        rate_hz: Option<f64>,
        steps: Option<u64>,
        seed: Option<u64>,
        x0: Option<Bound<'_, PyAny>>,
        wait_subscriber: Option<f64>,
    ) -> PyResult<Py<PyAny>> {
        let py = slf.py();
        let info = sim_info(&slf.call_method0("info")?)?;
        let zopts = zenoh_options(connect, listen, mode, zenoh_config)?;
        let mut opts = AdapterOptions::new(session, id).map_err(bridge_err)?;
        if free_run {
            let x0 = match x0 {
                Some(x) => Some(vec_f64(&x, "x0")?),
                None => None,
            };
            opts.free_run = Some(FreeRunOptions {
                rate_hz,
                steps,
                reset: ResetRequest {
                    seed,
                    x0,
                    perturbation: None,
                },
            });
            opts.wait_subscriber = match wait_subscriber {
                Some(w) if !(w.is_finite() && w >= 0.0) => {
                    return Err(PyValueError::new_err(
                        "wait_subscriber must be a finite number of seconds >= 0",
                    ))
                }
                w => w.map(std::time::Duration::from_secs_f64),
            };
        } else if rate_hz.is_some() || steps.is_some() || wait_subscriber.is_some() {
            return Err(PyValueError::new_err(
                "rate_hz, steps and wait_subscriber apply to free_run=True only",
            ));
        }
        let (stop, serving, last_stats) = {
            let me = slf.borrow();
            (me.stop.clone(), me.serving.clone(), me.last_stats.clone())
        };
        let keep_stats = |stats: &AdapterStats| {
            if let Ok(mut slot) = last_stats.lock() {
                *slot = Some(stats.clone());
            }
        };
        if serving.swap(true, Ordering::SeqCst) {
            return Err(PyRuntimeError::new_err("this adapter is already serving"));
        }
        stop.store(false, Ordering::SeqCst);
        let backend = PyBackend {
            obj: slf.clone().into_any().unbind(),
            info,
            has_status: slf.hasattr(pyo3::intern!(py, "step_status"))?,
        };
        let (tx, rx) = mpsc::channel();
        // A Mutex makes the receiver Sync, as waiting with the GIL released requires.
        let rx = std::sync::Mutex::new(rx);
        let recv = |t: Option<Duration>| match rx.lock() {
            Ok(rx) => match t {
                Some(t) => rx.recv_timeout(t),
                None => rx.recv().map_err(|_| mpsc::RecvTimeoutError::Disconnected),
            },
            Err(_) => Err(mpsc::RecvTimeoutError::Disconnected),
        };
        let worker_stop = stop.clone();
        let spawned = std::thread::Builder::new()
            .name(format!("koopbridge-adapter-{id}"))
            .spawn(move || {
                let mut backend = backend;
                // Attach once and detach for the whole serve: the thread keeps its Python thread
                // state, so each callback's `Python::attach` only re-takes the GIL instead of
                // creating and destroying a thread state per step.
                let result = Python::attach(|py| {
                    py.detach(|| {
                        open_session(&zopts).and_then(|s| {
                            let r = bridge::adapter::serve(&s, &mut backend, &opts, &worker_stop);
                            let _ = s.close().wait();
                            r
                        })
                    })
                });
                // Drop the Python object reference with the GIL held.
                Python::attach(|_| drop(backend));
                let _ = tx.send(result);
            });
        let handle = match spawned {
            Ok(h) => h,
            Err(e) => {
                serving.store(false, Ordering::SeqCst);
                return Err(PyRuntimeError::new_err(format!(
                    "cannot start the adapter thread: {e}"
                )));
            }
        };
        let outcome = loop {
            match py.detach(|| recv(Some(Duration::from_millis(100)))) {
                Ok(r) => {
                    if let Ok(stats) = &r {
                        keep_stats(stats);
                    }
                    break r.map_err(bridge_err);
                }
                Err(mpsc::RecvTimeoutError::Timeout) => {
                    if let Err(e) = py.check_signals() {
                        // Ctrl-C (or another signal handler's exception): stop the worker and
                        // keep its counters for `last_stats` before re-raising.
                        stop.store(true, Ordering::SeqCst);
                        if let Ok(Ok(stats)) = py.detach(|| recv(None)) {
                            keep_stats(&stats);
                        }
                        break Err(e);
                    }
                }
                Err(mpsc::RecvTimeoutError::Disconnected) => {
                    break Err(PyRuntimeError::new_err(
                        "the adapter thread ended without a result",
                    ))
                }
            }
        };
        let _ = py.detach(|| handle.join());
        serving.store(false, Ordering::SeqCst);
        to_py_json(py, &outcome?)
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

    /// The counters (as ``serve()`` returns them) of the last ``serve()`` that ran, also one
    /// ended by Ctrl-C, whose ``KeyboardInterrupt`` carries no return value; ``None`` before.
    #[getter]
    fn last_stats(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        let stats = self.last_stats.lock().ok().and_then(|s| s.clone());
        match stats {
            Some(s) => to_py_json(py, &s),
            None => Ok(py.None()),
        }
    }
}

/// The Python object seen as a `SimBackend`: each call takes the GIL for the callback only.
struct PyBackend {
    obj: Py<PyAny>,
    info: SimInfo,
    /// The object has a `step_status()` method (read once, when serving starts).
    has_status: bool,
}

impl SimBackend for PyBackend {
    fn info(&self) -> SimInfo {
        self.info.clone()
    }

    fn reset(&mut self, req: &ResetRequest) -> Result<Vec<f64>, SimError> {
        Python::attach(|py| {
            let kwargs = PyDict::new(py);
            let set = |k: &str, v: Bound<'_, PyAny>| kwargs.set_item(k, v);
            let r = (|| -> PyResult<Vec<f64>> {
                set("seed", req.seed.into_pyobject(py)?.into_any())?;
                match &req.x0 {
                    Some(x0) => set("x0", array1(py, x0).into_any())?,
                    None => set("x0", py.None().into_bound(py))?,
                }
                // Only when given: a simulator whose reset() has no `perturbation` serves as before.
                if let Some(p) = &req.perturbation {
                    let json = serde_json::to_string(p)
                        .map_err(|e| PyValueError::new_err(e.to_string()))?;
                    let obj = py.import("json")?.call_method1("loads", (json,))?;
                    set("perturbation", obj)?;
                }
                let x = self.obj.bind(py).call_method("reset", (), Some(&kwargs))?;
                vec_f64(&x, "the state returned by reset()")
            })();
            r.map_err(|e| {
                let no_keyword = req.perturbation.is_some()
                    && e.is_instance_of::<pyo3::exceptions::PyTypeError>(py)
                    && e.value(py).to_string().contains("perturbation");
                if no_keyword {
                    SimError::Unsupported(
                        "this simulator's reset() takes no `perturbation` (the legged adapters' \
                         does)"
                            .into(),
                    )
                } else {
                    sim_error(py, e, "reset")
                }
            })
        })
    }

    fn step(&mut self, u: &[f64]) -> Result<Vec<f64>, SimError> {
        Python::attach(|py| {
            let r = (|| -> PyResult<Vec<f64>> {
                let x = self
                    .obj
                    .bind(py)
                    .call_method1(pyo3::intern!(py, "step"), (array1(py, u),))?;
                vec_f64(&x, "the state returned by step()")
            })();
            r.map_err(|e| sim_error(py, e, "step"))
        })
    }

    fn step_reporting(&mut self, u: &[f64]) -> Result<(Vec<f64>, StepStatus), SimError> {
        if !self.has_status {
            return Ok((self.step(u)?, StepStatus::EMPTY));
        }
        // One GIL take for the step and its status.
        Python::attach(|py| {
            let x = (|| -> PyResult<Vec<f64>> {
                let x = self
                    .obj
                    .bind(py)
                    .call_method1(pyo3::intern!(py, "step"), (array1(py, u),))?;
                vec_f64(&x, "the state returned by step()")
            })()
            .map_err(|e| sim_error(py, e, "step"))?;
            let status = self
                .obj
                .bind(py)
                .call_method0(pyo3::intern!(py, "step_status"))
                .and_then(|s| step_status(&s))
                .map_err(|e| sim_error(py, e, "step_status"))?;
            Ok((x, status))
        })
    }

    fn collect(&mut self, plan: &CollectPlan) -> Result<Windows, SimError> {
        let own = Python::attach(|py| {
            self.python_collect(py, plan)
                .map(|r| r.map_err(|e| sim_error(py, e, "collect")))
        });
        // A plain `Adapter` subclass without `collect`: its reset and step, window by window.
        own.unwrap_or_else(|| bridge::adapter::run_windows(self, plan))
    }
}

impl PyBackend {
    /// The Python object's own `collect(policy, seed, n_windows, T, start)` (``SimulatorAdapter``
    /// has one), if it has that method.
    fn python_collect(&self, py: Python<'_>, plan: &CollectPlan) -> Option<PyResult<Windows>> {
        let obj = self.obj.bind(py);
        let method = obj.getattr(pyo3::intern!(py, "collect")).ok()?;
        Some((|| {
            let policy = to_py_json(py, &plan.policy())?;
            let args = (policy, plan.seed, plan.windows, plan.steps, plan.first);
            let w = method.call1(args)?;
            let (n, t) = (plan.windows, plan.steps);
            let (nx, nu) = (self.info.nx(), self.info.nu());
            Ok(Windows {
                x: flat(&w.getattr("x")?, &[n, t + 1, nx], "collect(): x")?,
                u: flat(&w.getattr("u")?, &[n, t, nu], "collect(): u")?,
            })
        })())
    }
}

/// The flags `step_status()` returned: `None`, or a dict whose keys are among `terminated`,
/// `truncated` and `clipped` (values read as booleans).
fn step_status(obj: &Bound<'_, PyAny>) -> PyResult<StepStatus> {
    if obj.is_none() {
        return Ok(StepStatus::EMPTY);
    }
    let d = obj.cast::<PyDict>().map_err(|_| {
        PyValueError::new_err(format!(
            "step_status() must return None or a dict, got {}",
            obj.get_type()
                .name()
                .map(|n| n.to_string())
                .unwrap_or_default()
        ))
    })?;
    let mut status = StepStatus::EMPTY;
    for (k, v) in d.iter() {
        let flag = match k.extract::<String>().as_deref() {
            Ok("terminated") => StepStatus::TERMINATED,
            Ok("truncated") => StepStatus::TRUNCATED,
            Ok("clipped") => StepStatus::CLIPPED,
            _ => {
                return Err(PyValueError::new_err(format!(
                    "step_status(): unknown key {} (the flags are terminated, truncated, clipped)",
                    k.repr()?
                )))
            }
        };
        if v.is_truthy()? {
            status = status | flag;
        }
    }
    Ok(status)
}

/// The float64 values of array `obj`, which must have `shape`.
fn flat(obj: &Bound<'_, PyAny>, shape: &[usize], what: &str) -> PyResult<Vec<f64>> {
    let np = obj.py().import("numpy")?;
    let a = np.call_method1("ascontiguousarray", (obj, "float64"))?;
    let got: Vec<usize> = a.getattr("shape")?.extract()?;
    if got != shape {
        return Err(PyValueError::new_err(format!(
            "{what} has shape {got:?}, expected {shape:?}"
        )));
    }
    vec_f64(&a.call_method0("ravel")?, what)
}

/// A Python exception raised by a callback as the backend error the protocol reports.
fn sim_error(py: Python<'_>, e: PyErr, what: &str) -> SimError {
    if e.is_instance_of::<InvalidInput>(py) {
        return SimError::InvalidInput(e.value(py).to_string());
    }
    if e.is_instance_of::<Unsupported>(py) {
        return SimError::Unsupported(e.value(py).to_string());
    }
    let ty = e
        .get_type(py)
        .name()
        .map(|n| n.to_string())
        .unwrap_or_else(|_| "Exception".into());
    let msg = format!("{what}() raised {ty}: {}", e.value(py));
    // The traceback helps whoever runs the adapter; the orchestrator gets the message.
    e.display(py);
    SimError::Failed(msg)
}

/// Keys of `info()`'s dict that are fields of `SimInfo`; every other key goes to `extra`.
const INFO_KEYS: [&str; 9] = [
    "env",
    "kind",
    "version",
    "dt",
    "state_names",
    "input_names",
    "u_min",
    "u_max",
    "angle_indices",
];

/// The keys of `info()`'s dict that are not `SimInfo` fields, as JSON (through Python's `json`
/// module, so anything it can encode is accepted; NaN and infinities are refused).
fn extra_info(d: &Bound<'_, PyAny>) -> PyResult<serde_json::Map<String, serde_json::Value>> {
    let mut out = serde_json::Map::new();
    for item in d.try_iter()? {
        let key = item?;
        let name: String = key
            .extract()
            .map_err(|_| PyValueError::new_err("info(): the dict's keys must be strings"))?;
        if INFO_KEYS.contains(&name.as_str()) {
            continue;
        }
        let v = from_py_json(&d.get_item(&key)?, &format!("info(): '{name}'"))?;
        out.insert(name, v);
    }
    Ok(out)
}

/// The `SimInfo` described by the dict returned from `info()`.
fn sim_info(d: &Bound<'_, PyAny>) -> PyResult<SimInfo> {
    let get = |k: &str| -> PyResult<Bound<'_, PyAny>> {
        d.get_item(k)
            .map_err(|_| PyValueError::new_err(format!("info(): the dict has no '{k}'")))
    };
    let opt = |k: &str| -> Option<Bound<'_, PyAny>> { d.get_item(k).ok().filter(|v| !v.is_none()) };
    let names = |k: &str| -> PyResult<Vec<String>> {
        get(k)?
            .extract()
            .map_err(|_| PyValueError::new_err(format!("info(): '{k}' must be a list of strings")))
    };
    let info = SimInfo {
        env: get("env")?.extract()?,
        kind: match opt("kind") {
            Some(v) => v.extract()?,
            None => "python".into(),
        },
        version: match opt("version") {
            Some(v) => v.str()?.to_string(),
            None => String::new(),
        },
        dt: get("dt")?.extract()?,
        state_names: names("state_names")?,
        input_names: names("input_names")?,
        u_min: vec_f64(&get("u_min")?, "info()['u_min']")?,
        u_max: vec_f64(&get("u_max")?, "info()['u_max']")?,
        angle_indices: match opt("angle_indices") {
            Some(v) => v.extract()?,
            None => Vec::new(),
        },
        extra: extra_info(d)?,
    };
    if !(info.dt > 0.0 && info.dt.is_finite()) {
        return Err(PyValueError::new_err(format!(
            "info(): dt must be positive, got {}",
            info.dt
        )));
    }
    if info.u_min.len() != info.nu() || info.u_max.len() != info.nu() {
        return Err(PyValueError::new_err(format!(
            "info(): {} input names but {} u_min and {} u_max values",
            info.nu(),
            info.u_min.len(),
            info.u_max.len()
        )));
    }
    Ok(info)
}
