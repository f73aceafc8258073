//! The pseudo-inverse algebra of the inverse-control loss: the gradient that flows through
//! `pinv(B) = (BᵀB)⁻¹Bᵀ`; the inverse of the small SPD matrix `BᵀB` is
//! [`crate::linalg::spd_inverse`], re-exported here for the losses.

use faer::MatRef;

pub use crate::linalg::spd_inverse;
use crate::model::scalar::Real;

/// Adds the gradient of the loss w.r.t. B that flows through `P = pinv(B) = (BᵀB)⁻¹Bᵀ`:
/// `dL/dB = (I − B P) G_Pᵀ M⁻¹ − Pᵀ G_P Pᵀ`, with `G_P = dL/dP` (nu × N, row-major, f64),
/// `M⁻¹ = (BᵀB)⁻¹` (nu × nu, f64); `gb` is dL/dB (N × nu, row-major).
pub(crate) fn pinv_backward<T: Real>(
    gp: &[f64],
    p: &[T],
    bm: MatRef<'_, T>,
    minv: &[f64],
    nu: usize,
    nn: usize,
    gb: &mut [T],
) {
    // X1 = G_Pᵀ M⁻¹ (N × nu).
    let mut x1 = vec![0.0; nn * nu];
    for c in 0..nn {
        for r in 0..nu {
            let mut s = 0.0;
            for k in 0..nu {
                s += gp[k * nn + c] * minv[k * nu + r];
            }
            x1[c * nu + r] = s;
        }
    }
    // PX1 = P X1 (nu × nu); GPPt = G_P Pᵀ (nu × nu).
    let mut px1 = vec![0.0; nu * nu];
    let mut gppt = vec![0.0; nu * nu];
    for r in 0..nu {
        for c in 0..nu {
            let (mut s1, mut s2) = (0.0, 0.0);
            for k in 0..nn {
                s1 += p[r * nn + k].to_f64() * x1[k * nu + c];
                s2 += gp[r * nn + k] * p[c * nn + k].to_f64();
            }
            px1[r * nu + c] = s1;
            gppt[r * nu + c] = s2;
        }
    }
    for c in 0..nn {
        for r in 0..nu {
            let mut s = x1[c * nu + r];
            for k in 0..nu {
                s -= bm[(c, k)].to_f64() * px1[k * nu + r];
                s -= p[k * nn + c].to_f64() * gppt[k * nu + r];
            }
            gb[c * nu + r] += T::from_f64(s);
        }
    }
}
