//! The bilinear terms of the training losses (`z⁺ = A z + B u + Σ_i u_i N_i z`): the extra term
//! of the prediction rollout and of its adjoint, the gradient w.r.t. the N_i, and the
//! inverse-control loss with each sample's own input matrix `B(z) = B + [N_1 z … N_nu z]`.
//!
//! The N_i (N × N each, row-major, one after the other) follow the linear model's parameters in
//! the flat vector, so Adam, clipping and checkpoints see one vector as before.

use crate::model::arch::Arch;
use crate::model::encoder::{view, view_mut};
use crate::model::scalar::Real;
use crate::{Error, Result};
use faer::linalg::matmul::matmul;
use faer::reborrow::{Reborrow, ReborrowMut};
use faer::{Accum, MatMut, MatRef, Par};

/// Number of bilinear parameters, `nu·N²`, appended after the linear layout.
pub fn bilinear_len(arch: &Arch) -> usize {
    let n = arch.latent_dim();
    arch.nu * n * n
}

/// The matrices of the bilinear latent dynamics, borrowed from the flat parameters.
pub(crate) struct Dynamics<'a, T: Real> {
    /// A (N × N).
    pub a: MatRef<'a, T>,
    /// B (N × nu).
    pub b: MatRef<'a, T>,
    /// N_1..N_nu, row-major N × N each.
    pub n: &'a [T],
}

/// Where the inverse-control loss writes its gradients.
pub(crate) struct CtrlGrads<'g, T: Real> {
    /// dL/dZ of every state of the batch (rows × N, column-major view).
    pub dz: MatMut<'g, T>,
    /// dL/dA (row-major N × N).
    pub ga: &'g mut [T],
    /// dL/dB (row-major N × nu).
    pub gb: &'g mut [T],
    /// dL/dN_i (row-major N × N each).
    pub gn: &'g mut [T],
}

impl<'a, T: Real> Dynamics<'a, T> {
    fn nn(&self) -> usize {
        self.a.nrows()
    }

    fn nu(&self) -> usize {
        self.b.ncols()
    }

