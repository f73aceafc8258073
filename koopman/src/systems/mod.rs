//! Reference dynamical systems of SPEC.md ("Environments"), each integrated over one step with the
//! input held constant (zero-order hold) by an accurate adaptive integrator.
//!
//! The continuous-time systems use [`integrator::dopri5`] (Dormand–Prince 5(4), rtol 1e-10,
//! atol 1e-12) over each sampling interval; the polynomial system is a discrete map.

pub mod damped;
pub mod double;
pub mod integrator;
pub mod polynomial;
mod registry;
mod system;

pub use damped::DampedPendulum;
pub use double::DoublePendulum;
pub use polynomial::PolynomialSystem;
pub use registry::{by_name, by_name_with, SystemOptions, NAMES};
pub use system::System;
