//! Conversions between numpy arrays (or any float sequence) and Rust vectors and matrices.

use faer::{Mat, MatRef};
use numpy::{PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

/// A 1-D vector of floats from a numpy array or any sequence of numbers; `what` names it in errors.
pub fn vec_f64(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<f64>> {
    if let Ok(a) = obj.extract::<PyReadonlyArray1<'_, f64>>() {
        return Ok(a.as_array().to_vec());
    }
    let np = obj.py().import("numpy")?;
    let arr = np
        .call_method1("asarray", (obj, "float64"))
        .map_err(|e| PyValueError::new_err(format!("{what}: not an array of numbers ({e})")))?;
    let ndim: usize = arr.getattr("ndim")?.extract()?;
    if ndim > 1 {
        return Err(PyValueError::new_err(format!(
            "{what}: expected a 1-D array, got {ndim}-D"
        )));
    }
    let a: PyReadonlyArray1<'_, f64> = arr.call_method0("ravel")?.extract()?;
    Ok(a.as_array().to_vec())
}

/// A 1-D vector of exactly `n` finite floats.
pub fn vec_n(obj: &Bound<'_, PyAny>, n: usize, what: &str) -> PyResult<Vec<f64>> {
    let v = vec_f64(obj, what)?;
    if v.len() != n {
        return Err(PyValueError::new_err(format!(
            "{what}: expected {n} values, got {}",
            v.len()
        )));
    }
    check_finite(&v, what)?;
    Ok(v)
}

/// Ok when every value of `v` is finite, else a `ValueError` naming `what`.
pub fn check_finite(v: &[f64], what: &str) -> PyResult<()> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(PyValueError::new_err(format!(
            "{what}: values must be finite"
        )))
    }
}

/// A 2-D array of floats as (rows, cols, row-major values); a 1-D array is one row.
pub fn rows_f64(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<(usize, usize, Vec<f64>)> {
    let np = obj.py().import("numpy")?;
    let arr = np
        .call_method1("asarray", (obj, "float64"))
        .map_err(|e| PyValueError::new_err(format!("{what}: not an array of numbers ({e})")))?;
    let ndim: usize = arr.getattr("ndim")?.extract()?;
    let arr = match ndim {
        1 => arr.call_method1("reshape", (1, -1))?,
        2 => arr,
        _ => {
            return Err(PyValueError::new_err(format!(
                "{what}: expected a 1-D or 2-D array, got {ndim}-D"
            )))
        }
    };
    let a: PyReadonlyArray2<'_, f64> = np.call_method1("ascontiguousarray", (arr,))?.extract()?;
    let view = a.as_array();
    let (r, c) = view.dim();
    Ok((r, c, view.iter().copied().collect()))
}

/// A numpy 1-D array holding `v`.
pub fn array1<'py>(py: Python<'py>, v: &[f64]) -> Bound<'py, PyArray1<f64>> {
    PyArray1::from_slice(py, v)
}

/// A numpy 2-D array of shape (rows, cols) from row-major values.
pub fn array2<'py>(
    py: Python<'py>,
    rows: usize,
    cols: usize,
    v: &[f64],
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    PyArray1::from_slice(py, v).reshape([rows, cols])
}

/// A numpy 2-D array copied from a faer matrix.
pub fn mat<'py>(py: Python<'py>, m: MatRef<'_, f64>) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let (r, c) = (m.nrows(), m.ncols());
    let mut v = Vec::with_capacity(r * c);
    for i in 0..r {
        for j in 0..c {
            v.push(m[(i, j)]);
        }
    }
    array2(py, r, c, &v)
}

/// A faer matrix from row-major values.
pub fn faer_rows(rows: usize, cols: usize, v: &[f64]) -> Mat<f64> {
    Mat::from_fn(rows, cols, |i, j| v[i * cols + j])
}

/// A serialisable Rust value as the Python object `json.loads` makes of it (dicts, lists, ...).
pub fn to_py_json<T: serde::Serialize>(py: Python<'_>, v: &T) -> PyResult<Py<PyAny>> {
    let text = serde_json::to_string(v)
        .map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(e.to_string()))?;
    Ok(py.import("json")?.call_method1("loads", (text,))?.unbind())
}

/// A Python object as JSON through `json.dumps` (NaN and infinities refused); `what` names it.
pub fn from_py_json(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<serde_json::Value> {
    let py = obj.py();
    let kwargs = pyo3::types::PyDict::new(py);
    kwargs.set_item("allow_nan", false)?;
    let text: String = py
        .import("json")?
        .getattr("dumps")?
        .call((obj,), Some(&kwargs))
        .map_err(|e| PyValueError::new_err(format!("{what} is not JSON-serialisable: {e}")))?
        .extract()?;
    serde_json::from_str(&text).map_err(|e| PyValueError::new_err(format!("{what}: {e}")))
}

/// A reset's perturbation from its Python dict (PROTOCOL.md "reset"); `ValueError` naming what
/// is wrong (an unknown key, a scale that is not finite and > 0).
pub fn perturbation(obj: &Bound<'_, PyAny>) -> PyResult<bridge::messages::Perturbation> {
    let v = from_py_json(obj, "perturbation")?;
    let p: bridge::messages::Perturbation = serde_json::from_value(v)
        .map_err(|e| PyValueError::new_err(format!("perturbation: {e}")))?;
    p.check().map_err(PyValueError::new_err)?;
    Ok(p)
}
