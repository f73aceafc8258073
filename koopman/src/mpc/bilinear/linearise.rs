//! The linearisation step of the sequential convex MPC: the bilinear model rolled out along a
//! nominal plan (`z̄_τ`, `A_τ = A + Σ ū_{τ,i} N_i`) and the time-varying condensed QP built
//! around it (`B_τ = B + [N_1 z̄_τ … N_nu z̄_τ]`, `H = ΓᵀQ̄Γ + R̄ + δI`, `q`).

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};

use super::BilinearMpc;
use crate::mpc::condensed::gemv_acc;

impl BilinearMpc<'_> {
    /// Rolls the bilinear model out along `u` (z̄ and A_τ into the workspace, plus the offset-free
    /// disturbance on the state part of each step when it is on) and returns the plan's cost
    /// (∞ when the rollout is not finite).
    pub(super) fn rollout(&mut self, z0: &[f64], u: &[f64]) -> f64 {
        let (nn, nu, nx) = (self.nn, self.nu, self.nx);
        self.zbar[..nn].copy_from_slice(z0);
        let mut cost = 0.0;
        for t in 0..self.hz {
            let ut = &u[t * nu..(t + 1) * nu];
            let at = &mut self.at[t * nn * nn..(t + 1) * nn * nn];
            at.copy_from_slice(&self.a);
            for (i, &ui) in ut.iter().enumerate() {
                if ui != 0.0 {
                    let ni = &self.n[i * nn * nn..(i + 1) * nn * nn];
                    for (x, &y) in at.iter_mut().zip(ni) {
                        *x += ui * y;
                    }
                }
            }
            let (cur, next) = self.zbar.split_at_mut((t + 1) * nn);
            let (cur, next) = (&cur[t * nn..], &mut next[..nn]);
            next.fill(0.0);
            gemv_acc(MatRef::from_column_major_slice(at, nn, nn), cur, next);
            gemv_acc(MatRef::from_column_major_slice(&self.b, nn, nu), ut, next);
            if let Some(d) = self.offset.as_ref().and_then(|o| o.disturbance()) {
                for (v, di) in next.iter_mut().zip(d) {
                    *v += di;
                }
            }
            for (i, &v) in next[..nx].iter().enumerate() {
                let d = v - self.r[t * nx + i];
                cost += self.qbar[t * nx + i] * d * d;
            }
            for (i, &ui) in ut.iter().enumerate() {
                cost += self.rbar[t * nu + i] * ui * ui;
            }
        }
        if cost.is_finite() {
            cost
        } else {
            f64::INFINITY
        }
    }

    /// Builds `H` (into the solver) and `q` of the linearisation along `ubar`; needs the
    /// rollout of `ubar` in the workspace. Returns false (and leaves the solver's Hessian as it
    /// was) when `H` or `q` is not finite.
    pub(super) fn build_qp(&mut self, ubar: &[f64]) -> bool {
        let (nn, nu, nx, hz) = (self.nn, self.nu, self.nx, self.hz);
        // B_τ = B + [N_i z̄_τ].
        for t in 0..hz {
            let bt = &mut self.bt[t * nn * nu..(t + 1) * nn * nu];
            bt.copy_from_slice(&self.b);
            let z = &self.zbar[t * nn..(t + 1) * nn];
            for i in 0..nu {
                gemv_acc(
                    MatRef::from_column_major_slice(
                        &self.n[i * nn * nn..(i + 1) * nn * nn],
                        nn,
                        nn,
                    ),
                    z,
                    &mut bt[i * nn..(i + 1) * nn],
                );
            }
        }
        // Γ column block j: S = B_j, then S ← A_{τ+1} S; block (τ, j) = P S.
        for j in 0..hz {
            self.s
                .copy_from_slice(&self.bt[j * nn * nu..(j + 1) * nn * nu]);
            for t in j..hz {
                for k in 0..nu {
                    for i in 0..nx {
                        self.gamma[(t * nx + i, j * nu + k)] = self.s[k * nn + i];
                    }
                }
                if t + 1 < hz {
                    matmul(
                        MatMut::from_column_major_slice_mut(&mut self.s2, nn, nu),
                        Accum::Replace,
                        MatRef::from_column_major_slice(
                            &self.at[(t + 1) * nn * nn..(t + 2) * nn * nn],
                            nn,
                            nn,
                        ),
                        MatRef::from_column_major_slice(&self.s, nn, nu),
                        1.0,
                        Par::Seq,
                    );
                    std::mem::swap(&mut self.s, &mut self.s2);
                }
            }
            for t in 0..j {
                for k in 0..nu {
                    for i in 0..nx {
                        self.gamma[(t * nx + i, j * nu + k)] = 0.0;
                    }
                }
            }
        }
        // X̄ − ΓŪ − r.
        for t in 0..hz {
            for i in 0..nx {
                self.xfree[t * nx + i] = self.zbar[(t + 1) * nn + i] - self.r[t * nx + i];
            }
        }
        for v in self.xfree.iter_mut() {
            *v = -*v;
        }
        gemv_acc(self.gamma.as_ref(), ubar, &mut self.xfree);
        for v in self.xfree.iter_mut() {
            *v = -*v;
        }
        let nv = hz * nu;
        for c in 0..nv {
            for r in 0..hz * nx {
                self.wq[(r, c)] = self.qbar[r] * self.gamma[(r, c)];
            }
        }
        matmul(
            self.hess.as_mut(),
            Accum::Replace,
            self.gamma.transpose(),
            self.wq.as_ref(),
            1.0,
            Par::Seq,
        );
        for i in 0..nv {
            self.hess[(i, i)] += self.rbar[i];
            for j in 0..i {
                let v = 0.5 * (self.hess[(i, j)] + self.hess[(j, i)]);
                self.hess[(i, j)] = v;
                self.hess[(j, i)] = v;
            }
        }
        let max_diag = (0..nv).map(|i| self.hess[(i, i)]).fold(0.0f64, f64::max);
        let delta = if max_diag > 0.0 {
            self.cfg.regularization * max_diag
        } else {
            self.cfg.regularization.max(f64::MIN_POSITIVE)
        };
        for i in 0..nv {
            self.hess[(i, i)] += delta;
        }
        for c in 0..nv {
            self.q[c] = (0..hz * nx).map(|r| self.wq[(r, c)] * self.xfree[r]).sum();
        }
        let finite = self.q.iter().all(|v| v.is_finite())
            && (0..nv).all(|c| (0..nv).all(|r| self.hess[(r, c)].is_finite()));
        finite && self.solver.set_hessian(self.hess.as_ref()).is_ok()
    }
}
