//! A dense Cholesky factor `A = L Lᵀ` on a contiguous row-major buffer: factorise, solve,
//! invert, and grow or shrink it by one row and column in O(n²) (append, delete).

use super::kernels::{axpy, dot};

/// `A = L Lᵀ` with L lower triangular, stored row-major with row stride `stride ≥ n` (the upper
/// part is unused), so that rows can be appended without moving the others.
#[derive(Clone, Debug, Default)]
pub struct SmallCholesky {
    n: usize,
    stride: usize,
    l: Vec<f64>,
    /// `1 / L_ii`, for the solves that multiply instead of dividing.
    inv_diag: Vec<f64>,
}

impl SmallCholesky {
    /// Reserves room for factors of up to `cap` rows (appends beyond it reallocate).
    pub fn reserve(&mut self, cap: usize) {
        if cap > self.stride {
            let mut l = vec![0.0; cap * cap];
            for i in 0..self.n {
                l[i * cap..i * cap + i + 1]
                    .copy_from_slice(&self.l[i * self.stride..i * self.stride + i + 1]);
            }
            self.l = l;
            self.stride = cap;
            self.inv_diag.resize(cap, 0.0);
        }
    }

    /// Factorises the symmetric matrix given by `entry(i, j)` (only `j ≤ i` is read).
    /// Returns false if it is not numerically positive definite.
    pub fn factor(&mut self, n: usize, entry: impl Fn(usize, usize) -> f64) -> bool {
        self.factor_with_floor(n, entry, 0.0)
    }

    /// Like [`SmallCholesky::factor`], but a pivot must exceed `floor` (≥ 0) to count as
    /// positive.
    pub fn factor_with_floor(
        &mut self,
        n: usize,
        entry: impl Fn(usize, usize) -> f64,
        floor: f64,
    ) -> bool {
        self.n = 0;
        self.reserve(n);
        let s = self.stride;
        for i in 0..n {
            for j in 0..=i {
                let mut v = entry(i, j);
                for k in 0..j {
                    v -= self.l[i * s + k] * self.l[j * s + k];
                }
                if i == j {
                    if !(v > floor && v.is_finite()) {
                        return false;
                    }
                    self.l[i * s + i] = v.sqrt();
                    self.inv_diag[i] = 1.0 / self.l[i * s + i];
                } else {
                    self.l[i * s + j] = v / self.l[j * s + j];
                }
            }
        }
        self.n = n;
        true
    }

    /// Dimension of the factorised matrix.
    pub fn n(&self) -> usize {
        self.n
    }

    /// Solves `A x = b` in place (`b.len() == n`).
    pub fn solve_in_place(&self, b: &mut [f64]) {
        let (n, s) = (self.n, self.stride);
        debug_assert_eq!(b.len(), n);
        for i in 0..n {
            let row = &self.l[i * s..i * s + i];
            let mut v = b[i];
            for (lk, bk) in row.iter().zip(&b[..i]) {
                v -= lk * bk;
            }
            b[i] = v / self.l[i * s + i];
        }
        for i in (0..n).rev() {
            let mut v = b[i];
            for (k, bk) in b.iter().enumerate().take(n).skip(i + 1) {
                v -= self.l[k * s + i] * bk;
            }
            b[i] = v / self.l[i * s + i];
        }
    }

    /// `b ← L⁻¹ b` (the first half of a solve), with vectorised dot products: the same result
    /// as [`SmallCholesky::solve_in_place`]'s first half up to the order of rounding.
    #[inline(always)]
    pub fn forward_in_place(&self, b: &mut [f64]) {
        let (n, s) = (self.n, self.stride);
        debug_assert_eq!(b.len(), n);
        for i in 0..n {
            let v = b[i] - dot(&self.l[i * s..i * s + i], &b[..i]);
            b[i] = v * self.inv_diag[i];
        }
    }

    /// `b ← L⁻ᵀ b` (the second half of a solve), row by row with contiguous axpy updates.
    #[inline(always)]
    pub fn backward_in_place(&self, b: &mut [f64]) {
        let (n, s) = (self.n, self.stride);
        debug_assert_eq!(b.len(), n);
        for i in (0..n).rev() {
            let x = b[i] * self.inv_diag[i];
            b[i] = x;
            axpy(-x, &self.l[i * s..i * s + i], &mut b[..i]);
        }
    }

    /// Row `i` of L up to and including the diagonal (`i + 1` values).
    #[inline(always)]
    pub fn row(&self, i: usize) -> &[f64] {
        debug_assert!(i < self.n);
        &self.l[i * self.stride..i * self.stride + i + 1]
    }

    /// Writes `A⁻¹` (row-major, n × n) into `inv`, column by column.
    pub fn inverse_into(&self, inv: &mut [f64]) {
        let n = self.n;
        let mut col = vec![0.0; n];
        for c in 0..n {
            col.fill(0.0);
            col[c] = 1.0;
            self.solve_in_place(&mut col);
            for (i, v) in col.iter().enumerate() {
                inv[i * n + c] = *v;
            }
        }
    }

