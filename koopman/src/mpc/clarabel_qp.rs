//! Clarabel (interior point) behind [`QpSolver`]: `min ½uᵀHu + qᵀu` s.t. `G u ≤ h`, with the
//! problem set up once (presolve off) and only `q` and `h` updated at each step.

use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettings, DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT,
};
use faer::MatRef;

use super::qp::{QpOutcome, QpSolver, QpStatus};
use crate::error::{Error, Result};

/// Clarabel set up for a fixed Hessian `H` and constraint matrix `G`.
pub struct ClarabelQp {
    solver: DefaultSolver<f64>,
    n: usize,
    m: usize,
}

impl ClarabelQp {
    /// Sets up `min ½uᵀHu + qᵀu` s.t. `G u ≤ h` (q and h are given per solve).
    pub fn new(
        h: MatRef<'_, f64>,
        g: MatRef<'_, f64>,
        max_iterations: usize,
        time_limit: Option<f64>,
    ) -> Result<Self> {
        let n = h.nrows();
        if h.ncols() != n {
            return Err(Error::dimension("Hessian columns", n, h.ncols()));
        }
        if g.ncols() != n {
            return Err(Error::dimension("constraint matrix columns", n, g.ncols()));
        }
        let m = g.nrows();
        let p = dense_upper_csc(h);
        let a = dense_csc(g);
        let settings: DefaultSettings<f64> = DefaultSettingsBuilder::default()
            .verbose(false)
            .presolve_enable(false)
            .input_sparse_dropzeros(false)
            .max_iter(max_iterations.min(u32::MAX as usize) as u32)
            .time_limit(time_limit.unwrap_or(f64::INFINITY))
            .tol_gap_abs(1e-13)
            .tol_gap_rel(1e-13)
            .tol_feas(1e-12)
            .tol_ktratio(1e-10)
            .build()
            .map_err(|e| Error::InvalidArgument(format!("Clarabel settings: {e}")))?;
        let cones = if m > 0 {
            vec![SupportedConeT::NonnegativeConeT(m)]
        } else {
            vec![]
        };
        let solver = DefaultSolver::new(&p, &vec![0.0; n], &a, &vec![0.0; m], &cones, settings)
            .map_err(|e| Error::InvalidArgument(format!("Clarabel set-up: {e}")))?;
        if !solver.is_data_update_allowed() {
            return Err(Error::Numerical(
                "Clarabel does not allow data updates (presolve active)".into(),
            ));
        }
        Ok(ClarabelQp { solver, n, m })
    }

    /// Number of constraint rows.
    pub fn n_constraints(&self) -> usize {
        self.m
    }
}

impl QpSolver for ClarabelQp {
    fn name(&self) -> &'static str {
        "clarabel"
    }

    fn solve(&mut self, q: &[f64], h: &[f64], u: &mut [f64]) -> QpOutcome {
        let fail = |status| QpOutcome {
            status,
            iterations: 0,
            feasible_iterate: false,
        };
        if q.len() != self.n || h.len() != self.m || u.len() != self.n {
            return fail(QpStatus::Numerical);
        }
        if self.solver.update_q(&q.to_vec()).is_err()
            || (self.m > 0 && self.solver.update_b(&h.to_vec()).is_err())
        {
            return fail(QpStatus::Numerical);
        }
        self.solver.solve();
        let sol = &self.solver.solution;
        let status = match sol.status {
            SolverStatus::Solved => QpStatus::Solved,
            SolverStatus::AlmostSolved => QpStatus::Inaccurate,
            SolverStatus::PrimalInfeasible | SolverStatus::AlmostPrimalInfeasible => {
                QpStatus::Infeasible
            }
            SolverStatus::MaxIterations => QpStatus::MaxIterations,
            SolverStatus::MaxTime => QpStatus::TimeLimit,
            _ => QpStatus::Numerical,
        };
        if matches!(status, QpStatus::Solved | QpStatus::Inaccurate) {
            u.copy_from_slice(&sol.x);
        }
        QpOutcome {
            status,
            iterations: sol.iterations as usize,
            feasible_iterate: false,
        }
    }
}

/// The upper triangle of a dense symmetric matrix in CSC form (zeros kept as structure so
/// that later value updates keep the pattern).
fn dense_upper_csc(h: MatRef<'_, f64>) -> CscMatrix<f64> {
    let n = h.nrows();
    let mut colptr = Vec::with_capacity(n + 1);
    let mut rowval = Vec::with_capacity(n * (n + 1) / 2);
    let mut nzval = Vec::with_capacity(n * (n + 1) / 2);
    colptr.push(0);
    for j in 0..n {
        for i in 0..=j {
            rowval.push(i);
            nzval.push(h[(i, j)]);
        }
        colptr.push(rowval.len());
    }
    CscMatrix::new(n, n, colptr, rowval, nzval)
}

/// A dense matrix in CSC form, exact zeros dropped (the pattern of G never changes).
fn dense_csc(g: MatRef<'_, f64>) -> CscMatrix<f64> {
    let (m, n) = (g.nrows(), g.ncols());
    let mut colptr = Vec::with_capacity(n + 1);
    let mut rowval = Vec::new();
    let mut nzval = Vec::new();
    colptr.push(0);
    for j in 0..n {
        for i in 0..m {
            let v = g[(i, j)];
            if v != 0.0 {
                rowval.push(i);
                nzval.push(v);
            }
        }
        colptr.push(rowval.len());
    }
    CscMatrix::new(m, n, colptr, rowval, nzval)
}
