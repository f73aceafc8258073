//! The box solver's iteration: the first working set from the warm start, then the dual
//! active-set steps (drop a bound whose multiplier reaches zero, or add the most violated one),
//! and the best feasible point when a limit stops it early.

use std::time::Instant;

use super::{BoxQp, Side, WarmStart, NONE};
use crate::linalg::kernels::{dot, gather_gemv};
use crate::mpc::condensed::gemv_acc;
use crate::mpc::qp::{QpOutcome, QpStatus};

impl BoxQp {
    /// `u = u* − H⁻¹[:, W] μ` with the working set exactly on its bounds.
    #[inline(always)]
    fn primal(&mut self, u: &mut [f64]) {
        u.copy_from_slice(&self.ustar);
        let m = self.ws.len();
        for (r, mu) in self.row.iter_mut().zip(&self.mu) {
            *r = -mu;
        }
        gather_gemv(&self.hinv, &self.ws, &self.row[..m], u);
        for &i in &self.ws {
            u[i] = self.bound(i);
        }
    }

    /// At an iteration or time limit: the best point on the segment from the warm start `u0` to
    /// the current iterate clamped to the box (feasible, and no worse than the warm start).
    fn stopped_early(&mut self, u: &mut [f64]) {
        self.primal(u);
        for (i, v) in u.iter_mut().enumerate() {
            *v = v.clamp(self.lo[i], self.hi[i]);
        }
        // d = c − u0 (in u); f(u0 + t d) = f(u0) + t gᵀd + ½ t² dᵀHd, g = H u0 + q
        // = H (u0 − u*).
        for (ui, u0) in u.iter_mut().zip(&self.u0) {
            *ui -= u0;
        }
        for ((d, u0), s) in self.mustar.iter_mut().zip(&self.u0).zip(&self.ustar) {
            *d = u0 - s;
        }
        self.g.fill(0.0);
        gemv_acc(self.h.as_ref(), &self.mustar, &mut self.g);
        self.hd.fill(0.0);
        gemv_acc(self.h.as_ref(), u, &mut self.hd);
        let gd: f64 = self.g.iter().zip(u.iter()).map(|(a, b)| a * b).sum();
        let dhd: f64 = self.hd.iter().zip(u.iter()).map(|(a, b)| a * b).sum();
        let t = if dhd > 0.0 && gd < 0.0 {
            (-gd / dhd).min(1.0)
        } else {
            0.0
        };
        for (i, (ui, u0)) in u.iter_mut().zip(&self.u0).enumerate() {
            *ui = (u0 + t * *ui).clamp(self.lo[i], self.hi[i]);
        }
    }

    /// The solve from `u*` in place: the first working set, then the iteration.
    // Index loops over several parallel arrays (u, bounds, sides) read best here.
    #[allow(clippy::needless_range_loop)]
    #[inline(always)]
    pub(super) fn run(&mut self, u: &mut [f64], start: Option<Instant>) -> QpOutcome {
        let n = self.n;
        let outcome = |status, iterations, feasible_iterate| QpOutcome {
            status,
            iterations,
            feasible_iterate,
        };
        if self.warm_start == WarmStart::Previous
            && self.has_previous
            && self.chol_valid
            && self.edits <= 4 * n
        {
            // The working set and its factor are where the last solve left them.
            for i in 0..n {
                let v = if u[i].is_finite() { u[i] } else { 0.0 };
                u[i] = v.clamp(self.lo[i], self.hi[i]);
                self.u0[i] = u[i];
            }
            self.mu.clear();
            self.mu.resize(self.ws.len(), 0.0);
            self.has_previous = false;
            let out = self.iterate(u, start);
            self.has_previous = out.status != QpStatus::Numerical;
            return out;
        }
        // Warm start: feasible, and the bounds it sits on are the first working set.
        let mut warm = false;
        for i in 0..n {
            let v = if u[i].is_finite() { u[i] } else { 0.0 };
            u[i] = v.clamp(self.lo[i], self.hi[i]);
            self.u0[i] = u[i];
            self.want[i] = if self.lo[i] == self.hi[i] {
                Side::Fixed
            } else if u[i] == self.hi[i] {
                Side::Upper
            } else if u[i] == self.lo[i] {
                Side::Lower
            } else {
                Side::Free
            };
            warm |= matches!(self.want[i], Side::Upper | Side::Lower);
        }
        let shift = match self.warm_start {
            WarmStart::Point => None,
            WarmStart::Previous => Some(0),
            WarmStart::Shifted(s) => Some(s),
        };
        if let (Some(shift), true) = (shift, self.has_previous) {
            self.previous_working_set(shift);
            warm = self
                .want
                .iter()
                .any(|s| matches!(s, Side::Upper | Side::Lower));
        }
        self.has_previous = false;
        if !warm {
            // Cold: the bounds the unconstrained optimum violates.
            for i in 0..n {
                if self.want[i] == Side::Free {
                    if self.ustar[i] > self.hi[i] {
                        self.want[i] = Side::Upper;
                    } else if self.ustar[i] < self.lo[i] {
                        self.want[i] = Side::Lower;
                    }
                }
            }
        }
        if !self.set_working_set() {
            return outcome(QpStatus::Numerical, 0, false);
        }
        let out = self.iterate(u, start);
        // Every end but a numerical failure leaves a usable working set for the next solve.
        self.has_previous = out.status != QpStatus::Numerical;
        out
    }

