//! Linear MPC on lifted (Koopman) models: the condensed QP of SPEC.md ("Control"), its two
//! solvers, the baselines (closed form + clamping, LQR, random shooting) and closed-loop
//! evaluation on the reference systems.
//!
//! - [`MpcController`] (built once per model and [`MpcConfig`]) plans with
//!   [`MpcController::solve`] (or, along a planned trajectory with its feed-forward inputs,
//!   the error-state [`MpcController::solve_about_plan`]); [`SolverKind`] picks the dedicated box-QP solver
//!   ([`boxqp::BoxQp`]), Clarabel ([`clarabel_qp::ClarabelQp`]) or the clamped closed form.
//! - R = 0 (the paper's setting) leaves the Hessian only positive semidefinite: a relative
//!   Tikhonov term `MpcConfig::regularization · max_i H_ii` (default 1e-9) is added to its
//!   diagonal, so the optimum is unique and the Cholesky factorisation stable.
//! - Baselines: [`SolverKind::ClosedForm`] (unconstrained optimum, clamped), [`Lqr`] with
//!   feed-forward on the lifted model, [`RandomShooting`] on any [`OneStepModel`]; every
//!   controller is a [`Policy`] that [`run_closed_loop`] evaluates on a reference system;
//!   [`controllers::build`] makes any of them by [`controllers::ControllerKind`].
//! - [`BilinearMpc`]: sequential convex MPC on a bilinear model (`z⁺ = A z + B u + Σ u_i N_i z`),
//!   re-linearised along each new plan (at most [`ScpOptions::max_linearisations`] QPs on the
//!   dedicated box solver); [`ScpStatus`] says whether it converged. [`OffsetFreeConfig`]
//!   switches on an offset-free correction near the target (disturbance estimate or integral).
//! - On solver failure the controller returns the shifted previous plan clamped to the bounds
//!   ([`SolveStatus::Fallback`]), never NaN; bad input is a typed [`crate::Error`].
//! - [`served`]: a saved model directory + [`MpcConfig`] → [`ModelController`], the one path from
//!   "model + settings" to a command shared by the MPC service and the exported FMU.

pub mod bilinear;
pub mod boxqp;
pub mod clarabel_qp;
pub mod closed_form;
pub mod closed_loop;
pub mod condensed;
pub mod config;
pub mod constraints;
pub mod controller;
pub mod controllers;
pub mod lqr;
pub mod lqr_law;
pub mod metrics;
mod model_plan;
pub mod offset_free;
pub mod policy;
pub mod qp;
pub mod served;
pub mod shooting;

pub use bilinear::{BilinearMpc, BilinearSolution, ScpOptions, ScpStatus};
pub use closed_loop::{run_closed_loop, ClosedLoopMetrics, Task, TaskKind, Trajectory};
pub use config::{ControlLaw, MpcConfig, SolverKind};
pub use controller::{FallbackReason, MpcController, MpcSolution, SolveStatus};
pub use lqr::Lqr;
pub use offset_free::{OffsetFree, OffsetFreeConfig, OffsetMode};
pub use policy::{Action, ConstantPolicy, LqrPolicy, Policy, ShootingPolicy};
pub use qp::{QpOutcome, QpSolver, QpStatus};
pub use served::{LoadedModel, ModelController, ModelPlan, PlanStatus, AUTONOMOUS_MPC};
pub use shooting::{OneStepModel, RandomShooting, SystemAsModel};

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_closed_loop;
#[cfg(test)]
mod tests_error_state;
#[cfg(test)]
mod tests_error_state_offset;
#[cfg(test)]
mod tests_lqr_law;
#[cfg(test)]
mod tests_terminal;
