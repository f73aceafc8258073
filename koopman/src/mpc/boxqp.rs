//! The dedicated dense solver for `min ½uᵀHu + qᵀu` s.t. `lo ≤ u ≤ hi`: projected Newton with a
//! cached Cholesky factorisation of the free block of H, warm-started by the caller.

use std::time::{Duration, Instant};

use faer::{Mat, MatRef, Side};

use super::condensed::gemv_acc;
use super::qp::{QpOutcome, QpSolver, QpStatus};
use crate::error::{Error, Result};
use crate::linalg::SmallCholesky;

/// Projected Newton (Bertsekas 1982) for a strictly convex box-constrained QP.
///
/// Each iteration fixes the variables that sit on a bound with the gradient pushing outwards
/// (the ε-active set), takes the Newton step on the others (`H_FF d_F = −g_F`, solved with a
/// Cholesky factorisation that is reused as long as the free set does not change — in steady
/// receding-horizon operation it rarely does), projects onto the box and backtracks (Armijo
/// along the projection arc). Every iterate is feasible and the cost decreases monotonically;
/// once the right active set is found the step is exact, so it stops on the KKT conditions to
/// rounding accuracy (projected gradient ≤ `tol`).
pub struct BoxQp {
    n: usize,
    h: Mat<f64>,
    lo: Vec<f64>,
    hi: Vec<f64>,
    max_iterations: usize,
    time_limit: Option<Duration>,
    /// Absolute KKT tolerance on the projected gradient, scaled by the problem's size.
    rel_tol: f64,
    // Cached factorisation of H_FF for the free set `cached_free`.
    cached_free: Vec<usize>,
    chol: SmallCholesky,
    chol_valid: bool,
    // Workspace.
    g: Vec<f64>,
    d: Vec<f64>,
    rhs: Vec<f64>,
    trial: Vec<f64>,
    step: Vec<f64>,
    hs: Vec<f64>,
    free: Vec<usize>,
}

impl BoxQp {
    /// A solver for the Hessian `h` (symmetric positive definite) and the box `[lo, hi]`.
    pub fn new(
        h: MatRef<'_, f64>,
        lo: &[f64],
        hi: &[f64],
        max_iterations: usize,
        time_limit: Option<f64>,
    ) -> Result<Self> {
        let n = h.nrows();
        if h.ncols() != n {
            return Err(Error::dimension("Hessian columns", n, h.ncols()));
        }
        if lo.len() != n || hi.len() != n {
            return Err(Error::dimension("box bounds", n, lo.len().min(hi.len())));
        }
        if let Some(i) = (0..n).find(|&i| lo[i].is_nan() || hi[i].is_nan() || lo[i] > hi[i]) {
            return Err(Error::InvalidArgument(format!(
                "box bound {i} is empty or NaN: [{}, {}]",
                lo[i], hi[i]
            )));
        }
        if max_iterations == 0 {
            return Err(Error::InvalidArgument("max_iterations must be ≥ 1".into()));
        }
        let h = h.to_owned();
        // faer's factorisation (blocked, fast for large n) checks definiteness once up front.
        h.llt(Side::Lower).map_err(|_| {
            Error::Numerical(
                "the MPC Hessian is not positive definite; increase R or the regularization".into(),
            )
        })?;
        Ok(BoxQp {
            n,
            h,
            lo: lo.to_vec(),
            hi: hi.to_vec(),
            max_iterations,
            time_limit: time_limit.map(Duration::from_secs_f64),
            rel_tol: 1e-11,
            cached_free: Vec::new(),
            chol: SmallCholesky::default(),
            chol_valid: false,
            g: vec![0.0; n],
            d: vec![0.0; n],
            rhs: vec![0.0; n],
            trial: vec![0.0; n],
            step: vec![0.0; n],
            hs: vec![0.0; n],
            free: Vec::with_capacity(n),
        })
    }

    /// Number of variables.
    pub fn n(&self) -> usize {
        self.n
    }

    /// Replaces the Hessian (same size, symmetric positive definite) for the next solves, as a
    /// time-varying QP needs; copies into the existing buffer and drops the cached factor.
    pub fn set_hessian(&mut self, h: MatRef<'_, f64>) -> Result<()> {
        if h.nrows() != self.n || h.ncols() != self.n {
            return Err(Error::dimension("Hessian rows", self.n, h.nrows()));
        }
        self.h.copy_from(h);
        self.chol_valid = false;
        Ok(())
    }

    fn gradient(&mut self, q: &[f64], u: &[f64]) {
        self.g.copy_from_slice(q);
        gemv_acc(self.h.as_ref(), u, &mut self.g);
    }

    /// Factorises `H_FF` for the current free set unless the cached factor already is for it.
    fn factor_free(&mut self) -> bool {
        if self.chol_valid && self.cached_free == self.free {
            return true;
        }
        let (f, h) = (&self.free, &self.h);
        self.chol_valid = self.chol.factor(f.len(), |i, j| h[(f[i], f[j])]);
        self.cached_free.clone_from(&self.free);
        self.chol_valid
    }
}

