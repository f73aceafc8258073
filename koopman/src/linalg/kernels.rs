//! Small dense vector kernels written so that the compiler vectorises them without fast-math:
//! a dot product with eight independent partial sums, and `y += Σ a_k c_k` over four columns per
//! pass (one load and store of `y` for four columns).

/// `Σ a_i b_i` over the shorter length, with eight partial sums (a different rounding order from
/// a sequential sum; the latency chain is an eighth as long).
#[inline(always)]
#[allow(clippy::needless_range_loop)]
pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut s = [0.0f64; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for k in 0..8 {
            s[k] += x[k] * y[k];
        }
    }
    let mut t = ((s[0] + s[4]) + (s[2] + s[6])) + ((s[1] + s[5]) + (s[3] + s[7]));
    for (x, y) in ra.iter().zip(rb) {
        t += x * y;
    }
    t
}

/// `y += a x` (over the shorter length).
#[inline(always)]
pub fn axpy(a: f64, x: &[f64], y: &mut [f64]) {
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi += a * xi;
    }
}

/// `y += Σ_k a[k] · col(idx[k])` where column `j` of the column-major matrix `m` (`y.len()` rows)
/// is `m[j·rows .. (j+1)·rows]`; four columns per pass over `y`.
#[inline(always)]
#[allow(clippy::needless_range_loop)]
pub fn gather_gemv(m: &[f64], idx: &[usize], a: &[f64], y: &mut [f64]) {
    let rows = y.len();
    let col = |j: usize| &m[j * rows..(j + 1) * rows];
    let (ci, ca) = (idx.chunks_exact(4), a.chunks_exact(4));
    let (ri, ra) = (ci.remainder(), ca.remainder());
    for (j, w) in ci.zip(ca) {
        let (c0, c1, c2, c3) = (col(j[0]), col(j[1]), col(j[2]), col(j[3]));
        let y = &mut y[..rows];
        for i in 0..rows {
            y[i] += (w[0] * c0[i] + w[1] * c1[i]) + (w[2] * c2[i] + w[3] * c3[i]);
        }
    }
    for (&j, &w) in ri.iter().zip(ra) {
        axpy(w, col(j), y);
    }
}

/// `y += M x` for the column-major matrix `m` (`y.len()` rows, `x.len()` columns), four columns
/// per pass over `y`.
#[inline(always)]
#[allow(clippy::needless_range_loop)]
pub fn gemv(m: &[f64], x: &[f64], y: &mut [f64]) {
    let rows = y.len();
    debug_assert_eq!(m.len(), rows * x.len());
    let (cm, cx) = (m.chunks_exact(4 * rows), x.chunks_exact(4));
    let (rm, rx) = (cm.remainder(), cx.remainder());
    for (block, w) in cm.zip(cx) {
        let (c0, rest) = block.split_at(rows);
        let (c1, rest) = rest.split_at(rows);
        let (c2, c3) = rest.split_at(rows);
        let (c0, c1, c2, c3) = (&c0[..rows], &c1[..rows], &c2[..rows], &c3[..rows]);
        for i in 0..rows {
            y[i] += (w[0] * c0[i] + w[1] * c1[i]) + (w[2] * c2[i] + w[3] * c3[i]);
        }
    }
    for (c, &w) in rm.chunks_exact(rows.max(1)).zip(rx) {
        axpy(w, c, y);
    }
}

/// [`gemv`] compiled for the CPU's vector extension, found at run time (AVX2 where there is
/// one); VEX-encoded code also does not stall when other code has left the upper halves of the
/// vector registers dirty.
pub fn gemv_simd(m: &[f64], x: &[f64], y: &mut [f64]) {
    struct Op<'a>(&'a [f64], &'a [f64], &'a mut [f64]);
    impl pulp::WithSimd for Op<'_> {
        type Output = ();
        #[inline(always)]
        fn with_simd<S: pulp::Simd>(self, _simd: S) {
            gemv(self.0, self.1, self.2);
        }
    }
    pulp::Arch::new().dispatch(Op(m, x, y));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kernels_match_plain_loops() {
        for n in [0usize, 1, 3, 7, 8, 9, 17, 33] {
            let a: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin()).collect();
            let b: Vec<f64> = (0..n).map(|i| (i as f64 * 0.71).cos()).collect();
            let want: f64 = a.iter().zip(&b).map(|(x, y)| x * y).sum();
            assert!((dot(&a, &b) - want).abs() <= 1e-14 * (1.0 + want.abs()));
            let rows = 5;
            let m: Vec<f64> = (0..rows * n).map(|k| (k as f64 * 0.13).sin()).collect();
            let mut y = vec![1.0; rows];
            gemv(&m, &a, &mut y);
            let idx: Vec<usize> = (0..n).rev().collect();
            let mut yg = vec![1.0; rows];
            gather_gemv(&m, &idx, &b, &mut yg);
            for i in 0..rows {
                let w: f64 = 1.0 + (0..n).map(|j| m[j * rows + i] * a[j]).sum::<f64>();
                let wg: f64 = 1.0 + (0..n).map(|k| m[idx[k] * rows + i] * b[k]).sum::<f64>();
                assert!((y[i] - w).abs() <= 1e-13, "gemv n {n}");
                assert!((yg[i] - wg).abs() <= 1e-13, "gather n {n}");
            }
        }
    }
}
