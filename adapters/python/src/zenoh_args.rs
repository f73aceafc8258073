//! The Zenoh arguments every binding takes (`connect`, `listen`, `mode`, `zenoh_config`) as
//! `bridge`'s `ZenohOptions`.

use std::path::PathBuf;

use bridge::session::{Mode, ZenohOptions};
use pyo3::exceptions::PyValueError;
use pyo3::PyResult;

/// `ZenohOptions` from the Python arguments: missing endpoint lists are empty, `mode` is parsed
/// by `bridge` (`peer`, `client` or `router`; anything else is a `ValueError`).
pub fn zenoh_options(
    connect: Option<Vec<String>>,
    listen: Option<Vec<String>>,
    mode: &str,
    zenoh_config: Option<PathBuf>,
) -> PyResult<ZenohOptions> {
    let mode: Mode = mode.parse().map_err(|_| {
        PyValueError::new_err(format!("mode '{mode}': expected peer, client or router"))
    })?;
    Ok(ZenohOptions {
        connect: connect.unwrap_or_default(),
        listen: listen.unwrap_or_default(),
        mode: Some(mode),
        zenoh_config,
    })
}
