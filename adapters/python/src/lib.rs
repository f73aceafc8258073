//! `koopbridge._native`: the pyo3 extension module behind the Python package `koopbridge`.
//!
//! The protocol lives once, in Rust (crate `bridge`); Python gets it through these bindings:
//! - [`adapter`]: `Adapter`, the base class of simulators written in Python;
//! - [`model`]: `KoopmanModel`, a trained model loaded from disk;
//! - [`mpc`]: `Mpc`, in-process MPC solves on a loaded model;
//! - [`client`]: `Client`, the querying side (simulators, MPC service, model store), with
//!   [`control`] for the JSON control plane through the `bridge` types;
//! - [`systems`]: `ReferenceSystem`, the built-in Rust reference dynamics;
//! - [`planner`]: `PlannerService`, a Python planner served at `…/planner/{id}/plan`;
//! - [`survival`]: `survival`, the scenario engine's survival metric of a tracking task;
//! - [`errors`]: the exception types; [`convert`]: numpy conversions; [`zenoh_args`]: the
//!   Zenoh arguments as `ZenohOptions`.

use pyo3::prelude::*;

mod adapter;
mod client;
mod control;
mod convert;
mod errors;
mod model;
mod mpc;
mod planner;
mod survival;
mod systems;
mod zenoh_args;

/// The extension module.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add_class::<adapter::Adapter>()?;
    m.add_class::<model::KoopmanModel>()?;
    m.add_class::<model::BilinearModel>()?;
    m.add_class::<mpc::Mpc>()?;
    m.add_class::<client::Client>()?;
    m.add_class::<systems::ReferenceSystem>()?;
    m.add_class::<planner::PlannerService>()?;
    m.add_function(wrap_pyfunction!(survival::survival, m)?)?;
    errors::register(py, m)?;
    m.add("PROTOCOL_VERSION", bridge::codec::PROTOCOL_VERSION)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
