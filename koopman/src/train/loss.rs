//! The three training losses of SPEC.md and their hand-written gradients, sharing one encoding
//! of every state of the batch.
//!
//! Rows of every batch matrix are time-major: state `t` of window `i` is row `t·b + i`, so the
//! states at one time form a contiguous block of `b` rows and "all current / all next states" are
//! two overlapping row ranges of one matrix.

use super::bilinear::{CtrlGrads, Dynamics};
use super::parts::{cuts, for_blocks, SPLIT_MIN_MACS};
use super::regular::{cov_grad, cov_loss, ctrl_loss, CovWs, CtrlInputs, CtrlWs};
use crate::model::arch::{Arch, Layout};
use crate::model::encoder::{view, view_mut, EncoderWs};
use crate::model::scalar::Real;
use crate::{Error, Result};
use faer::linalg::matmul::matmul;
use faer::reborrow::{Reborrow, ReborrowMut};
use faer::{Accum, MatMut, MatRef, Par};
use rayon::prelude::*;

/// Which loss terms are on, and the discount.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LossOptions {
    /// Discount γ of the multi-step losses.
    pub gamma: f64,
    /// Inverse-control loss on (ignored when nu = 0).
    pub ctrl: bool,
    /// Covariance loss on (ignored when n_enc = 1).
    pub cov: bool,
}

/// Values of the loss terms of one batch (terms that are off are 0).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LossParts {
    /// Multi-step discounted prediction loss.
    pub pred: f64,
    /// Inverse-control loss.
    pub ctrl: f64,
    /// Covariance loss.
    pub cov: f64,
    /// Their sum.
    pub total: f64,
}

/// Every buffer one loss-and-gradient evaluation needs, allocated once for a batch shape.
pub struct LossWs<T: Real> {
    arch: Arch,
    layout: Layout,
    /// Windows per batch.
    pub b: usize,
    /// Transitions per window.
    pub steps: usize,
    /// The batch's states (column-major, `n × nx`).
    x: Vec<T>,
    /// One encoder workspace per part of the rows (data parallelism over threads).
    encs: Vec<EncoderWs<T>>,
    /// First row of each part.
    starts: Vec<usize>,
    /// Encoder parameter gradient of each part, summed afterwards.
    gparts: Vec<Vec<T>>,
    u: Vec<T>,
    z: Vec<T>,
    dz: Vec<T>,
    zhat: Vec<T>,
    g: Vec<T>,
    /// Buffers of the inverse-control and covariance losses.
    ctrl: CtrlWs<T>,
    cov: CovWs<T>,
    /// Bilinear dynamics `z⁺ = A z + B u + Σ u_i N_i z` (parameters end with the N_i).
    bil: bool,
    /// Bilinear scratch: T·b × N, and T·b × nu·N (empty for the linear model).
    tmp: Vec<T>,
    bw: Vec<T>,
    /// Cut points of the batch's windows (rows of one time step) over the threads.
    row_cuts: Vec<usize>,
    /// Cut points of A's columns over the threads.
    col_cuts: Vec<usize>,
}

impl<T: Real> LossWs<T> {
    /// Buffers for batches of `b` windows of `steps` transitions. With `Par::Rayon(k)` the
    /// encoder's rows are split into `k` parts that run on `k` threads (each with sequential
    /// GEMMs, so the threads never wait on each other inside a pass); `Par::Seq` runs one part.
    pub fn new(arch: &Arch, b: usize, steps: usize, par: Par) -> Self {
        Self::with_dynamics(arch, b, steps, par, false)
    }

