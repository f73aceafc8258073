//! `koopbridge.Mpc`: in-process receding-horizon MPC solves on a loaded model
//! (`koopman::mpc::MpcController`).

use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use koopman::model::LiftedModel;
use koopman::mpc::{MpcConfig, MpcController};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::convert::{array2, vec_f64, vec_n};
use crate::errors::koopman_err;
use crate::model::KoopmanModel;

/// Linear MPC on a lifted model (SPEC.md, "Control").
///
/// ``Mpc(model, **config)``: ``model`` is a ``KoopmanModel`` or the directory of any saved
/// lifted model (Koopman or EDMD); the keyword arguments are the fields of the MPC
/// configuration: ``horizon`` (15), ``q``, ``r``, ``terminal`` (diagonals),
/// ``terminal_riccati`` (the model's Riccati cost-to-go as terminal cost), ``u_min``,
/// ``u_max``, ``du_max``, ``x_min``, ``x_max``, ``solver`` (``"dedicated"``, ``"clarabel"``,
/// ``"closed-form"``), ``regularization``, ``max_iterations``, ``time_limit``, ``fallback``.
/// Every matrix that depends on the model alone is built once, here.
#[pyclass(module = "koopbridge._native")]
pub struct Mpc {
    ctrl: Mutex<MpcController<'static>>,
    nx: usize,
    nu: usize,
    horizon: usize,
}

#[pymethods]
impl Mpc {
    #[new]
    #[pyo3(signature = (model, **config))]
    fn new(
        py: Python<'_>,
        model: &Bound<'_, PyAny>,
        config: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        let model: Arc<dyn LiftedModel> = if let Ok(m) = model.cast::<KoopmanModel>() {
            m.get().inner.clone()
        } else {
            let path: PathBuf = model.extract().map_err(|_| {
                PyValueError::new_err("model: expected a KoopmanModel or a model directory")
            })?;
            Arc::from(
                py.detach(|| koopman::model::load_lifted(&path))
                    .map_err(koopman_err)?,
            )
        };
        let json = match config {
            Some(d) => py
                .import("json")?
                .call_method1("dumps", (to_plain(d)?,))?
                .extract::<String>()?,
            None => "{}".into(),
        };
        let cfg: MpcConfig = serde_json::from_str(&json)
            .map_err(|e| PyValueError::new_err(format!("MPC configuration: {e}")))?;
        let (nx, nu, horizon) = (model.nx(), model.nu(), cfg.horizon);
        let ctrl = py
            .detach(move || MpcController::from_shared(model, &cfg))
            .map_err(koopman_err)?;
        Ok(Mpc {
            ctrl: Mutex::new(ctrl),
            nx,
            nu,
            horizon,
        })
    }

    /// Solves at state ``x`` (nx,) for ``reference``: one state (nx,), held over the horizon, or
    /// the horizon's states (H, nx). With ``feedforward`` (a plan's inputs at this and the next
    /// H−1 steps, (H, nu)), ``reference`` is the plan's state at this step (nx,) and the plan is
    /// the error-state MPC's (the deviation from the plan; ``MpcController::solve_about_plan``).
    /// Returns a dict: ``u`` (H, nu) plan, first input first; ``status`` (``solved``,
    /// ``inaccurate``, ``suboptimal`` or ``fallback:<reason>``); ``solve_time`` in seconds;
    /// ``iterations``.
    #[pyo3(signature = (x, reference, feedforward=None))]
    fn solve<'py>(
        &self,
        py: Python<'py>,
        x: &Bound<'py, PyAny>,
        reference: &Bound<'py, PyAny>,
        feedforward: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let x = vec_n(x, self.nx, "x")?;
        let np = py.import("numpy")?;
        let r = vec_f64(&np.call_method1("ravel", (reference,))?, "reference")?;
        let ff = match feedforward {
            Some(f) => Some(vec_n(
                &np.call_method1("ravel", (f,))?,
                self.nu * self.horizon,
                "feedforward",
            )?),
            None => None,
        };
        if ff.is_some() && r.len() != self.nx {
            return Err(PyValueError::new_err(format!(
                "reference: with a feedforward, the plan's state at this step ({} values), got {}",
                self.nx,
                r.len()
            )));
        }
        if r.len() != self.nx && r.len() != self.nx * self.horizon {
            return Err(PyValueError::new_err(format!(
                "reference: expected {} (one state) or {} (H × nx) values, got {}",
                self.nx,
                self.nx * self.horizon,
                r.len()
            )));
        }
        let sol = py.detach(|| {
            let mut c = self
                .ctrl
                .lock()
                .map_err(|_| PyRuntimeError::new_err("MPC controller poisoned"))?;
            match &ff {
                Some(ff) => c.solve_about_plan(&x, &r, ff),
                None => c.solve(&x, &r),
            }
            .map_err(koopman_err)
        })?;
        let d = PyDict::new(py);
        d.set_item(
            "u",
            array2(py, sol.u.len() / self.nu.max(1), self.nu, &sol.u)?,
        )?;
        let status = match serde_json::to_value(sol.status) {
            Ok(serde_json::Value::String(s)) => s,
            Ok(serde_json::Value::Object(m)) => m
                .iter()
                .map(|(k, v)| format!("{k}:{}", v.as_str().unwrap_or("?")))
                .collect::<Vec<_>>()
                .join(","),
            _ => format!("{:?}", sol.status),
        };
        d.set_item("status", status)?;
        d.set_item("solve_time", sol.solve_time.as_secs_f64())?;
        d.set_item("iterations", sol.iterations)?;
        Ok(d)
    }

    /// The horizon H.
    #[getter]
    fn horizon(&self) -> usize {
        self.horizon
    }

    fn __repr__(&self) -> String {
        format!(
            "Mpc(nx={}, nu={}, horizon={})",
            self.nx, self.nu, self.horizon
        )
    }
}

/// Numpy arrays in the configuration dict become lists (so that `json.dumps` accepts them).
fn to_plain<'py>(d: &Bound<'py, PyDict>) -> PyResult<Bound<'py, PyDict>> {
    let out = PyDict::new(d.py());
    for (k, v) in d.iter() {
        let v = if v.hasattr("tolist")? {
            v.call_method0("tolist")?
        } else {
            v
        };
        out.set_item(k, v)?;
    }
    Ok(out)
}
