//! `koopbridge.ReferenceSystem`: the built-in Rust reference dynamics (`koopman::systems`), e.g.
//! to check a Python or FMU simulator against them step by step.

use koopman::systems::System;
use numpy::PyArray1;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::convert::{array1, vec_n};
use crate::errors::koopman_err;

/// A reference system by name (``damped-pendulum``, ``double-pendulum``, ``polynomial``).
#[pyclass(module = "koopbridge._native", frozen)]
pub struct ReferenceSystem {
    sys: Box<dyn System>,
}

#[pymethods]
impl ReferenceSystem {
    #[new]
    fn new(name: &str) -> PyResult<Self> {
        Ok(ReferenceSystem {
            sys: koopman::systems::by_name(name).map_err(koopman_err)?,
        })
    }

    /// The known names.
    #[staticmethod]
    fn names() -> Vec<&'static str> {
        koopman::systems::NAMES.to_vec()
    }

    /// Name, dt, dimensions, state and input names and input bounds, as a dict.
    fn info<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        let (lo, hi) = self.sys.input_bounds();
        d.set_item("env", self.sys.name())?;
        d.set_item("dt", self.sys.dt())?;
        d.set_item("state_names", self.sys.state_names())?;
        d.set_item("input_names", self.sys.input_names())?;
        d.set_item("u_min", lo)?;
        d.set_item("u_max", hi)?;
        d.set_item("angle_indices", self.sys.angle_indices())?;
        Ok(d)
    }

    /// One step of ``dt`` from ``x`` with ``u`` held constant: the next state.
    fn step<'py>(
        &self,
        py: Python<'py>,
        x: &Bound<'py, PyAny>,
        u: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let x = vec_n(x, self.sys.nx(), "x")?;
        let u = vec_n(u, self.sys.nu(), "u")?;
        let mut next = vec![0.0; x.len()];
        py.detach(|| self.sys.step(&x, &u, &mut next));
        Ok(array1(py, &next))
    }
}