    /// Grows the factor of `A` to that of `[A r; rᵀ d]` (`r.len() == n`). Returns false, leaving
    /// the factor unchanged, if the result is not numerically positive definite.
    #[inline(always)]
    pub fn append(&mut self, r: &[f64], d: f64) -> bool {
        let n = self.n;
        debug_assert_eq!(r.len(), n);
        if n + 1 > self.stride {
            self.reserve((2 * self.stride).max(n + 1));
        }
        let s = self.stride;
        let (done, new) = self.l.split_at_mut(n * s);
        let new = &mut new[..n];
        for (i, &ri) in r.iter().enumerate().take(n) {
            let v = ri - dot(&done[i * s..i * s + i], &new[..i]);
            new[i] = v * self.inv_diag[i];
        }
        let p = d - dot(new, new);
        if !(p > 0.0 && p.is_finite()) {
            return false;
        }
        self.l[n * s + n] = p.sqrt();
        self.inv_diag[n] = 1.0 / self.l[n * s + n];
        self.n = n + 1;
        true
    }

    /// Shrinks the factor of `A` to that of `A` without row and column `p` (a rank-one update
    /// of the trailing block by Givens rotations, O((n − p)·n)).
    pub fn delete(&mut self, p: usize) {
        self.delete_rotating(p, &mut []);
    }

    /// Like [`SmallCholesky::delete`], and keeps `y = L⁻¹ c` current for a right-hand side `c`
    /// that loses its entry `p`: `y` (n values, or empty for none) becomes the n − 1 values of
    /// the new `L⁻¹ c` (the same rotations applied to it).
    #[inline(always)]
    pub fn delete_rotating(&mut self, p: usize, y: &mut [f64]) {
        let (n, s) = (self.n, self.stride);
        debug_assert!(p < n);
        debug_assert!(y.is_empty() || y.len() == n);
        // x = the dropped column below the diagonal; rows after p move up, columns left.
        let l = &mut self.l;
        // (Element loops, not `copy_within`: the rows are short, and a library call per row
        // cost more than the copy.)
        for i in p + 1..n {
            let x = l[i * s + p];
            let (dst, src) = ((i - 1) * s, i * s);
            for k in 0..p {
                l[dst + k] = l[src + k];
            }
            for k in p..i {
                l[dst + k] = l[src + k + 1];
            }
            // Keep x where the rotation below reads it: in the slot just past the new row.
            l[dst + i] = x;
        }
        let mut yx = 0.0;
        if !y.is_empty() {
            yx = y[p];
            for k in p..n - 1 {
                y[k] = y[k + 1];
            }
        }
        // Trailing block rows/cols p..n−1 (new indexing): L₂₂L₂₂ᵀ + x xᵀ; the rotation k
        // mixes column k with x so that x's entry k vanishes.
        let m = n - 1;
        for k in p..m {
            let lkk = l[k * s + k];
            let xk = l[k * s + k + 1];
            let r = (lkk * lkk + xk * xk).sqrt();
            let ir = 1.0 / r;
            let (c, sn) = (lkk * ir, xk * ir);
            l[k * s + k] = r;
            self.inv_diag[k] = ir;
            for i in k + 1..m {
                let (lik, xi) = (l[i * s + k], l[i * s + i + 1]);
                l[i * s + k] = c * lik + sn * xi;
                l[i * s + i + 1] = c * xi - sn * lik;
            }
            if !y.is_empty() {
                let yk = y[k];
                y[k] = c * yk + sn * yx;
                yx = c * yx - sn * yk;
            }
        }
        self.n = m;
    }
}

