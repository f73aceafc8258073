//! A small dense Cholesky factorisation on a contiguous row-major buffer, single-threaded: the
//! hot path of the box-QP solver factorises blocks of a few dozen rows, where a threaded
//! library call costs more in synchronisation than the arithmetic itself.

/// `A = L Lᵀ` with L lower triangular, stored row-major in `l` (n × n, upper part unused).
#[derive(Clone, Debug, Default)]
pub struct SmallCholesky {
    n: usize,
    l: Vec<f64>,
}

impl SmallCholesky {
    /// Factorises the symmetric matrix given by `entry(i, j)` (only `j ≤ i` is read).
    /// Returns false if it is not numerically positive definite.
    pub fn factor(&mut self, n: usize, entry: impl Fn(usize, usize) -> f64) -> bool {
        self.n = n;
        self.l.clear();
        self.l.resize(n * n, 0.0);
        for i in 0..n {
            for j in 0..=i {
                let (ri, rj) = (i * n, j * n);
                let dot: f64 = self.l[ri..ri + j]
                    .iter()
                    .zip(&self.l[rj..rj + j])
                    .map(|(a, b)| a * b)
                    .sum();
                let v = entry(i, j) - dot;
                if i == j {
                    if !(v > 0.0 && v.is_finite()) {
                        return false;
                    }
                    self.l[ri + i] = v.sqrt();
                } else {
                    self.l[ri + j] = v / self.l[rj + j];
                }
            }
        }
        true
    }

    /// Dimension of the factorised matrix.
    pub fn n(&self) -> usize {
        self.n
    }

    /// Solves `A x = b` in place (`b.len() == n`).
    pub fn solve_in_place(&self, b: &mut [f64]) {
        let n = self.n;
        for i in 0..n {
            let r = i * n;
            let dot: f64 = self.l[r..r + i]
                .iter()
                .zip(&b[..i])
                .map(|(a, b)| a * b)
                .sum();
            b[i] = (b[i] - dot) / self.l[r + i];
        }
        for i in (0..n).rev() {
            let s: f64 = b[i + 1..]
                .iter()
                .enumerate()
                .map(|(k, bk)| self.l[(i + 1 + k) * n + i] * bk)
                .sum();
            b[i] = (b[i] - s) / self.l[i * n + i];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn solves_spd_systems_and_rejects_indefinite_ones() {
        let mut rng = Rng::new(3);
        let n = 9;
        let m: Vec<f64> = (0..n * n).map(|_| rng.normal()).collect();
        // A = MᵀM + I is SPD.
        let a = |i: usize, j: usize| {
            (0..n).map(|k| m[k * n + i] * m[k * n + j]).sum::<f64>() + f64::from(u8::from(i == j))
        };
        let mut c = SmallCholesky::default();
        assert!(c.factor(n, a));
        let x: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
        let mut b: Vec<f64> = (0..n)
            .map(|i| (0..n).map(|j| a(i, j) * x[j]).sum())
            .collect();
        c.solve_in_place(&mut b);
        for (bi, xi) in b.iter().zip(&x) {
            assert!((bi - xi).abs() < 1e-10);
        }
        assert!(!c.factor(2, |i, j| if i == j { 1.0 } else { 2.0 }));
        assert!(!c.factor(1, |_, _| f64::NAN));
    }
}
