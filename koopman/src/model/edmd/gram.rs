//! Chunked, parallel accumulation of the EDMD normal equations `G = Σ w wᵀ`, `C = Σ w z⁺ᵀ` with
//! `w = [Φ(x_t), u_t]`, and their ridge-regularised solution (Cholesky, SVD fallback).
//!
//! The transitions are cut into a fixed number of contiguous blocks (independent of the thread
//! count), each accumulated chunk by chunk with one GEMM per chunk; the block sums are added in
//! block order, so the result is deterministic and memory does not grow with the number of pairs.

use super::dictionary::Dictionary;
use crate::data::Dataset;
use crate::{Error, Result};
use faer::linalg::matmul::matmul;
use faer::linalg::matmul::triangular::{self, BlockStructure};
use faer::linalg::solvers::Solve;
use faer::{Accum, Mat, MatRef, Par, Side};
use rayon::prelude::*;

/// Mean squared lifted residual `(1/P) Σ ‖z⁺ − Kᵀ w‖² = syy − 2⟨K, C⟩ + ⟨K, G K⟩` of a
/// solution K, from the normal equations alone (clamped at 0 against rounding).
pub fn residual(normal: &Normal, k: &Mat<f64>) -> f64 {
    let gk = &normal.g * k;
    let mut kc = 0.0;
    let mut kgk = 0.0;
    for j in 0..k.ncols() {
        for i in 0..k.nrows() {
            kc += k[(i, j)] * normal.c[(i, j)];
            kgk += k[(i, j)] * gk[(i, j)];
        }
    }
    (normal.syy - 2.0 * kc + kgk).max(0.0) / k.ncols().max(1) as f64
}

/// Fixed number of blocks the transitions are split into (≥ the useful thread count).
const BLOCKS: usize = 16;

/// The accumulated normal equations, normalised by the number of pairs.
pub struct Normal {
    /// `(1/P) Σ w wᵀ`, (N+nu) × (N+nu).
    pub g: Mat<f64>,
    /// `(1/P) Σ w z⁺ᵀ`, (N+nu) × N.
    pub c: Mat<f64>,
    /// `(1/P) Σ ‖z⁺‖²` (for the training residual).
    pub syy: f64,
    /// Number of pairs P.
    pub pairs: usize,
}

