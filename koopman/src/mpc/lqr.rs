//! LQR on the lifted model (the reference code's pendulum/arm controller): the infinite-horizon
//! gain from the discrete Riccati iteration, with the feed-forward `pinv(B)(Φ(r⁺) − AΦ(r))`.

use faer::linalg::solvers::Solve;
use faer::{Mat, Side};

use crate::error::{ensure_finite, Error, Result};
use crate::model::LiftedModel;

/// The converged (or last) Riccati solution and its gain.
pub struct Lqr {
    /// Feedback gain K (nu × N): `u = u_ff − K (z − z_ref)`.
    pub k: Mat<f64>,
    /// Riccati iterations used.
    pub iterations: usize,
    /// True if the relative change of the Riccati matrix, or of the gain, fell below the
    /// tolerance.
    pub converged: bool,
    /// The Riccati matrix `P` (N × N) the gain was computed from: the cost-to-go `zᵀPz` from a
    /// lifted state, its own stage cost included.
    pub p: Mat<f64>,
    a: Mat<f64>,
    pinv_b: Mat<f64>,
}

impl Lqr {
    /// Iterates `P ← Q_z + AᵀPA − AᵀPB (R + BᵀPB)⁻¹ BᵀPA` from `P = Q_z = PᵀQP` until the relative
    /// change is below `tol` (or `max_iterations`). `q` (nx) and `r` (nu, > 0 for a well-posed
    /// gain; 0 is replaced by `1e-9·max(BᵀPB)`) are diagonal weights.
    pub fn new(
        model: &dyn LiftedModel,
        q: &[f64],
        r: &[f64],
        max_iterations: usize,
        tol: f64,
    ) -> Result<Self> {
        let (nx, nu, n) = (model.nx(), model.nu(), model.latent_dim());
        if q.len() != nx {
            return Err(Error::dimension("LQR Q diagonal", nx, q.len()));
        }
        if r.len() != nu {
            return Err(Error::dimension("LQR R diagonal", nu, r.len()));
        }
        if q.iter().chain(r).any(|v| !(v.is_finite() && *v >= 0.0)) {
            return Err(Error::InvalidArgument(
                "LQR weights must be finite and ≥ 0".into(),
            ));
        }
        let a = model.a();
        let b = model.b();
        let qz = Mat::from_fn(n, n, |i, j| if i == j && i < nx { q[i] } else { 0.0 });
        let mut p = qz.clone();
        let mut k = Mat::<f64>::zeros(nu, n);
        let (mut iterations, mut converged) = (0, false);
        for it in 0..max_iterations {
            iterations = it + 1;
            let pb = &p * &b; // N × nu
            let pa = &p * &a; // N × N
            let mut s = b.transpose() * &pb; // nu × nu
            let smax = (0..nu).map(|i| s[(i, i)]).fold(0.0f64, f64::max);
            for i in 0..nu {
                s[(i, i)] += if r[i] > 0.0 {
                    r[i]
                } else {
                    1e-9 * smax.max(1e-300)
                };
            }
            let rhs = b.transpose() * &pa; // nu × N
            let llt = s
                .llt(Side::Lower)
                .map_err(|_| Error::Numerical("LQR: R + BᵀPB is not positive definite".into()))?;
            let k_prev = std::mem::replace(&mut k, llt.solve(&rhs));
            let k_diff = (&k - &k_prev).norm_max();
            let k_scale = k.norm_max();
            let mut pn = &qz + a.transpose() * &pa - rhs.transpose() * &k;
            // Keep P symmetric.
            for i in 0..n {
                for j in 0..i {
                    let v = 0.5 * (pn[(i, j)] + pn[(j, i)]);
                    pn[(i, j)] = v;
                    pn[(j, i)] = v;
                }
            }
            let diff = (&pn - &p).norm_max();
            let scale = pn.norm_max().max(1e-300);
            if !scale.is_finite() {
                return Err(Error::Numerical(
                    "LQR: the Riccati iteration diverged".into(),
                ));
            }
            p = pn;
            // Converged when P stops changing, or when the gain does: a lifted constant that
            // the input cannot move and the cost sees through an affine offset (EDMD's degree-1
            // dictionary) makes P's constant-constant entry grow by the same amount every
            // iteration while K and every other entry of P settle — and that entry multiplies a
            // deviation that is always zero.
            if diff <= tol * scale || (it > 0 && k_diff <= tol * k_scale.max(1e-300)) {
                converged = true;
                break;
            }
        }
        let pinv_b = pseudo_inverse(&b)?;
        Ok(Lqr {
            k,
            iterations,
            converged,
            p,
            a,
            pinv_b,
        })
    }

    /// The input `u_ff − K(z − z_ref)` with `u_ff = pinv(B)(z_ref_next − A z_ref)`.
    pub fn control(&self, z: &[f64], z_ref: &[f64], z_ref_next: &[f64]) -> Result<Vec<f64>> {
        let n = self.a.nrows();
        for (what, v) in [
            ("lifted state", z),
            ("lifted reference", z_ref),
            ("next lifted reference", z_ref_next),
        ] {
            if v.len() != n {
                return Err(Error::dimension(what, n, v.len()));
            }
            ensure_finite(what, v)?;
        }
        let nu = self.k.nrows();
        let resid: Vec<f64> = (0..n)
            .map(|i| z_ref_next[i] - (0..n).map(|j| self.a[(i, j)] * z_ref[j]).sum::<f64>())
            .collect();
        Ok((0..nu)
            .map(|i| {
                let ff: f64 = (0..n).map(|j| self.pinv_b[(i, j)] * resid[j]).sum();
                let fb: f64 = (0..n).map(|j| self.k[(i, j)] * (z[j] - z_ref[j])).sum();
                ff - fb
            })
            .collect())
    }
}

/// Moore–Penrose pseudo-inverse of a tall matrix via its SVD (small singular values cut).
fn pseudo_inverse(b: &Mat<f64>) -> Result<Mat<f64>> {
    let svd = b
        .thin_svd()
        .map_err(|_| Error::Numerical("SVD of B failed".into()))?;
    let (u, s, v) = (svd.U(), svd.S(), svd.V());
    let s = s.column_vector();
    let smax = (0..s.nrows()).map(|i| s[i]).fold(0.0f64, f64::max);
    let cut = smax * 1e-12 * b.nrows().max(b.ncols()) as f64;
    Ok(Mat::from_fn(b.ncols(), b.nrows(), |i, j| {
        (0..s.nrows())
            .filter(|&l| s[l] > cut)
            .map(|l| v[(i, l)] * u[(j, l)] / s[l])
            .sum()
    }))
}