    /// N_i as a view.
    pub fn n_i(&self, i: usize) -> MatRef<'a, T> {
        let nn = self.nn();
        MatRef::from_row_major_slice(&self.n[i * nn * nn..(i + 1) * nn * nn], nn, nn)
    }

    /// `next += Σ_i diag(u_i) · cur · N_iᵀ` (rows are samples); `tmp` holds ≥ rows·N values.
    pub fn add_forward(
        &self,
        mut next: MatMut<'_, T>,
        cur: MatRef<'_, T>,
        u: MatRef<'_, T>,
        tmp: &mut [T],
    ) {
        let (rows, nn) = (cur.nrows(), self.nn());
        for i in 0..self.nu() {
            let mut t = view_mut(tmp, rows, nn);
            matmul(
                t.rb_mut(),
                Accum::Replace,
                cur,
                self.n_i(i).transpose(),
                T::one(),
                Par::Seq,
            );
            for c in 0..nn {
                for r in 0..rows {
                    next[(r, c)] += u[(r, i)] * t[(r, c)];
                }
            }
        }
    }

    /// `dst += Σ_i diag(u_i) · g · N_i` (the adjoint of [`Dynamics::add_forward`]).
    pub fn add_adjoint(
        &self,
        mut dst: MatMut<'_, T>,
        g: MatRef<'_, T>,
        u: MatRef<'_, T>,
        tmp: &mut [T],
    ) {
        let (rows, nn) = (g.nrows(), self.nn());
        for i in 0..self.nu() {
            let mut t = view_mut(tmp, rows, nn);
            for c in 0..nn {
                for r in 0..rows {
                    t[(r, c)] = u[(r, i)] * g[(r, c)];
                }
            }
            matmul(
                dst.rb_mut(),
                Accum::Add,
                t.rb(),
                self.n_i(i),
                T::one(),
                Par::Seq,
            );
        }
    }

    /// `gn_i += (diag(u_i) · g)ᵀ · z` for every i: the gradient of the rollout w.r.t. N_i, given
    /// `g` = dL/dẑ_{k+1} and `z` = ẑ_k row by row.
    pub fn grad_n(
        &self,
        gn: &mut [T],
        g: MatRef<'_, T>,
        z: MatRef<'_, T>,
        u: MatRef<'_, T>,
        tmp: &mut [T],
    ) {
        let (rows, nn) = (g.nrows(), self.nn());
        for i in 0..self.nu() {
            let mut t = view_mut(tmp, rows, nn);
            for c in 0..nn {
                for r in 0..rows {
                    t[(r, c)] = u[(r, i)] * g[(r, c)];
                }
            }
            let gni =
                MatMut::from_row_major_slice_mut(&mut gn[i * nn * nn..(i + 1) * nn * nn], nn, nn);
            matmul(gni, Accum::Add, t.rb().transpose(), z, T::one(), Par::Seq);
        }
    }

    /// The inverse-control loss `(1/W) Σ_k γ^k mean((û − u)²)` with
    /// `û_s = pinv(B(z_s)) (z_{s+1} − A z_s)` per sample s, and its gradient.
    ///
    /// `z` holds the encoded states (`(T+1)·b` rows, time-major), `u` the inputs (`T·b` rows);
    /// `w` (≥ T·b·nu·N values) and `res` (≥ T·b·N) are scratch. Per sample,
    /// `dL/dr = B(z) M⁻¹ e` and `dL/dB(z) = ρ (M⁻¹e)ᵀ − B(z) M⁻¹ e ûᵀ` with `M = B(z)ᵀB(z)`,
    /// `e = dL/dû`, `ρ = r − B(z) û`.
    #[allow(clippy::too_many_arguments)]
    pub fn ctrl_loss(
        &self,
        z: MatRef<'_, T>,
        u: MatRef<'_, T>,
        b: usize,
        weights: &[f64],
        w: &mut [T],
        res: &mut [T],
        out: CtrlGrads<'_, T>,
    ) -> Result<f64> {
        let (nn, nu) = (self.nn(), self.nu());
        let tb = u.nrows();
        let one = T::one();
        let wsum: f64 = weights.iter().sum();
        let zc = z.subrows(0, tb);
        let zn = z.subrows(b, tb);
        {
            let mut r = view_mut(res, tb, nn);
            r.copy_from(zn);
            matmul(r, Accum::Add, zc, self.a.transpose(), -one, Par::Seq);
        }
        for i in 0..nu {
            let wi = view_mut(&mut w[i * tb * nn..], tb, nn);
            matmul(
                wi,
                Accum::Replace,
                zc,
                self.n_i(i).transpose(),
                one,
                Par::Seq,
            );
        }
        let mut bs = vec![0.0; nn * nu];
        let mut m = vec![0.0; nu * nu];
        let (mut y, mut uh, mut e, mut wv) =
            (vec![0.0; nu], vec![0.0; nu], vec![0.0; nu], vec![0.0; nu]);
        let mut gbacc = vec![0.0; nn * nu];
        let mut loss = 0.0;
        for s in 0..tb {
            let coef = weights[s / b] / (wsum * (b * nu) as f64);
            for i in 0..nu {
                for c in 0..nn {
                    bs[i * nn + c] = self.b[(c, i)].to_f64() + w[i * tb * nn + c * tb + s].to_f64();
                }
            }
            for i in 0..nu {
                for j in 0..nu {
                    m[i * nu + j] = (0..nn).map(|c| bs[i * nn + c] * bs[j * nn + c]).sum();
                }
            }
            let minv = super::pinv::spd_inverse(&m, nu).ok_or_else(|| {
                Error::Numerical(
                    "B(z)ᵀB(z) is not positive definite at a training sample: pinv(B(z)) is undefined"
                        .into(),
                )
            })?;
            for i in 0..nu {
                y[i] = (0..nn)
                    .map(|c| bs[i * nn + c] * res[c * tb + s].to_f64())
                    .sum();
            }
            for i in 0..nu {
                uh[i] = (0..nu).map(|j| minv[i * nu + j] * y[j]).sum();
                let d = uh[i] - u[(s, i)].to_f64();
                loss += coef * d * d;
                e[i] = 2.0 * coef * d;
            }
            for i in 0..nu {
                wv[i] = (0..nu).map(|j| minv[i * nu + j] * e[j]).sum();
            }
            for c in 0..nn {
                let (mut rho, mut q) = (res[c * tb + s].to_f64(), 0.0);
                for i in 0..nu {
                    rho -= bs[i * nn + c] * uh[i];
                    q += bs[i * nn + c] * wv[i];
                }
                res[c * tb + s] = T::from_f64(q);
                for i in 0..nu {
                    let db = rho * wv[i] - q * uh[i];
                    gbacc[c * nu + i] += db;
                    w[i * tb * nn + c * tb + s] = T::from_f64(db);
                }
            }
        }
        let CtrlGrads { mut dz, ga, gb, gn } = out;
        for (g, v) in gb.iter_mut().zip(&gbacc) {
            *g += T::from_f64(*v);
        }
        // res now holds Q (rows q_s = dL/dr_s); w holds D_i (rows dL/dB(z_s)[:, i]).
        let q = view(res, tb, nn);
        let mut dzn = dz.rb_mut().subrows_mut(b, tb);
        for c in 0..nn {
            for r in 0..tb {
                dzn[(r, c)] += q[(r, c)];
            }
        }
        matmul(
            dz.rb_mut().subrows_mut(0, tb),
            Accum::Add,
            q,
            self.a,
            -one,
            Par::Seq,
        );
        matmul(
            MatMut::from_row_major_slice_mut(ga, nn, nn),
            Accum::Add,
            q.transpose(),
            zc,
            -one,
            Par::Seq,
        );
        for i in 0..nu {
            let d = view(&w[i * tb * nn..], tb, nn);
            matmul(
                MatMut::from_row_major_slice_mut(&mut gn[i * nn * nn..(i + 1) * nn * nn], nn, nn),
                Accum::Add,
                d.transpose(),
                zc,
                one,
                Par::Seq,
            );
            matmul(
                dz.rb_mut().subrows_mut(0, tb),
                Accum::Add,
                d,
                self.n_i(i),
                one,
                Par::Seq,
            );
        }
        Ok(loss)
    }
}