/// Accumulates the normal equations over every transition of `data` in chunks of `chunk` pairs.
pub fn accumulate(dict: &Dictionary, data: &Dataset, chunk: usize) -> Normal {
    let n_lat = dict.len();
    let nu = data.nu;
    let nw = n_lat + nu;
    let pairs = data.transitions();
    let chunk = chunk.max(1);
    let per_block = pairs.div_ceil(BLOCKS).max(1);
    let partials: Vec<(Mat<f64>, Mat<f64>, f64)> = (0..BLOCKS)
        .into_par_iter()
        .map(|b| {
            let start = (b * per_block).min(pairs);
            let end = ((b + 1) * per_block).min(pairs);
            // Over the block: g = WᵀW (lower triangle only), c = WᵀY, syy = Σ ‖z⁺‖².
            let mut g = Mat::<f64>::zeros(nw, nw);
            let mut c = Mat::<f64>::zeros(nw, n_lat);
            let mut syy = 0.0;
            let rows = chunk.min(end - start);
            let width = nw + n_lat;
            // Column-major chunk [W Y] with leading dimension `rows`, lifted column by column.
            let mut wy = vec![0.0; rows * width];
            let mut work = Vec::new();
            let mut xs: Vec<&[f64]> = Vec::with_capacity(rows);
            let mut p = start;
            while p < end {
                let m = chunk.min(end - p);
                let pair = |q: usize| (q / data.steps, q % data.steps);
                xs.clear();
                xs.extend((p..p + m).map(|q| data.state(pair(q).0, pair(q).1)));
                dict.lift_columns(&xs, &mut wy, rows, &mut work);
                for j in 0..nu {
                    for r in 0..m {
                        let (i, t) = pair(p + r);
                        wy[(n_lat + j) * rows + r] = data.input(i, t)[j];
                    }
                }
                xs.clear();
                xs.extend((p..p + m).map(|q| data.state(pair(q).0, pair(q).1 + 1)));
                dict.lift_columns(&xs, &mut wy[nw * rows..], rows, &mut work);
                for j in 0..n_lat {
                    let col = &wy[(nw + j) * rows..(nw + j) * rows + m];
                    syy += col.iter().map(|v| v * v).sum::<f64>();
                }
                let block = MatRef::from_column_major_slice_with_stride(&wy, m, width, rows);
                let w = block.subcols(0, nw);
                triangular::matmul(
                    g.as_mut(),
                    BlockStructure::TriangularLower,
                    Accum::Add,
                    w.transpose(),
                    BlockStructure::Rectangular,
                    w,
                    BlockStructure::Rectangular,
                    1.0,
                    Par::Seq,
                );
                matmul(
                    c.as_mut(),
                    Accum::Add,
                    w.transpose(),
                    block.subcols(nw, n_lat),
                    1.0,
                    Par::Seq,
                );
                p += m;
            }
            (g, c, syy)
        })
        .collect();
    let mut gl = Mat::<f64>::zeros(nw, nw);
    let mut c = Mat::<f64>::zeros(nw, n_lat);
    let mut syy = 0.0;
    for (pg, pc, ps) in &partials {
        gl += pg;
        c += pc;
        syy += ps;
    }
    let scale = 1.0 / pairs.max(1) as f64;
    // Mirror the lower triangle.
    let g = Mat::from_fn(nw, nw, |i, j| {
        if i >= j {
            gl[(i, j)] * scale
        } else {
            gl[(j, i)] * scale
        }
    });
    c *= faer::Scale(scale);
    let syy = syy * scale;
    Normal { g, c, syy, pairs }
}

/// Which factorisation solved the normal equations.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Solver {
    /// Cholesky of `G + λI`.
    Cholesky,
    /// Pseudo-inverse by SVD (Cholesky failed: `G + λI` numerically not positive definite).
    Svd,
}

/// Solves `(G + λ I) K = C` for K ((N+nu) × N), by Cholesky or, if that fails, by the
/// SVD pseudo-inverse with relative cut-off `1e-13 · σ_max`.
pub fn solve(normal: &Normal, ridge: f64) -> Result<(Mat<f64>, Solver)> {
    let nw = normal.g.nrows();
    let mut greg = normal.g.clone();
    for i in 0..nw {
        greg[(i, i)] += ridge;
    }
    if let Ok(llt) = greg.llt(Side::Lower) {
        let k = llt.solve(&normal.c);
        if k.col_iter().all(|c| c.iter().all(|v| v.is_finite())) {
            return Ok((k, Solver::Cholesky));
        }
    }
    solve_svd(&greg, &normal.c).map(|k| (k, Solver::Svd))
}

/// `K = pinv(G) C` by the SVD of the symmetric matrix `G`.
pub fn solve_svd(g: &Mat<f64>, c: &Mat<f64>) -> Result<Mat<f64>> {
    let svd = g
        .svd()
        .map_err(|e| Error::Numerical(format!("SVD of the EDMD Gram matrix failed: {e:?}")))?;
    let s = svd.S().column_vector();
    let smax = s.iter().cloned().fold(0.0, f64::max);
    if !(smax > 0.0 && smax.is_finite()) {
        return Err(Error::Numerical(
            "the EDMD Gram matrix is zero or not finite".into(),
        ));
    }
    let cut = 1e-13 * smax;
    // K = V S⁺ Uᵀ C.
    let utc = svd.U().transpose() * c;
    let scaled = Mat::from_fn(utc.nrows(), utc.ncols(), |i, j| {
        if s[i] > cut {
            utc[(i, j)] / s[i]
        } else {
            0.0
        }
    });
    Ok(svd.V() * scaled)
}
