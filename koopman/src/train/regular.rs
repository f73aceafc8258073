//! The two regularisers of SPEC.md's linear Koopman loss with their hand-written gradients —
//! the inverse-control loss through `pinv(B)` and the covariance of ψ(x_0) over the batch — each
//! on its own buffers, so that the trainer can run them at the same time on two threads.

use super::pinv::{pinv_backward, spd_inverse};
use crate::model::encoder::{view, view_mut};
use crate::model::scalar::Real;
use crate::{Error, Result};
use faer::linalg::matmul::matmul;
use faer::reborrow::ReborrowMut;
use faer::{Accum, MatMut, MatRef, Par};

/// Buffers of the inverse-control loss (nu inputs, latent N, `tb` transitions).
pub(crate) struct CtrlWs<T: Real> {
    p: Vec<T>,
    pa: Vec<T>,
    q: Vec<T>,
    uhat: Vec<T>,
    /// A in f64 (row-major N × N), for the f64 gradient of pinv(B).
    a64: Vec<f64>,
    /// Q2 = Eᵀ Z_cur in f64 and G_P = dL/dP (nu × N each, row-major).
    q2_64: Vec<f64>,
    gp64: Vec<f64>,
}

impl<T: Real> CtrlWs<T> {
    pub(crate) fn new(nu: usize, nn: usize, tb: usize) -> Self {
        CtrlWs {
            p: vec![T::default(); nu * nn],
            pa: vec![T::default(); nu * nn],
            q: vec![T::default(); 2 * nu * nn],
            uhat: vec![T::default(); tb * nu],
            a64: vec![0.0; if nu > 0 { nn * nn } else { 0 }],
            q2_64: vec![0.0; nu * nn],
            gp64: vec![0.0; nu * nn],
        }
    }
}

/// What the inverse-control loss reads: A (row-major, flat and as a view), B, the lifted states
/// `z` of the whole batch (`(T+1)·b × N`), the inputs `u` (`T·b × nu`, column-major) and the
/// discount weights.
pub(crate) struct CtrlInputs<'a, T: Real> {
    pub a_flat: &'a [T],
    pub a: MatRef<'a, T>,
    pub bm: MatRef<'a, T>,
    pub z: MatRef<'a, T>,
    pub u_data: &'a [T],
    pub b: usize,
    pub weights: &'a [f64],
}

/// Inverse control `û = pinv(B) (Φ(x_{t+1}) − A Φ(x_t))`: returns its loss and adds its
/// gradient to `dz` (all states, `(T+1)·b × N`), `ga` (row-major N × N) and `gb` (N × nu).
pub(crate) fn ctrl_loss<T: Real>(
    ws: &mut CtrlWs<T>,
    inp: &CtrlInputs<'_, T>,
    dz: MatMut<'_, T>,
    ga: &mut [T],
    gb: &mut [T],
) -> Result<f64> {
    let CtrlInputs {
        a_flat,
        a,
        bm,
        z,
        u_data,
        b,
        weights,
    } = *inp;
    let (nn, nu) = (bm.nrows(), bm.ncols());
    let tb = z.nrows() - b;
    let one = T::one();
    let wsum: f64 = weights.iter().sum();
    // M = BᵀB and its inverse (f64, nu × nu, Cholesky).
    let mut mmat = vec![0.0; nu * nu];
    for r in 0..nu {
        for c in 0..nu {
            let mut s = 0.0;
            for k in 0..nn {
                s += bm[(k, r)].to_f64() * bm[(k, c)].to_f64();
            }
            mmat[r * nu + c] = s;
        }
    }
    let minv = spd_inverse(&mmat, nu).ok_or_else(|| {
        Error::Numerical(
            "BᵀB is not positive definite: B lost full column rank, pinv(B) is undefined".into(),
        )
    })?;
    // P = M⁻¹ Bᵀ (nu × N, row-major), PA = P A.
    for r in 0..nu {
        for c in 0..nn {
            let mut s = 0.0;
            for k in 0..nu {
                s += minv[r * nu + k] * bm[(c, k)].to_f64();
            }
            ws.p[r * nn + c] = T::from_f64(s);
        }
    }
    let p = MatRef::from_row_major_slice(&ws.p, nu, nn);
    matmul(
        MatMut::from_row_major_slice_mut(&mut ws.pa, nu, nn),
        Accum::Replace,
        p,
        a,
        one,
        Par::Seq,
    );
    let pa = MatRef::from_row_major_slice(&ws.pa, nu, nn);
    let z_next = z.subrows(b, tb);
    let z_cur = z.subrows(0, tb);
    {
        let mut uhat = view_mut(&mut ws.uhat, tb, nu);
        matmul(
            uhat.rb_mut(),
            Accum::Replace,
            z_next,
            p.transpose(),
            one,
            Par::Seq,
        );
        matmul(uhat, Accum::Add, z_cur, pa.transpose(), -one, Par::Seq);
    }
    // E = dL/dû in place of û.
    let mut loss = 0.0;
    for (k, &wk) in weights.iter().enumerate() {
        let coef = wk / (wsum * (b * nu) as f64);
        let c2 = T::from_f64(2.0 * coef);
        for j in 0..nu {
            let mut s = 0.0;
            for i in 0..b {
                let r = k * b + i;
                let diff = ws.uhat[j * tb + r] - u_data[j * tb + r];
                s += diff.to_f64() * diff.to_f64();
                ws.uhat[j * tb + r] = c2 * diff;
            }
            loss += coef * s;
        }
    }
    let ctrl_loss = loss;
    let e = view(&ws.uhat, tb, nu);
    // Q1 = Eᵀ Z_next, Q2 = Eᵀ Z_cur (nu × N each, row-major).
    let (q1, q2) = ws.q.split_at_mut(nu * nn);
    matmul(
        MatMut::from_row_major_slice_mut(&mut *q1, nu, nn),
        Accum::Replace,
        e.transpose(),
        z_next,
        one,
        Par::Seq,
    );
    matmul(
        MatMut::from_row_major_slice_mut(&mut *q2, nu, nn),
        Accum::Replace,
        e.transpose(),
        z_cur,
        one,
        Par::Seq,
    );
    let q2m = MatRef::from_row_major_slice(&*q2, nu, nn);
    // dZ_next += E P, dZ_cur −= E PA, dA −= Pᵀ Q2.
    let mut dz = dz;
    matmul(
        dz.rb_mut().subrows_mut(b, tb),
        Accum::Add,
        e,
        p,
        one,
        Par::Seq,
    );
    matmul(dz.subrows_mut(0, tb), Accum::Add, e, pa, -one, Par::Seq);
    matmul(
        MatMut::from_row_major_slice_mut(&mut *ga, nn, nn),
        Accum::Add,
        p.transpose(),
        q2m,
        -one,
        Par::Seq,
    );
    // G_P = dL/dP = Q1 − Q2 Aᵀ; dL/dB = (I − B P) G_Pᵀ M⁻¹ − Pᵀ G_P Pᵀ.
    // (in f64, as one GEMM: G_P = Q1 − Q2 Aᵀ).
    for (d, s) in ws.a64.iter_mut().zip(a_flat) {
        *d = s.to_f64();
    }
    for (d, s) in ws.q2_64.iter_mut().zip(&*q2) {
        *d = s.to_f64();
    }
    for (d, s) in ws.gp64.iter_mut().zip(&*q1) {
        *d = s.to_f64();
    }
    matmul(
        MatMut::from_row_major_slice_mut(&mut ws.gp64, nu, nn),
        Accum::Add,
        MatRef::from_row_major_slice(&ws.q2_64, nu, nn),
        MatRef::from_row_major_slice(&ws.a64, nn, nn).transpose(),
        -1.0,
        Par::Seq,
    );
    pinv_backward(&ws.gp64, &ws.p, bm, &minv, nu, nn, gb);
    Ok(ctrl_loss)
}

