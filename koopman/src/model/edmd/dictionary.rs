//! The polynomial dictionary of EDMD: `z = [x, 1, p_α(x̃) for 2 ≤ |α| ≤ d]`, all products of
//! per-variable polynomials of total degree 2..d of the scaled state `x̃ = (x − c) / h`.
//!
//! Together with `x` itself (the degree-1 terms up to an affine change) and the constant, the
//! features span exactly the polynomials of total degree ≤ d in x, `C(nx + d, d)` of them (231 for
//! nx = 2, d = 20). The per-variable polynomials are Chebyshev polynomials `T_k` by default: the
//! same span as the monomials `x̃^k` but a far better conditioned Gram matrix at high degree; the
//! monomial basis is available for comparison. `c` and `h` are the centre and half-range of the
//! training states, so the training data lies in `[−1, 1]`.

use serde::{Deserialize, Serialize};

/// Per-variable polynomial family of the dictionary.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Basis {
    /// Chebyshev polynomials of the first kind `T_k(x̃)` (default).
    #[default]
    Chebyshev,
    /// Plain powers `x̃^k`.
    Monomial,
}

/// A polynomial dictionary with its scaling.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Dictionary {
    /// State dimension.
    pub nx: usize,
    /// Total degree d.
    pub degree: usize,
    /// Polynomial family.
    pub basis: Basis,
    /// Centre of the scaling, per state component.
    pub center: Vec<f64>,
    /// Half-range of the scaling, per state component (> 0).
    pub half_width: Vec<f64>,
    /// Exponent vectors α (length nx) of the features after `[x, 1]`, in graded order.
    pub exponents: Vec<Vec<u16>>,
}

/// Number of polynomials of total degree ≤ d in nx variables, `C(nx + d, d)` (saturating).
pub fn feature_count(nx: usize, degree: usize) -> usize {
    let mut c: u128 = 1;
    for i in 1..=nx as u128 {
        c = c * (degree as u128 + i) / i;
        if c > usize::MAX as u128 {
            return usize::MAX;
        }
    }
    c as usize
}

/// The largest degree whose dictionary has at most `max_features` features (at least 1).
pub fn auto_degree(nx: usize, max_features: usize) -> usize {
    let mut d = 1;
    while d < 1000 && feature_count(nx, d + 1) <= max_features {
        d += 1;
    }
    d
}

/// All exponent vectors of total degree `2..=degree` in `nx` variables, graded then
/// lexicographically descending.
fn exponents(nx: usize, degree: usize) -> Vec<Vec<u16>> {
    fn rec(nx: usize, left: usize, cur: &mut Vec<u16>, out: &mut Vec<Vec<u16>>) {
        if cur.len() == nx - 1 {
            cur.push(left as u16);
            out.push(cur.clone());
            cur.pop();
            return;
        }
        for k in (0..=left).rev() {
            cur.push(k as u16);
            rec(nx, left - k, cur, out);
            cur.pop();
        }
    }
    let mut out = Vec::new();
    for total in 2..=degree {
        rec(nx, total, &mut Vec::with_capacity(nx), &mut out);
    }
    out
}

impl Dictionary {
    /// A dictionary of total degree `degree` scaled to the box `[lo, hi]` (per component).
    pub fn new(degree: usize, basis: Basis, lo: &[f64], hi: &[f64]) -> Dictionary {
        let nx = lo.len();
        let center = lo.iter().zip(hi).map(|(a, b)| 0.5 * (a + b)).collect();
        let half_width = lo
            .iter()
            .zip(hi)
            .map(|(a, b)| (0.5 * (b - a)).max(1e-12))
            .collect();
        Dictionary {
            nx,
            degree,
            basis,
            center,
            half_width,
            exponents: exponents(nx, degree),
        }
    }

    /// Number of features N (the latent dimension): `nx + 1 + exponents.len()`.
    pub fn len(&self) -> usize {
        self.nx + 1 + self.exponents.len()
    }

    /// Whether the dictionary is empty (never: it always holds x and the constant).
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Writes `z = Φ(x)` into `z` (`len()` values). `work` is scratch of `nx · (degree + 1)`.
    pub fn lift_into(&self, x: &[f64], z: &mut [f64], work: &mut [f64]) {
        let (nx, d1) = (self.nx, self.degree + 1);
        z[..nx].copy_from_slice(&x[..nx]);
        z[nx] = 1.0;
        for i in 0..nx {
            let s = (x[i] - self.center[i]) / self.half_width[i];
            let p = &mut work[i * d1..(i + 1) * d1];
            p[0] = 1.0;
            if d1 > 1 {
                p[1] = s;
            }
            for k in 2..d1 {
                p[k] = match self.basis {
                    Basis::Chebyshev => 2.0 * s * p[k - 1] - p[k - 2],
                    Basis::Monomial => s * p[k - 1],
                };
            }
        }
        for (zj, alpha) in z[nx + 1..].iter_mut().zip(&self.exponents) {
            let mut v = 1.0;
            for (i, &a) in alpha.iter().enumerate() {
                v *= work[i * d1 + a as usize];
            }
            *zj = v;
        }
    }