    /// Like [`LossWs::new`], for the bilinear model `z⁺ = A z + B u + Σ_i u_i N_i z` when
    /// `bilinear`: its parameter vectors are the linear layout followed by N_1..N_nu
    /// ([`super::bilinear::bilinear_len`] values, row-major).
    pub fn with_dynamics(arch: &Arch, b: usize, steps: usize, par: Par, bilinear: bool) -> Self {
        let n = (steps + 1) * b;
        let nn = arch.latent_dim();
        let nu = arch.nu;
        let d = arch.n_enc();
        let layout = arch.layout();
        let parts = match par {
            Par::Seq => 1,
            Par::Rayon(k) => k.get().clamp(1, n.max(1)),
        };
        let starts: Vec<usize> = (0..=parts).map(|p| p * n / parts).collect();
        let encs = starts
            .windows(2)
            .map(|w| EncoderWs::new(arch, w[1] - w[0], Par::Seq))
            .collect();
        let gparts = (0..parts).map(|_| vec![T::default(); layout.a]).collect();
        LossWs {
            arch: arch.clone(),
            layout,
            b,
            steps,
            x: vec![T::default(); n * arch.nx],
            encs,
            starts,
            gparts,
            u: vec![T::default(); steps * b * nu],
            z: vec![T::default(); n * nn],
            dz: vec![T::default(); n * nn],
            zhat: vec![T::default(); n * nn],
            g: vec![T::default(); steps * b * nn],
            ctrl: CtrlWs::new(nu, nn, steps * b),
            cov: CovWs::new(b, d),
            bil: bilinear,
            tmp: vec![T::default(); if bilinear { steps * b * nn } else { 0 }],
            bw: vec![T::default(); if bilinear { steps * b * nu * nn } else { 0 }],
            row_cuts: cuts(b, parts),
            col_cuts: cuts(nn, parts),
        }
    }

    /// The state buffer to fill: column-major `((T+1)·b) × nx`, row `t·b + i` = state t of
    /// window i.
    pub fn states_mut(&mut self) -> &mut [T] {
        &mut self.x
    }

    /// The input buffer to fill: column-major `(T·b) × nu`, row `t·b + i` = input t of window i.
    pub fn inputs_mut(&mut self) -> &mut [T] {
        &mut self.u
    }

