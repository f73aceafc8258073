//! The reference code's baseline: the unconstrained optimum `u = −H⁻¹q` in closed form (one
//! cached Cholesky factorisation), then clamped to the input bounds.

use faer::linalg::solvers::{Llt, Solve};
use faer::{ColMut, MatRef, Side};

use super::qp::{QpOutcome, QpSolver, QpStatus};
use crate::error::{Error, Result};

/// Unconstrained closed-form MPC followed by clamping (not optimal when a bound is active).
pub struct ClampedClosedForm {
    llt: Llt<f64>,
    lo: Vec<f64>,
    hi: Vec<f64>,
}

impl ClampedClosedForm {
    /// Factorises `h` once; `lo`/`hi` are the per-variable clamping bounds.
    pub fn new(h: MatRef<'_, f64>, lo: &[f64], hi: &[f64]) -> Result<Self> {
        let n = h.nrows();
        if lo.len() != n || hi.len() != n {
            return Err(Error::dimension("box bounds", n, lo.len().min(hi.len())));
        }
        let llt = h.llt(Side::Lower).map_err(|_| {
            Error::Numerical(
                "the MPC Hessian is not positive definite; increase R or the regularization".into(),
            )
        })?;
        Ok(ClampedClosedForm {
            llt,
            lo: lo.to_vec(),
            hi: hi.to_vec(),
        })
    }
}

impl QpSolver for ClampedClosedForm {
    fn name(&self) -> &'static str {
        "closed-form"
    }

    fn solve(&mut self, q: &[f64], _h: &[f64], u: &mut [f64]) -> QpOutcome {
        if q.len() != self.lo.len() || u.len() != self.lo.len() {
            return QpOutcome {
                status: QpStatus::Numerical,
                iterations: 0,
                feasible_iterate: false,
            };
        }
        for (ui, qi) in u.iter_mut().zip(q) {
            *ui = -qi;
        }
        self.llt.solve_in_place(ColMut::from_slice_mut(u));
        let finite = u.iter().all(|v| v.is_finite());
        for (i, ui) in u.iter_mut().enumerate() {
            *ui = ui.clamp(self.lo[i], self.hi[i]);
        }
        QpOutcome {
            status: if finite {
                QpStatus::Solved
            } else {
                QpStatus::Numerical
            },
            iterations: 1,
            feasible_iterate: finite,
        }
    }
}