/// Buffers of the covariance loss (`b` windows, `d` encoder features).
pub(crate) struct CovWs<T: Real> {
    cen: Vec<T>,
    cmat: Vec<T>,
}

impl<T: Real> CovWs<T> {
    pub(crate) fn new(b: usize, d: usize) -> Self {
        CovWs {
            cen: vec![T::default(); b * d],
            cmat: vec![T::default(); d * d],
        }
    }
}

/// Covariance loss of ψ(x_0) = `z[0..b, nx..nx+d]` over the batch (b ≥ 2): returns it and keeps
/// the centred features and `S = dL/dC` for [`cov_grad`].
pub(crate) fn cov_loss<T: Real>(ws: &mut CovWs<T>, z: MatRef<'_, T>, nx: usize, b: usize) -> f64 {
    let d = z.ncols() - nx;
    let zero = T::default();
    let mut cen = view_mut(&mut ws.cen, b, d);
    for j in 0..d {
        let mut mean = 0.0;
        for i in 0..b {
            mean += z[(i, nx + j)].to_f64();
        }
        let mean = T::from_f64(mean / b as f64);
        for i in 0..b {
            cen[(i, j)] = z[(i, nx + j)] - mean;
        }
    }
    let cen = view(&ws.cen, b, d);
    let mut cm = view_mut(&mut ws.cmat, d, d);
    let inv_b1 = T::from_f64(1.0 / (b - 1) as f64);
    matmul(
        cm.rb_mut(),
        Accum::Replace,
        cen.transpose(),
        cen,
        inv_b1,
        Par::Seq,
    );
    let norm = (d * (d - 1)) as f64;
    let mut loss = 0.0;
    let s_scale = T::from_f64(2.0 / norm);
    for j in 0..d {
        for i in 0..d {
            if i == j {
                cm[(i, j)] = zero;
            } else {
                let c = cm[(i, j)];
                loss += c.to_f64() * c.to_f64();
                cm[(i, j)] = s_scale * c;
            }
        }
    }
    loss / norm
}

/// Adds the covariance loss's gradient `2/(b−1) · cen · S[:, c0..]` to `dst` (b rows of ψ(x_0)'s
/// gradient, ψ's columns from `c0`) after [`cov_loss`].
pub(crate) fn cov_grad<T: Real>(ws: &CovWs<T>, dst: MatMut<'_, T>, c0: usize) {
    let b = dst.nrows();
    let d = ws.cen.len() / b;
    let cen = view(&ws.cen, b, d);
    let s = view(&ws.cmat, d, d).subcols(c0, dst.ncols());
    let alpha = T::from_f64(2.0 / (b - 1) as f64);
    matmul(dst, Accum::Add, cen, s, alpha, Par::Seq);
}
