//! The Python exception types of koopbridge and the conversions from the Rust errors.

use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyDict, PyTuple, PyType};

pyo3::create_exception!(
    koopbridge,
    KoopbridgeError,
    PyException,
    "Base class of every error raised by koopbridge."
);
pyo3::create_exception!(
    koopbridge,
    RemoteError,
    KoopbridgeError,
    "A remote participant answered with a typed error reply (`code` and `message` attributes)."
);
pyo3::create_exception!(
    koopbridge,
    GoneError,
    KoopbridgeError,
    "A participant's liveliness token disappeared (it died or left); the message names it."
);
pyo3::create_exception!(
    koopbridge,
    InvalidInput,
    KoopbridgeError,
    "Raise it from an adapter's `reset`/`step` to answer with a `bad_request` error reply."
);
pyo3::create_exception!(
    koopbridge,
    Unsupported,
    KoopbridgeError,
    "Raise it from an adapter's `reset`/`step` to answer with an `unsupported` error reply."
);

static BRIDGE_TIMEOUT: PyOnceLock<Py<PyType>> = PyOnceLock::new();

/// `koopbridge.BridgeTimeout`: a participant did not answer in time. A subclass of both
/// `KoopbridgeError` and Python's built-in `TimeoutError` (which it does not shadow), made once.
fn bridge_timeout(py: Python<'_>) -> PyResult<Bound<'_, PyType>> {
    let t = BRIDGE_TIMEOUT.get_or_try_init(py, || -> PyResult<Py<PyType>> {
        let builtins = py.import("builtins")?;
        let bases = PyTuple::new(
            py,
            [
                py.get_type::<KoopbridgeError>().into_any(),
                builtins.getattr("TimeoutError")?,
            ],
        )?;
        let ns = PyDict::new(py);
        ns.set_item("__module__", "koopbridge")?;
        ns.set_item(
            "__doc__",
            "A participant did not answer in time; the message names it. Also a built-in TimeoutError.",
        )?;
        let t = builtins
            .getattr("type")?
            .call1(("BridgeTimeout", bases, ns))?
            .cast_into::<PyType>()?;
        Ok(t.unbind())
    })?;
    Ok(t.bind(py).clone())
}

/// Adds the exception types to the module.
pub fn register(py: Python<'_>, m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("KoopbridgeError", py.get_type::<KoopbridgeError>())?;
    m.add("RemoteError", py.get_type::<RemoteError>())?;
    m.add("BridgeTimeout", bridge_timeout(py)?)?;
    m.add("GoneError", py.get_type::<GoneError>())?;
    m.add("InvalidInput", py.get_type::<InvalidInput>())?;
    m.add("Unsupported", py.get_type::<Unsupported>())?;
    Ok(())
}

/// A `bridge` error as a Python exception of the matching type.
pub fn bridge_err(e: bridge::Error) -> PyErr {
    let msg = e.to_string();
    match e {
        bridge::Error::Remote { reply, .. } => Python::attach(|py| {
            let err = RemoteError::new_err(msg);
            let v = err.value(py);
            // Attributes for programmatic handling; failures to set them are not worth an error.
            let _ = v.setattr("code", reply.code.to_string());
            let _ = v.setattr("message", reply.message);
            err
        }),
        bridge::Error::Timeout { .. } => Python::attach(|py| match bridge_timeout(py) {
            Ok(t) => PyErr::from_type(t, msg),
            Err(e) => e,
        }),
        bridge::Error::Gone(_) => GoneError::new_err(msg),
        bridge::Error::Koopman(k) => koopman_err(k),
        _ => KoopbridgeError::new_err(msg),
    }
}

/// A `koopman` error as a Python exception (`ValueError` for bad arguments, `OSError` for files).
pub fn koopman_err(e: koopman::Error) -> PyErr {
    use pyo3::exceptions::{PyOSError, PyValueError};
    let msg = e.to_string();
    match e {
        koopman::Error::Io { .. } => PyOSError::new_err(msg),
        koopman::Error::Dimension { .. }
        | koopman::Error::NonFinite(_)
        | koopman::Error::InvalidArgument(_)
        | koopman::Error::UnknownName { .. } => PyValueError::new_err(msg),
        _ => KoopbridgeError::new_err(msg),
    }
}
