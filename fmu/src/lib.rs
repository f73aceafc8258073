//! The learned Koopman MPC as an FMI 3.0 / FMI 2.0 co-simulation FMU: a `cdylib` implementing
//! both C APIs ([`fmi3`], [`fmi2`]) over `koopman`'s model and MPC — the same "model + MPC
//! settings → command" path as the MPC service ([`koopman::mpc::served`]) — with no Python and
//! no Zenoh inside.
//!
//! The FMU's `resources/` hold the saved model (`model/`) and `controller.json`
//! ([`settings::ControllerFile`]); both load in instantiate. Each `doStep` solves the MPC for
//! the measured state and the reference as set and holds the plan's first input over the step
//! ([`instance::Instance::do_step`]). `koopbridge export-fmu` packs it, with the model
//! description of [`describe`] generated from the same variable table ([`layout`]).

pub mod describe;
pub mod ffi;
pub mod fmi2;
pub mod fmi3;
pub mod instance;
pub mod layout;
pub mod settings;

#[cfg(test)]
mod tests;
