//! Settings of the Koopman MPC (`MpcConfig`) and the choice of QP solver (`SolverKind`).

use serde::{Deserialize, Serialize};

/// Which solver computes the input plan.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum SolverKind {
    /// The dedicated dense box-constrained QP solver ([`crate::mpc::boxqp::BoxQp`], a dual
    /// active-set method warm-started from the previous solve's working set). Input bounds
    /// only.
    #[default]
    Dedicated,
    /// Clarabel (interior point), for every constraint type: input, input-rate and state bounds.
    Clarabel,
    /// The reference code's baseline: the unconstrained optimum `−H⁻¹q` in closed form, then
    /// clamped to the input bounds. Ignores rate and state bounds.
    ClosedForm,
}

impl SolverKind {
    /// The name used on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            SolverKind::Dedicated => "dedicated",
            SolverKind::Clarabel => "clarabel",
            SolverKind::ClosedForm => "closed-form",
        }
    }
}

/// What the MPC service computes from a lifted-linear model.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum ControlLaw {
    /// The condensed MPC over the horizon (SPEC's).
    #[default]
    Mpc,
    /// The infinite-horizon LQR gain under the same Q and R ([`crate::mpc::lqr_law::LqrLaw`]):
    /// about a plan `u = u_ff,k − K(Φ(x_k) − Φ(r_k))`, clamped to the input bounds. Only the
    /// weights, the bounds and the horizon (the length of the returned plan) apply.
    Lqr,
}

/// Settings of the condensed linear MPC of SPEC.md ("Control").
///
/// Over the horizon H it minimises `Σ_τ (x_{τ+1} − r_τ)ᵀ Q_τ (x_{τ+1} − r_τ) + u_τᵀ R u_τ` with
/// `x = P z`, `z_{τ+1} = A z_τ + B u_τ`, `z_0 = Φ(x)`, subject to the bounds that are set.
/// Weights are diagonal; `None` means the SPEC default. Bounds left `None` are absent.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MpcConfig {
    /// Horizon H (number of planned inputs). SPEC default 15.
    pub horizon: usize,
    /// Diagonal of the state weight Q (nx values); `None` = identity (SPEC).
    pub q: Option<Vec<f64>>,
    /// Diagonal of the input weight R (nu values, ≥ 0); `None` = 0 (SPEC).
    pub r: Option<Vec<f64>>,
    /// Diagonal of the terminal weight on `x_H` (nx values); `None` = Q.
    pub terminal: Option<Vec<f64>>,
    /// The terminal cost is the model's infinite-horizon cost-to-go instead: `(z_H − Φ(r_H))ᵀ P
    /// (z_H − Φ(r_H))` with `P` the discrete Riccati solution of the lifted `(A, B)` under the
    /// same Q (on `x = P z`) and R (in place of the terminal weight, so not with `terminal`).
    /// Unconstrained, the first planned input is then LQR's whatever the horizon: what an
    /// unstable plant needs from a short horizon. Not with the error-state MPC or the
    /// offset-free correction.
    pub terminal_riccati: bool,
    /// Lower input bounds (nu values, may be −∞).
    pub u_min: Option<Vec<f64>>,
    /// Upper input bounds (nu values, may be +∞).
    pub u_max: Option<Vec<f64>>,
    /// Input-rate bounds `|u_τ − u_{τ−1}| ≤ du_max` (nu values, > 0), with `u_{−1}` the input
    /// applied at the previous step (see [`crate::mpc::MpcController::set_previous_input`]).
    /// Needs [`SolverKind::Clarabel`].
    pub du_max: Option<Vec<f64>>,
    /// Lower bounds on the predicted states `x_1..x_H` (nx values, may be −∞). Clarabel only.
    pub x_min: Option<Vec<f64>>,
    /// Upper bounds on the predicted states `x_1..x_H` (nx values, may be +∞). Clarabel only.
    pub x_max: Option<Vec<f64>>,
    /// The QP solver.
    pub solver: SolverKind,
    /// Relative Tikhonov term: `δ = regularization · max_i H_ii` is added to the diagonal of
    /// the Hessian. With R = 0 (the paper's setting) `H = ΓᵀQ̄Γ` is only positive semidefinite
    /// (its rank is at most H·nx, and often numerically lower); the term makes it positive
    /// definite so that the optimum is unique and Cholesky is stable, at the price of a change
    /// of the optimum of relative size ~δ in the well-determined directions and a preference
    /// for small inputs along the directions the cost does not see.
    pub regularization: f64,
    /// Iteration limit of the solver: Clarabel's interior-point iterations; for the dedicated
    /// box solver, working-set changes (one bound added or dropped) per solve. Default 1000
    /// (DAQP's): a cold start of the box solver with 230 inputs, 97% of them on a bound, needs
    /// ~470 changes (the limit was 100 until session 6); warm-started solves need a few.
    pub max_iterations: usize,
    /// Time limit per solve in seconds (`None` = none).
    pub time_limit: Option<f64>,
    /// What to do when the solver fails (infeasible, iteration or time limit without a usable
    /// plan, numerical trouble): `true` returns the shifted previous plan clamped to the input
    /// bounds with [`crate::mpc::SolveStatus::Fallback`]; `false` returns the error.
    pub fallback: bool,
    /// The control law: the MPC (default) or LQR on the same model and weights
    /// ([`ControlLaw`]; a lifted-linear model only).
    pub law: ControlLaw,
}

impl Default for MpcConfig {
    fn default() -> Self {
        MpcConfig {
            horizon: 15,
            q: None,
            r: None,
            terminal: None,
            terminal_riccati: false,
            u_min: None,
            u_max: None,
            du_max: None,
            x_min: None,
            x_max: None,
            solver: SolverKind::Dedicated,
            regularization: 1e-9,
            max_iterations: 1000,
            time_limit: None,
            fallback: true,
            law: ControlLaw::Mpc,
        }
    }
}

impl MpcConfig {
    /// The SPEC defaults with the input bounds of a system (`System::input_bounds`).
    pub fn with_bounds(u_min: Vec<f64>, u_max: Vec<f64>) -> Self {
        MpcConfig {
            u_min: Some(u_min),
            u_max: Some(u_max),
            ..MpcConfig::default()
        }
    }

    /// True if rate or state bounds are set (constraints beyond the input box).
    pub fn has_general_constraints(&self) -> bool {
        self.du_max.is_some() || self.x_min.is_some() || self.x_max.is_some()
    }
}