    /// Lifts a batch of states column-wise: for `m = states.len()`, column `j` of the
    /// column-major block `out[j·ld .. j·ld + m]` (`ld ≥ m`) receives feature j of every state.
    /// Same values as [`Dictionary::lift_into`], computed feature by feature over contiguous
    /// vectors. `work` is resized as needed.
    pub fn lift_columns(&self, states: &[&[f64]], out: &mut [f64], ld: usize, work: &mut Vec<f64>) {
        let (nx, d1, m) = (self.nx, self.degree + 1, states.len());
        work.resize(nx * d1 * m, 0.0);
        // work[(i·d1 + k)·m + r] = p_k(x̃_i) of state r.
        for i in 0..nx {
            let base = i * d1 * m;
            let (c, h) = (self.center[i], self.half_width[i]);
            for (r, x) in states.iter().enumerate() {
                work[base + r] = 1.0;
                if d1 > 1 {
                    work[base + m + r] = (x[i] - c) / h;
                }
            }
            for k in 2..d1 {
                let (done, rest) = work[base..].split_at_mut(k * m);
                let (s, prev) = (&done[m..2 * m], &done[(k - 1) * m..k * m]);
                let prev2 = &done[(k - 2) * m..(k - 1) * m];
                let dst = &mut rest[..m];
                match self.basis {
                    Basis::Chebyshev => {
                        for r in 0..m {
                            dst[r] = 2.0 * s[r] * prev[r] - prev2[r];
                        }
                    }
                    Basis::Monomial => {
                        for r in 0..m {
                            dst[r] = s[r] * prev[r];
                        }
                    }
                }
            }
        }
        for i in 0..nx {
            for (r, x) in states.iter().enumerate() {
                out[i * ld + r] = x[i];
            }
        }
        out[nx * ld..nx * ld + m].fill(1.0);
        for (j, alpha) in self.exponents.iter().enumerate() {
            let col = &mut out[(nx + 1 + j) * ld..(nx + 1 + j) * ld + m];
            let first = &work[alpha[0] as usize * m..(alpha[0] as usize + 1) * m];
            col.copy_from_slice(first);
            for (i, &a) in alpha.iter().enumerate().skip(1) {
                let o = (i * d1 + a as usize) * m;
                for (v, p) in col.iter_mut().zip(&work[o..o + m]) {
                    *v *= p;
                }
            }
        }
    }

    /// `Φ(x)` as a new vector.
    pub fn lift(&self, x: &[f64]) -> Vec<f64> {
        let mut z = vec![0.0; self.len()];
        let mut work = vec![0.0; self.nx * (self.degree + 1)];
        self.lift_into(x, &mut z, &mut work);
        z
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn column_lifting_equals_pointwise_lifting() {
        for (nx, d, basis) in [
            (2, 20, Basis::Chebyshev),
            (3, 5, Basis::Monomial),
            (1, 7, Basis::Chebyshev),
        ] {
            let dict = Dictionary::new(d, basis, &vec![-3.0; nx], &vec![2.0; nx]);
            let mut rng = crate::rng::Rng::new(1);
            let xs: Vec<Vec<f64>> = (0..37)
                .map(|_| (0..nx).map(|_| rng.uniform(-4.0, 3.0)).collect())
                .collect();
            let refs: Vec<&[f64]> = xs.iter().map(|v| v.as_slice()).collect();
            let ld = 40;
            let mut out = vec![f64::NAN; ld * dict.len()];
            let mut work = Vec::new();
            dict.lift_columns(&refs, &mut out, ld, &mut work);
            for (r, x) in xs.iter().enumerate() {
                let z = dict.lift(x);
                for (j, zj) in z.iter().enumerate() {
                    let got = out[j * ld + r];
                    assert!(
                        (got - zj).abs() <= 1e-12 * zj.abs().max(1.0),
                        "nx {nx} row {r} feature {j}: {got} vs {zj}"
                    );
                }
            }
        }
    }

    #[test]
    fn counts_match_the_binomial_and_the_spec_choice() {
        assert_eq!(feature_count(2, 20), 231);
        assert_eq!(feature_count(4, 6), 210);
        assert_eq!(auto_degree(2, 250), 20);
        assert_eq!(auto_degree(4, 250), 6);
        assert_eq!(auto_degree(3, 250), 9);
        for (nx, d) in [(1, 5), (2, 20), (3, 4), (4, 6)] {
            let dict = Dictionary::new(d, Basis::Chebyshev, &vec![-1.0; nx], &vec![1.0; nx]);
            assert_eq!(dict.len(), feature_count(nx, d), "nx {nx} d {d}");
            let mut seen = dict.exponents.clone();
            seen.sort();
            seen.dedup();
            assert_eq!(seen.len(), dict.exponents.len(), "duplicate exponents");
        }
    }

    #[test]
    fn features_are_the_products_of_chebyshev_and_monomial_values() {
        let lo = [-2.0, 0.0];
        let hi = [2.0, 8.0];
        let x = [0.7, 5.5];
        let s = [0.35, (5.5 - 4.0) / 4.0];
        for basis in [Basis::Chebyshev, Basis::Monomial] {
            let dict = Dictionary::new(6, basis, &lo, &hi);
            let z = dict.lift(&x);
            assert_eq!(&z[..3], &[0.7, 5.5, 1.0]);
            for (j, a) in dict.exponents.iter().enumerate() {
                let f = |v: f64, k: u16| match basis {
                    // T_k(cos θ) = cos(kθ): an independent closed form on [−1, 1].
                    Basis::Chebyshev => (k as f64 * v.acos()).cos(),
                    Basis::Monomial => v.powi(k as i32),
                };
                let expect = f(s[0], a[0]) * f(s[1], a[1]);
                assert!(
                    (z[3 + j] - expect).abs() < 1e-12,
                    "{a:?}: {} vs {expect}",
                    z[3 + j]
                );
            }
        }
    }
}
