//! The pseudo-inverse algebra of the inverse-control loss: the gradient that flows through
//! `pinv(B) = (BᵀB)⁻¹Bᵀ`, and the inverse of the small SPD matrix `BᵀB`.

use faer::MatRef;

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

/// Inverse of a small symmetric positive definite matrix (row-major, f64) by Cholesky; `None`
/// if it is not numerically positive definite.
pub fn spd_inverse(m: &[f64], n: usize) -> Option<Vec<f64>> {
    let mut l = vec![0.0; n * n];
    let scale = (0..n).map(|i| m[i * n + i].abs()).fold(0.0, f64::max);
    for i in 0..n {
        for j in 0..=i {
            let mut s = m[i * n + j];
            for k in 0..j {
                s -= l[i * n + k] * l[j * n + k];
            }
            if i == j {
                if s.is_nan() || s <= 1e-13 * scale || !s.is_finite() {
                    return None;
                }
                l[i * n + i] = s.sqrt();
            } else {
                l[i * n + j] = s / l[j * n + j];
            }
        }
    }
    // inv = L⁻ᵀ L⁻¹, column by column.
    let mut inv = vec![0.0; n * n];
    for col in 0..n {
        let mut y = vec![0.0; n];
        for i in 0..n {
            let mut s = if i == col { 1.0 } else { 0.0 };
            for k in 0..i {
                s -= l[i * n + k] * y[k];
            }
            y[i] = s / l[i * n + i];
        }
        for i in (0..n).rev() {
            let mut s = y[i];
            for k in i + 1..n {
                s -= l[k * n + i] * inv[k * n + col];
            }
            inv[i * n + col] = s / l[i * n + i];
        }
    }
    Some(inv)
}