    /// The dual active-set iteration from the working set in place.
    // Index loops over several parallel arrays (u, bounds, sides) read best here.
    #[allow(clippy::needless_range_loop)]
    #[inline(always)]
    fn iterate(&mut self, u: &mut [f64], start: Option<Instant>) -> QpOutcome {
        let n = self.n;
        let outcome = |status, iterations, feasible_iterate| QpOutcome {
            status,
            iterations,
            feasible_iterate,
        };
        let bscale = self.bscale;
        let tol = 1e-12 * bscale;
        let (mut its, mut last_added, mut tabu) = (0usize, NONE, NONE);
        // y = L⁻¹(u*_W − b_W) once; the edits below keep it current.
        self.y.clear();
        for k in 0..self.ws.len() {
            let i = self.ws[k];
            self.y.push(self.ustar[i] - self.bound(i));
        }
        self.chol.forward_in_place(&mut self.y);
        loop {
            let limit = if its >= self.max_iterations {
                Some(QpStatus::MaxIterations)
            } else if start.is_some_and(|t| Some(t.elapsed()) > self.time_limit) {
                Some(QpStatus::TimeLimit)
            } else {
                None
            };
            // μ* = L⁻ᵀ y of the working set.
            let m = self.ws.len();
            self.mustar[..m].copy_from_slice(&self.y);
            self.chol.backward_in_place(&mut self.mustar[..m]);
            if self.mustar[..m].iter().any(|v| !v.is_finite()) {
                return outcome(QpStatus::Numerical, its, false);
            }
            let mtol = 1e-13 * (1.0 + self.mustar[..m].iter().fold(0.0f64, |a, v| a.max(v.abs())));
            // The first multiplier to reach zero on the way to μ*; among ties (several at zero
            // already, as after a warm start) the one furthest on the wrong side.
            let (mut alpha, mut block, mut worst_dual) = (1.0f64, NONE, 0.0f64);
            for k in 0..m {
                let s = match self.side[self.ws[k]] {
                    Side::Upper => 1.0,
                    Side::Lower => -1.0,
                    _ => continue,
                };
                let (sm, sms) = (s * self.mu[k], s * self.mustar[k]);
                if sms < -mtol {
                    let a = (sm / (sm - sms)).max(0.0);
                    if a < alpha || (a == alpha && sms < worst_dual) {
                        (alpha, block, worst_dual) = (a, k, sms);
                    }
                }
            }
            if block != NONE {
                if let Some(status) = limit {
                    self.stopped_early(u);
                    return outcome(status, its, true);
                }
                for k in 0..m {
                    self.mu[k] += alpha * (self.mustar[k] - self.mu[k]);
                }
                if self.ws[block] == last_added && alpha <= 0.0 {
                    // The bound just added is dropped again at once: its violation is at
                    // rounding level; do not add it again (Lawson–Hanson's guard).
                    tabu = last_added;
                }
                self.drop_at(block);
                its += 1;
                continue;
            }
            self.mu[..m].copy_from_slice(&self.mustar[..m]);
            self.primal(u);
            // The most violated bound among the free variables.
            let (mut worst, mut j, mut side) = (tol, NONE, Side::Free);
            for i in 0..n {
                if self.side[i] != Side::Free || i == tabu {
                    continue;
                }
                if u[i] - self.hi[i] > worst {
                    (worst, j, side) = (u[i] - self.hi[i], i, Side::Upper);
                } else if self.lo[i] - u[i] > worst {
                    (worst, j, side) = (self.lo[i] - u[i], i, Side::Lower);
                }
            }
            if j == NONE {
                let stuck = tabu != NONE
                    && (u[tabu] - self.hi[tabu]).max(self.lo[tabu] - u[tabu]) > 1e-6 * bscale;
                for i in 0..n {
                    u[i] = u[i].clamp(self.lo[i], self.hi[i]);
                }
                let status = if stuck || u.iter().any(|v| !v.is_finite()) {
                    QpStatus::Numerical
                } else {
                    QpStatus::Solved
                };
                return outcome(status, its, true);
            }
            if let Some(status) = limit {
                self.stopped_early(u);
                return outcome(status, its, true);
            }
            if !self.add(j, side) {
                self.chol_valid = false;
                return outcome(QpStatus::Numerical, its, false);
            }
            // The new entry of y from the new row [r d] of L: (c_j − r·y) / d.
            let row = self.chol.row(m);
            let yj = (self.ustar[j] - self.bound(j) - dot(&row[..m], &self.y)) / row[m];
            self.y.push(yj);
            if j != tabu {
                tabu = NONE;
            }
            last_added = j;
            its += 1;
        }
    }
}
