//! The Python exception types of koopbridge and the conversions from the Rust errors.

use pyo3::exceptions::PyException;
use pyo3::prelude::*;

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
    TimeoutError,
    KoopbridgeError,
    "A participant did not answer in time; the message names it."
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

/// Adds the exception types to the module.
pub fn register(py: Python<'_>, m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("KoopbridgeError", py.get_type::<KoopbridgeError>())?;
    m.add("RemoteError", py.get_type::<RemoteError>())?;
    m.add("TimeoutError", py.get_type::<TimeoutError>())?;
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
        bridge::Error::Timeout { .. } => TimeoutError::new_err(msg),
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
