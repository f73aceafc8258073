//! The interface shared by the QP solvers: `min ½uᵀHu + qᵀu` subject to the solver's constraints.

/// How a QP solve ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum QpStatus {
    /// Optimal within the solver's tolerances.
    Solved,
    /// Optimal to a reduced accuracy (Clarabel's `AlmostSolved`).
    Inaccurate,
    /// The iteration limit was reached.
    MaxIterations,
    /// The time limit was reached.
    TimeLimit,
    /// The constraints admit no solution.
    Infeasible,
    /// The solver failed numerically.
    Numerical,
}

/// The result of one QP solve.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct QpOutcome {
    /// How it ended.
    pub status: QpStatus,
    /// Solver iterations used.
    pub iterations: usize,
    /// True if the returned point satisfies the constraints even though the status is not
    /// `Solved` (the dedicated solver's iterates are always feasible).
    pub feasible_iterate: bool,
}

/// A QP solver with fixed Hessian and constraint matrix; only the linear term `q` and the
/// constraint right-hand side `h` change from step to step.
pub trait QpSolver: Send {
    /// Short name for reports (`dedicated`, `clarabel`, `closed-form`).
    fn name(&self) -> &'static str;
    /// Solves for the linear term `q` and right-hand side `h` (ignored by solvers whose
    /// constraints are fixed). On entry `u` holds the warm start; on exit, the solution.
    fn solve(&mut self, q: &[f64], h: &[f64], u: &mut [f64]) -> QpOutcome;
    /// Forgets what earlier solves left for warm starts (a new episode); a no-op by default.
    fn reset(&mut self) {}
}
