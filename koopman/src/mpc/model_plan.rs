//! What a served controller's solve returns, whatever the controller ([`ModelPlan`]): the input
//! plan and how it was obtained.

use std::time::Duration;

/// How a [`ModelPlan`] was obtained, whatever the controller.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlanStatus {
    /// Optimal within the solver's tolerances (a converged linearisation for bilinear MPC;
    /// always for random shooting).
    Solved,
    /// Optimal to reduced accuracy.
    Inaccurate,
    /// Feasible but not proven optimal (an iteration or time limit, or a linearisation cap).
    Suboptimal,
    /// The solver failed; the plan is the shifted previous one clamped to the bounds.
    Fallback,
}

/// What one solve returns.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelPlan {
    /// The input plan, H·nu values, first input first (always finite).
    pub u: Vec<f64>,
    /// How it was obtained.
    pub status: PlanStatus,
    /// QP iterations (summed over linearisations for the bilinear MPC; samples for shooting).
    pub iterations: usize,
    /// Solve wall time.
    pub solve_time: Duration,
}