    /// Evaluates the loss of the batch in the buffers and writes its gradient w.r.t. every
    /// parameter into `grad` (overwritten; same layout as `params`).
    pub fn loss_and_grad(
        &mut self,
        params: &[T],
        grad: &mut [T],
        opts: &LossOptions,
    ) -> Result<LossParts> {
        let (b, steps) = (self.b, self.steps);
        let nx = self.arch.nx;
        let nu = self.arch.nu;
        let nn = self.arch.latent_dim();
        let d = self.arch.n_enc();
        let n = (steps + 1) * b;
        let tb = steps * b;
        let lay = &self.layout;
        let n_bil = if self.bil { nu * nn * nn } else { 0 };
        let total = lay.len + n_bil;
        if params.len() != total || grad.len() != total {
            return Err(Error::dimension(
                "parameter vector",
                total,
                params.len().min(grad.len()),
            ));
        }
        let one = T::one();
        let zero = T::default();

        // ψ(x) once for every state of the batch (the row parts in parallel); Z = [x, ψ].
        {
            let x = view(&self.x, n, nx);
            for (e, w) in self.encs.iter_mut().zip(self.starts.windows(2)) {
                let rows = w[1] - w[0];
                view_mut(e.input_mut(rows), rows, nx).copy_from(x.subrows(w[0], rows));
            }
        }
        if self.encs.len() == 1 {
            self.encs[0].forward(params);
        } else {
            self.encs.par_iter_mut().for_each(|e| e.forward(params));
        }
        {
            let x = view(&self.x, n, nx);
            let mut z = view_mut(&mut self.z, n, nn);
            z.rb_mut().subcols_mut(0, nx).copy_from(x);
            for (e, w) in self.encs.iter().zip(self.starts.windows(2)) {
                z.rb_mut()
                    .submatrix_mut(w[0], nx, w[1] - w[0], d)
                    .copy_from(e.output());
            }
        }
        self.dz.fill(zero);
        for v in &mut grad[lay.a..] {
            *v = zero;
        }
        let (gp, ga_gb) = grad.split_at_mut(lay.a);
        let _ = gp;
        let (ga, gb_gn) = ga_gb.split_at_mut(nn * nn);
        let (gb, gn) = gb_gn.split_at_mut(nn * nu);
        let a = MatRef::from_row_major_slice(&params[lay.a..lay.a + nn * nn], nn, nn);
        let bm = MatRef::from_row_major_slice(&params[lay.b..lay.len], nn, nu);
        let dynamics = Dynamics {
            a,
            b: bm,
            n: &params[lay.len..],
        };
        let bil = self.bil;
        let weights: Vec<f64> = (0..steps).map(|k| opts.gamma.powi(k as i32)).collect();
        let wsum: f64 = weights.iter().sum();
        let z = view(&self.z, n, nn);
        let u = view(&self.u, tb, nu);
        let x = view(&self.x, n, nx);
        let mut parts = LossParts::default();

        // The rollout's products split by windows over the threads when they are large enough.
        let row_cuts: &[usize] = if b * nn * nn >= SPLIT_MIN_MACS {
            &self.row_cuts
        } else {
            &[]
        };
        // Prediction: ẑ_0 = Φ(x_0), ẑ_{k+1} = A ẑ_k + B u_k.
        {
            let mut zhat = view_mut(&mut self.zhat, n, nn);
            zhat.rb_mut().subrows_mut(0, b).copy_from(z.subrows(0, b));
            for k in 0..steps {
                let (cur, mut next) = zhat.rb_mut().split_at_row_mut((k + 1) * b);
                let cur = cur.rb().subrows(k * b, b);
                let mut next = next.rb_mut().subrows_mut(0, b);
                let uk = u.subrows(k * b, b);
                for_blocks(next.rb_mut(), row_cuts, true, |r0, mut dst| {
                    let rows = dst.nrows();
                    let (cur, uk) = (cur.subrows(r0, rows), uk.subrows(r0, rows));
                    matmul(
                        dst.rb_mut(),
                        Accum::Replace,
                        cur,
                        a.transpose(),
                        one,
                        Par::Seq,
                    );
                    if nu > 0 {
                        matmul(dst, Accum::Add, uk, bm.transpose(), one, Par::Seq);
                    }
                });
                if bil {
                    dynamics.add_forward(next, cur, u.subrows(k * b, b), &mut self.tmp);
                }
            }
        }
        let zhat = view(&self.zhat, n, nn);
        {
            let mut g = view_mut(&mut self.g, tb, nn);
            g.fill(zero);
            let mut loss = 0.0;
            for k in 0..steps {
                let coef = weights[k] / (wsum * (b * nx) as f64);
                let c2 = T::from_f64(2.0 * coef);
                for j in 0..nx {
                    let mut s = 0.0;
                    for i in 0..b {
                        let r = (k + 1) * b + i;
                        let diff = zhat[(r, j)] - x[(r, j)];
                        s += diff.to_f64() * diff.to_f64();
                        g[(k * b + i, j)] = c2 * diff;
                    }
                    loss += coef * s;
                }
            }
            parts.pred = loss;
            // Adjoint: g_{k+1} += g_{k+2} A, then g_0 = g_1 A feeds Φ(x_0).
            for k in (0..steps.saturating_sub(1)).rev() {
                let (head, tail) = g.rb_mut().split_at_row_mut((k + 1) * b);
                let nextg = tail.rb().subrows(0, b);
                let mut dst = head.subrows_mut(k * b, b);
                for_blocks(dst.rb_mut(), row_cuts, true, |r0, d| {
                    let nextg = nextg.subrows(r0, d.nrows());
                    matmul(d, Accum::Add, nextg, a, one, Par::Seq);
                });
                if bil {
                    dynamics.add_adjoint(dst, nextg, u.subrows((k + 1) * b, b), &mut self.tmp);
                }
            }
            let g = view(&self.g, tb, nn);
            let mut dz = view_mut(&mut self.dz, n, nn);
            for_blocks(dz.rb_mut().subrows_mut(0, b), row_cuts, true, |r0, d| {
                let g0 = g.subrows(r0, d.nrows());
                matmul(d, Accum::Add, g0, a, one, Par::Seq);
            });
            if bil {
                dynamics.add_adjoint(
                    dz.rb_mut().subrows_mut(0, b),
                    g.subrows(0, b),
                    u.subrows(0, b),
                    &mut self.tmp,
                );
                dynamics.grad_n(&mut *gn, g, zhat.subrows(0, tb), u, &mut self.tmp);
            }
            // dA += gᵀ Ẑ_cur, A's columns over the threads.
            let ga_m = MatMut::from_row_major_slice_mut(&mut *ga, nn, nn);
            let col_cuts: &[usize] = if tb * nn * nn >= SPLIT_MIN_MACS {
                &self.col_cuts
            } else {
                &[]
            };
            let zcur = zhat.subrows(0, tb);
            for_blocks(ga_m, col_cuts, false, |c0, d| {
                let zc = zcur.subcols(c0, d.ncols());
                matmul(d, Accum::Add, g.transpose(), zc, one, Par::Seq);
            });
            if nu > 0 {
                let gb_m = MatMut::from_row_major_slice_mut(&mut *gb, nn, nu);
                matmul(gb_m, Accum::Add, g.transpose(), u, one, Par::Seq);
            }
        }

        // Bilinear inverse control: û = pinv(B(Φ(x_t))) (Φ(x_{t+1}) − A Φ(x_t)) per sample.
        if opts.ctrl && nu > 0 && bil {
            parts.ctrl = dynamics.ctrl_loss(
                z,
                u,
                b,
                &weights,
                &mut self.bw,
                &mut self.tmp,
                CtrlGrads {
                    dz: view_mut(&mut self.dz, n, nn),
                    ga: &mut *ga,
                    gb: &mut *gb,
                    gn: &mut *gn,
                },
            )?;
        }
        // The regularisers, at the same time on two threads when the products are split.
        let want_ctrl = opts.ctrl && nu > 0 && !bil;
        let want_cov = opts.cov && d > 1;
        if want_cov && b < 2 {
            return Err(Error::InvalidArgument(
                "the covariance loss needs a batch of at least 2".into(),
            ));
        }
        let inp = CtrlInputs {
            a_flat: &params[lay.a..lay.a + nn * nn],
            a,
            bm,
            z,
            u_data: &self.u,
            b,
            weights: &weights,
        };
        let dz_all = view_mut(&mut self.dz, n, nn);
        let (ctrl_ws, cov_ws) = (&mut self.ctrl, &mut self.cov);
        let (ctrl, cov) = if want_ctrl && want_cov && !row_cuts.is_empty() {
            rayon::join(
                || ctrl_loss(ctrl_ws, &inp, dz_all, &mut *ga, &mut *gb),
                || cov_loss(cov_ws, z, nx, b),
            )
        } else {
            let ctrl = if want_ctrl {
                ctrl_loss(ctrl_ws, &inp, dz_all, &mut *ga, &mut *gb)
            } else {
                Ok(0.0)
            };
            (
                ctrl,
                if want_cov {
                    cov_loss(cov_ws, z, nx, b)
                } else {
                    0.0
                },
            )
        };
        if want_ctrl {
            parts.ctrl = ctrl?;
        }
        if want_cov {
            parts.cov = cov;
            // After the inverse-control terms, as one product (ψ's columns over the threads).
            let dz = view_mut(&mut self.dz, n, nn);
            let col_cuts = if row_cuts.is_empty() {
                Vec::new()
            } else {
                cuts(d, row_cuts.len() - 1)
            };
            let cov_ws = &self.cov;
            for_blocks(
                dz.submatrix_mut(0, nx, b, d),
                &col_cuts,
                false,
                |c0, blk| cov_grad(cov_ws, blk, c0),
            );
        }

        parts.total = parts.pred + parts.ctrl + parts.cov;

        // Back through the encoder with the gradient w.r.t. ψ of every state.
        {
            let dz = view(&self.dz, n, nn);
            for (e, w) in self.encs.iter_mut().zip(self.starts.windows(2)) {
                e.output_grad_mut()
                    .copy_from(dz.submatrix(w[0], nx, w[1] - w[0], d));
            }
        }
        let genc = &mut grad[..lay.a];
        if self.encs.len() == 1 {
            self.encs[0].backward(params, genc);
        } else {
            self.encs
                .par_iter_mut()
                .zip(self.gparts.par_iter_mut())
                .for_each(|(e, g)| e.backward(params, g));
            genc.copy_from_slice(&self.gparts[0]);
            for gp in &self.gparts[1..] {
                for (a, b) in genc.iter_mut().zip(gp) {
                    *a += *b;
                }
            }
        }
        Ok(parts)
    }
}