/// Inverse of a small symmetric positive definite matrix (row-major, f64) by Cholesky; `None`
/// if it is not numerically positive definite (a pivot ≤ 1e-13 · max |diagonal|).
pub fn spd_inverse(m: &[f64], n: usize) -> Option<Vec<f64>> {
    let scale = (0..n).map(|i| m[i * n + i].abs()).fold(0.0, f64::max);
    let mut c = SmallCholesky::default();
    if !c.factor_with_floor(n, |i, j| m[i * n + j], 1e-13 * scale) {
        return None;
    }
    let mut inv = vec![0.0; n * n];
    c.inverse_into(&mut inv);
    Some(inv)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn random_spd(rng: &mut Rng, n: usize) -> Vec<f64> {
        let m: Vec<f64> = (0..n * n).map(|_| rng.normal()).collect();
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                a[i * n + j] = (0..n).map(|k| m[k * n + i] * m[k * n + j]).sum::<f64>()
                    + f64::from(u8::from(i == j));
            }
        }
        a
    }

    fn mat_vec(a: &[f64], x: &[f64]) -> Vec<f64> {
        let n = x.len();
        (0..n)
            .map(|i| (0..n).map(|j| a[i * n + j] * x[j]).sum())
            .collect()
    }

    #[test]
    fn solves_spd_systems_and_rejects_indefinite_ones() {
        let mut rng = Rng::new(3);
        let n = 9;
        let a = random_spd(&mut rng, n);
        let mut c = SmallCholesky::default();
        assert!(c.factor(n, |i, j| a[i * n + j]));
        let x: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
        let mut b = mat_vec(&a, &x);
        c.solve_in_place(&mut b);
        for (bi, xi) in b.iter().zip(&x) {
            assert!((bi - xi).abs() < 1e-10);
        }
        assert!(!c.factor(2, |i, j| if i == j { 1.0 } else { 2.0 }));
        assert!(!c.factor(1, |_, _| f64::NAN));
    }

    #[test]
    fn spd_inverse_is_the_inverse_and_rejects_singular_matrices() {
        let mut rng = Rng::new(5);
        let n = 7;
        let a = random_spd(&mut rng, n);
        let inv = spd_inverse(&a, n).unwrap();
        for i in 0..n {
            for j in 0..n {
                let p: f64 = (0..n).map(|k| a[i * n + k] * inv[k * n + j]).sum();
                assert!(
                    (p - f64::from(u8::from(i == j))).abs() < 1e-10,
                    "({i},{j}) {p}"
                );
            }
        }
        // Rank one: the second pivot is at rounding level, below the 1e-13 floor.
        assert!(spd_inverse(&[1.0, 1.0, 1.0, 1.0 + 1e-15], 2).is_none());
        assert!(spd_inverse(&[f64::NAN], 1).is_none());
    }

    #[test]
    fn forward_backward_and_rotated_right_hand_sides_match_fresh_solves() {
        let mut rng = Rng::new(13);
        let n = 15;
        let a = random_spd(&mut rng, n);
        let c: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
        let mut cur: Vec<usize> = (0..n).collect();
        let mut f = SmallCholesky::default();
        assert!(f.factor(n, |i, j| a[i * n + j]));
        let mut y: Vec<f64> = c.clone();
        f.forward_in_place(&mut y);
        for p in [4usize, 0, 11, 3, 9, 0] {
            f.delete_rotating(p, &mut y);
            cur.remove(p);
            y.truncate(cur.len());
            let m = cur.len();
            let mut g = SmallCholesky::default();
            assert!(g.factor(m, |i, j| a[cur[i] * n + cur[j]]));
            let mut want: Vec<f64> = cur.iter().map(|&i| c[i]).collect();
            g.forward_in_place(&mut want);
            for (p, q) in y.iter().zip(&want) {
                assert!((p - q).abs() < 1e-10 * (1.0 + q.abs()), "{p} vs {q}");
            }
            // forward + backward is the solve.
            let mut x = y.clone();
            f.backward_in_place(&mut x);
            let mut x2: Vec<f64> = cur.iter().map(|&i| c[i]).collect();
            g.solve_in_place(&mut x2);
            for (p, q) in x.iter().zip(&x2) {
                assert!((p - q).abs() < 1e-9 * (1.0 + q.abs()), "{p} vs {q}");
            }
        }
    }

    #[test]
    fn appends_and_deletes_match_a_fresh_factorisation() {
        let mut rng = Rng::new(11);
        let n = 12;
        let a = random_spd(&mut rng, n);
        // Grow a factor over a permuted index list, then delete positions, comparing each
        // state with a fresh factorisation of the same principal submatrix (same order).
        let mut idx: Vec<usize> = vec![3, 0, 7, 11, 5, 1, 9, 2];
        let mut c = SmallCholesky::default();
        c.reserve(2);
        assert!(c.factor(0, |_, _| 0.0));
        let mut cur: Vec<usize> = Vec::new();
        let check = |c: &SmallCholesky, cur: &[usize]| {
            let m = cur.len();
            let mut f = SmallCholesky::default();
            assert!(f.factor(m, |i, j| a[cur[i] * n + cur[j]]));
            assert_eq!(c.n(), m);
            let b: Vec<f64> = (0..m).map(|i| (i as f64 * 0.7).sin() + 0.3).collect();
            let (mut x1, mut x2) = (b.clone(), b.clone());
            c.solve_in_place(&mut x1);
            f.solve_in_place(&mut x2);
            for (p, q) in x1.iter().zip(&x2) {
                assert!((p - q).abs() < 1e-10 * (1.0 + q.abs()), "{p} vs {q}");
            }
        };
        for &j in &idx {
            let r: Vec<f64> = cur.iter().map(|&k| a[j * n + k]).collect();
            assert!(c.append(&r, a[j * n + j]));
            cur.push(j);
            check(&c, &cur);
        }
        for p in [2usize, 0, 5, 4, 3] {
            c.delete(p);
            cur.remove(p);
            check(&c, &cur);
        }
        // Append after deletes, and delete the last and the only row.
        idx.truncate(0);
        let r: Vec<f64> = cur.iter().map(|&k| a[4 * n + k]).collect();
        assert!(c.append(&r, a[4 * n + 4]));
        cur.push(4);
        check(&c, &cur);
        let last = cur.len() - 1;
        c.delete(last);
        cur.pop();
        check(&c, &cur);
        while !cur.is_empty() {
            c.delete(0);
            cur.remove(0);
            check(&c, &cur);
        }
        // A row that makes the matrix singular is refused and leaves the factor as it was.
        assert!(c.append(&[], 2.0));
        assert!(!c.append(&[2.0], 1.0));
        assert_eq!(c.n(), 1);
    }
}
