//! SPEC.md's initialisation of a neural Koopman model, drawn from the seeded [`Rng`].

use super::arch::Arch;
use crate::rng::Rng;
use crate::{Error, Result};
use faer::Mat;

/// Fresh f64 parameters for `arch` (flat, in [`Arch::layout`] order):
/// every block's weights and biases `U(±1/√fan_in)` (torch's `nn.Linear` default), except the
/// last block's main weight, which is orthogonal with gain 1 (QR of a Gaussian matrix with the
/// sign fix of `torch.nn.init.orthogonal_`); `A = 0.9·U Vᵀ` from the SVD of `W ~ N(0, (1/N)²)`;
/// `B ~ U(±1/√nu)`.
pub fn init_params(arch: &Arch, rng: &mut Rng) -> Result<Vec<f64>> {
    arch.check()?;
    let layout = arch.layout();
    let mut p = vec![0.0; layout.len];
    let last = layout.blocks.len() - 1;
    for (l, blk) in layout.blocks.iter().enumerate() {
        let bound = 1.0 / (blk.fan_in as f64).sqrt();
        let nw = blk.rows() * blk.fan_in;
        for v in &mut p[blk.w..blk.w + nw] {
            *v = rng.uniform(-bound, bound);
        }
        for v in &mut p[blk.b..blk.b + blk.rows()] {
            *v = rng.uniform(-bound, bound);
        }
        if l == last {
            let q = orthogonal(blk.out, blk.fan_in, rng)?;
            for i in 0..blk.out {
                for j in 0..blk.fan_in {
                    p[blk.w + i * blk.fan_in + j] = q[(i, j)];
                }
            }
        }
    }
    let n = arch.latent_dim();
    let w = Mat::from_fn(n, n, |_, _| rng.normal() / n as f64);
    let svd = w
        .svd()
        .map_err(|e| Error::Numerical(format!("SVD for the initial A failed: {e:?}")))?;
    let a = svd.U() * svd.V().transpose();
    for i in 0..n {
        for j in 0..n {
            p[layout.a + i * n + j] = 0.9 * a[(i, j)];
        }
    }
    if arch.nu > 0 {
        let bound = 1.0 / (arch.nu as f64).sqrt();
        for v in &mut p[layout.b..layout.b + n * arch.nu] {
            *v = rng.uniform(-bound, bound);
        }
    }
    Ok(p)
}

/// A `rows × cols` matrix with orthonormal rows (rows ≤ cols) or columns (rows ≥ cols), as
/// `torch.nn.init.orthogonal_(gain = 1)` builds it.
pub fn orthogonal(rows: usize, cols: usize, rng: &mut Rng) -> Result<Mat<f64>> {
    let (r, c) = if rows < cols {
        (cols, rows)
    } else {
        (rows, cols)
    };
    let g = Mat::from_fn(r, c, |_, _| rng.normal());
    let qr = g.qr();
    let mut q = qr.compute_thin_Q();
    let rr = qr.thin_R();
    for j in 0..c {
        if rr[(j, j)] < 0.0 {
            for i in 0..r {
                q[(i, j)] = -q[(i, j)];
            }
        }
    }
    Ok(if rows < cols {
        q.transpose().to_owned()
    } else {
        q
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn initial_a_is_scaled_orthogonal_and_last_block_weight_has_orthonormal_rows() {
        let arch = Arch::new(2, 1, &[16, 16], 4).unwrap();
        let p = init_params(&arch, &mut Rng::new(3)).unwrap();
        let lay = arch.layout();
        let n = arch.latent_dim();
        let a = Mat::from_fn(n, n, |i, j| p[lay.a + i * n + j]);
        let ata = a.transpose() * &a;
        for i in 0..n {
            for j in 0..n {
                let want = if i == j { 0.81 } else { 0.0 };
                assert!(
                    (ata[(i, j)] - want).abs() < 1e-12,
                    "AᵀA[{i},{j}] = {}",
                    ata[(i, j)]
                );
            }
        }
        let blk = *lay.blocks.last().unwrap();
        let w = Mat::from_fn(blk.out, blk.fan_in, |i, j| p[blk.w + i * blk.fan_in + j]);
        let wwt = &w * w.transpose();
        for i in 0..blk.out {
            for j in 0..blk.out {
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((wwt[(i, j)] - want).abs() < 1e-12);
            }
        }
        // Uniform layers stay within their bound, and B uses fan_in = nu.
        let b0 = lay.blocks[0];
        let bound = 1.0 / (b0.fan_in as f64).sqrt();
        assert!(p[b0.w..b0.b + b0.rows()].iter().all(|v| v.abs() <= bound));
        assert!(p[lay.b..lay.len].iter().all(|v| v.abs() <= 1.0));
        // Same seed, same parameters; another seed, others.
        assert_eq!(p, init_params(&arch, &mut Rng::new(3)).unwrap());
        assert_ne!(p, init_params(&arch, &mut Rng::new(4)).unwrap());
    }
}
