//! `koopman` — the mathematics of koopbridge: reference systems, datasets, neural Koopman models,
//! their training with hand-written gradients, linear MPC and analysis. No networking, no async.
//!
//! Layers, each readable alone:
//! - [`rng`]: a small deterministic random number generator (reproducible across platforms);
//! - [`systems`]: reference dynamics (damped pendulum, double pendulum, polynomial) and integrators;
//! - [`data`]: windows of states and inputs, splits, `.npz` I/O;
//! - [`model`]: the neural Koopman model, EDMD and NNDM baselines, save/load;
//! - [`train`]: losses with hand-written gradients, Adam, the training loop;
//! - [`mpc`]: condensed linear MPC, its solvers and baselines;
//! - [`linalg`]: the small dense Cholesky (solve, inverse, one-row updates) training and MPC share;
//! - [`analysis`]: conditioning, spectra, scaling-law fits;
//! - [`fsutil`]: the one atomic file write everything uses.

pub mod analysis;
pub mod data;
pub mod error;
pub mod fsutil;
pub mod linalg;
pub mod model;
pub mod mpc;
pub mod rng;
pub mod systems;
pub mod train;

pub use error::{Error, Result};