impl QpSolver for BoxQp {
    fn name(&self) -> &'static str {
        "dedicated"
    }

    // Index loops over several parallel arrays (u, g, d, bounds) read best here.
    #[allow(clippy::needless_range_loop)]
    fn solve(&mut self, q: &[f64], _h: &[f64], u: &mut [f64]) -> QpOutcome {
        let start = Instant::now();
        let n = self.n;
        if q.len() != n || u.len() != n {
            return QpOutcome {
                status: QpStatus::Numerical,
                iterations: 0,
                feasible_iterate: false,
            };
        }
        for i in 0..n {
            let v = if u[i].is_finite() { u[i] } else { 0.0 };
            u[i] = v.clamp(self.lo[i], self.hi[i]);
        }
        let scale = 1.0
            + q.iter().fold(0.0f64, |m, v| m.max(v.abs()))
            + (0..n).fold(0.0f64, |m, i| m.max(self.h[(i, i)]))
                * u.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let tol = self.rel_tol * scale;
        let outcome = |status, iterations| QpOutcome {
            status,
            iterations,
            feasible_iterate: true,
        };
        for it in 0..self.max_iterations {
            self.gradient(q, u);
            // Projected gradient and the ε-active set.
            let mut pg = 0.0f64;
            for i in 0..n {
                let p = u[i] - (u[i] - self.g[i]).clamp(self.lo[i], self.hi[i]);
                pg = pg.max(p.abs());
            }
            if !pg.is_finite() {
                return outcome(QpStatus::Numerical, it);
            }
            if pg <= tol {
                return outcome(QpStatus::Solved, it);
            }
            if let Some(limit) = self.time_limit {
                if start.elapsed() > limit {
                    return outcome(QpStatus::TimeLimit, it);
                }
            }
            let eps = pg.min(1e-3 * (1.0 + u.iter().fold(0.0f64, |m, v| m.max(v.abs()))));
            self.free.clear();
            for i in 0..n {
                let at_lo = u[i] <= self.lo[i] + eps && self.g[i] > 0.0;
                let at_hi = u[i] >= self.hi[i] - eps && self.g[i] < 0.0;
                if !(at_lo || at_hi) {
                    self.free.push(i);
                }
            }
            // Direction: Newton on the free set, scaled gradient on the active set.
            for i in 0..n {
                self.d[i] = -self.g[i] / self.h[(i, i)];
            }
            if !self.free.is_empty() {
                if !self.factor_free() {
                    return outcome(QpStatus::Numerical, it);
                }
                let nf = self.free.len();
                for (k, &i) in self.free.iter().enumerate() {
                    self.rhs[k] = -self.g[i];
                }
                self.chol.solve_in_place(&mut self.rhs[..nf]);
                for (k, &i) in self.free.iter().enumerate() {
                    self.d[i] = self.rhs[k];
                }
            }
            // Armijo backtracking along the projection arc.
            let sigma = 1e-4;
            let mut alpha = 1.0;
            let mut accepted = false;
            for _ in 0..40 {
                let mut decrease_bound = 0.0;
                let mut fi = 0;
                for i in 0..n {
                    self.trial[i] = (u[i] + alpha * self.d[i]).clamp(self.lo[i], self.hi[i]);
                    self.step[i] = self.trial[i] - u[i];
                    let is_free = fi < self.free.len() && self.free[fi] == i;
                    if is_free {
                        fi += 1;
                        decrease_bound += -alpha * self.g[i] * self.d[i];
                    } else {
                        decrease_bound += self.g[i] * (u[i] - self.trial[i]);
                    }
                }
                self.hs.fill(0.0);
                gemv_acc(self.h.as_ref(), &self.step, &mut self.hs);
                let mut df = 0.0;
                for i in 0..n {
                    df += self.step[i] * (self.g[i] + 0.5 * self.hs[i]);
                }
                if df <= -sigma * decrease_bound || self.step.iter().all(|s| *s == 0.0) {
                    accepted = true;
                    break;
                }
                alpha *= 0.5;
            }
            if !accepted {
                // No decrease is possible at rounding level: the point is optimal as far as
                // arithmetic can tell, or the problem is numerically broken.
                return outcome(
                    if pg <= 1e3 * tol {
                        QpStatus::Solved
                    } else {
                        QpStatus::Numerical
                    },
                    it + 1,
                );
            }
            u.copy_from_slice(&self.trial);
        }
        self.gradient(q, u);
        let pg = (0..n)
            .map(|i| (u[i] - (u[i] - self.g[i]).clamp(self.lo[i], self.hi[i])).abs())
            .fold(0.0f64, f64::max);
        outcome(
            if pg <= tol {
                QpStatus::Solved
            } else {
                QpStatus::MaxIterations
            },
            self.max_iterations,
        )
    }
}
