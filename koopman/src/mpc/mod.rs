//! Linear MPC on lifted (Koopman) models: the condensed QP of SPEC.md ("Control"), its two
//! solvers, the baselines (closed form + clamping, LQR, random shooting) and closed-loop
//! evaluation on the reference systems.
//!
//! - [`MpcController`] (built once per model and [`MpcConfig`]) plans with
//!   [`MpcController::solve`]; [`SolverKind`] picks the dedicated box-QP solver
//!   ([`boxqp::BoxQp`]), Clarabel ([`clarabel_qp::ClarabelQp`]) or the clamped closed form.
//! - R = 0 (the paper's setting) leaves the Hessian only positive semidefinite: a relative
//!   Tikhonov term `MpcConfig::regularization · max_i H_ii` (default 1e-9) is added to its
//!   diagonal, so the optimum is unique and the Cholesky factorisation stable.
//! - On solver failure the controller returns the shifted previous plan clamped to the bounds
//!   ([`SolveStatus::Fallback`]), never NaN; bad input is a typed [`crate::Error`].

pub mod boxqp;
pub mod clarabel_qp;
pub mod closed_form;
pub mod condensed;
pub mod config;
pub mod constraints;
pub mod controller;
pub mod matrix_model;
pub mod qp;

pub use config::{MpcConfig, SolverKind};
pub use controller::{FallbackReason, MpcController, MpcSolution, SolveStatus};
pub use matrix_model::MatrixModel;
pub use qp::{QpOutcome, QpSolver, QpStatus};

#[cfg(test)]
mod tests;
