//! Conditioning and spectra of lifted models: κ of the latent Gram matrix on data, κ(BᵀB), and
//! the eigenvalues of A.

use crate::data::Dataset;
use crate::model::LiftedModel;
use crate::{Error, Result};
use faer::{c64, Mat, MatRef, Side};

/// 2-norm condition number `λ_max / λ_min` of a symmetric positive semi-definite matrix
/// (infinite when it is singular).
pub fn spd_condition(m: MatRef<'_, f64>) -> Result<f64> {
    if m.nrows() != m.ncols() || m.nrows() == 0 {
        return Err(Error::dimension(
            "square matrix (rows vs columns)",
            m.nrows(),
            m.ncols(),
        ));
    }
    let ev = m
        .self_adjoint_eigenvalues(Side::Lower)
        .map_err(|e| Error::Numerical(format!("symmetric eigenvalues: {e:?}")))?;
    let max = ev.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let min = ev.iter().cloned().fold(f64::INFINITY, f64::min);
    if !max.is_finite() || !min.is_finite() {
        return Err(Error::NonFinite("matrix eigenvalues".into()));
    }
    if min <= 0.0 {
        return Ok(f64::INFINITY);
    }
    Ok(max / min)
}

/// κ(G) of the latent Gram matrix `G = (1/K) Σ z zᵀ` over the lifted states `z = Φ(x)` of every
/// state of every window of `data` (K = n·(T+1)).
pub fn gram_condition(model: &dyn LiftedModel, data: &Dataset) -> Result<f64> {
    super::prediction::check_states(model, data)?;
    let n_lat = model.latent_dim();
    let states = data.x.chunks_exact(data.nx);
    let k = states.len();
    // Lift in row-major chunks and accumulate Zᵀ Z with GEMM.
    let mut g = Mat::<f64>::zeros(n_lat, n_lat);
    let chunk = 2048;
    let mut buf = Vec::with_capacity(chunk * n_lat);
    let all: Vec<&[f64]> = states.collect();
    for block in all.chunks(chunk) {
        buf.clear();
        for s in block {
            let z = model.lift(s);
            if z.len() != n_lat {
                return Err(Error::dimension("lifted state", n_lat, z.len()));
            }
            buf.extend_from_slice(&z);
        }
        let z = MatRef::from_row_major_slice(&buf, block.len(), n_lat);
        faer::linalg::matmul::matmul(
            g.as_mut(),
            faer::Accum::Add,
            z.transpose(),
            z,
            1.0 / k as f64,
            faer::Par::rayon(0),
        );
    }
    let sym = Mat::from_fn(n_lat, n_lat, |i, j| 0.5 * (g[(i, j)] + g[(j, i)]));
    spd_condition(sym.as_ref())
}

/// κ(BᵀB) of the model's input matrix (nu × nu); an error for autonomous models (nu = 0).
pub fn bbt_condition(model: &dyn LiftedModel) -> Result<f64> {
    if model.nu() == 0 {
        return Err(Error::InvalidArgument(
            "κ(BᵀB) is undefined for a model without inputs".into(),
        ));
    }
    let b = model.b();
    let btb = b.transpose() * &b;
    spd_condition(btb.as_ref())
}

/// The eigenvalues of a square matrix (e.g. the model's A), sorted by decreasing modulus.
pub fn eigenvalues(a: MatRef<'_, f64>) -> Result<Vec<c64>> {
    if a.nrows() != a.ncols() {
        return Err(Error::dimension(
            "square matrix (rows vs columns)",
            a.nrows(),
            a.ncols(),
        ));
    }
    if a.col_iter().any(|c| c.iter().any(|v| !v.is_finite())) {
        return Err(Error::NonFinite("matrix for eigenvalues".into()));
    }
    let mut ev = a
        .eigenvalues()
        .map_err(|e| Error::Numerical(format!("eigenvalues: {e:?}")))?;
    ev.sort_by(|x, y| y.norm().total_cmp(&x.norm()));
    Ok(ev)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::{Dataset, DatasetMeta, Pairing};

    /// z = [x, 1] with a fixed B: everything has a closed form.
    struct Affine {
        b: Mat<f64>,
    }

    impl LiftedModel for Affine {
        fn nx(&self) -> usize {
            1
        }
        fn nu(&self) -> usize {
            self.b.ncols()
        }
        fn latent_dim(&self) -> usize {
            2
        }
        fn a(&self) -> Mat<f64> {
            Mat::identity(2, 2)
        }
        fn b(&self) -> Mat<f64> {
            self.b.clone()
        }
        fn lift(&self, x: &[f64]) -> Vec<f64> {
            vec![x[0], 1.0]
        }
    }

    #[test]
    fn gram_condition_matches_the_closed_form_2x2() {
        let xs = [0.5, 1.5, 2.0, 3.0, -1.0, 0.25];
        let data = Dataset {
            n: 2,
            steps: 2,
            nx: 1,
            nu: 1,
            x: xs.to_vec(),
            u: vec![0.0; 4],
            meta: DatasetMeta {
                env: "t".into(),
                dt: 1.0,
                state_names: vec!["x".into()],
                input_names: vec!["u".into()],
                pairing: Pairing::Aligned,
                seed: 0,
                source: "t".into(),
                policy: "t".into(),
                region: None,
                window_flags: None,
            },
        };
        let m = Affine {
            b: Mat::from_fn(2, 1, |i, _| i as f64 + 1.0),
        };
        let n = xs.len() as f64;
        let (m1, m2) = (
            xs.iter().sum::<f64>() / n,
            xs.iter().map(|v| v * v).sum::<f64>() / n,
        );
        // Eigenvalues of [[m2, m1], [m1, 1]].
        let (tr, det) = (m2 + 1.0, m2 - m1 * m1);
        let disc = (tr * tr / 4.0 - det).sqrt();
        let want = (tr / 2.0 + disc) / (tr / 2.0 - disc);
        let got = gram_condition(&m, &data).unwrap();
        assert!((got - want).abs() < 1e-10 * want, "{got} vs {want}");
    }

    #[test]
    fn bbt_condition_and_spd_condition_closed_forms() {
        let m = Affine {
            b: Mat::from_fn(2, 2, |i, j| if i == j { (i + 1) as f64 } else { 0.0 }),
        };
        assert!((bbt_condition(&m).unwrap() - 4.0).abs() < 1e-12);
        let singular = Affine {
            b: Mat::from_fn(2, 2, |i, _| i as f64 + 1.0),
        };
        assert!(bbt_condition(&singular).unwrap() > 1e12);
        let none = Affine {
            b: Mat::zeros(2, 0),
        };
        assert!(bbt_condition(&none).is_err());
        // Q diag(1, 4, 100) Qᵀ with a rotation Q has κ = 100.
        let (c, s) = (0.6, 0.8);
        let q = Mat::from_fn(3, 3, |i, j| match (i, j) {
            (0, 0) | (1, 1) => c,
            (0, 1) => -s,
            (1, 0) => s,
            (2, 2) => 1.0,
            _ => 0.0,
        });
        let d = Mat::from_fn(3, 3, |i, j| if i == j { [1.0, 4.0, 100.0][i] } else { 0.0 });
        let g = &q * &d * q.transpose();
        assert!((spd_condition(g.as_ref()).unwrap() - 100.0).abs() < 1e-9);
    }

    #[test]
    fn eigenvalues_of_a_rotation_block_sorted_by_modulus() {
        let (r, th) = (0.95f64, 0.3f64);
        let a = Mat::from_fn(3, 3, |i, j| match (i, j) {
            (0, 0) | (1, 1) => r * th.cos(),
            (0, 1) => -r * th.sin(),
            (1, 0) => r * th.sin(),
            (2, 2) => -0.5,
            _ => 0.0,
        });
        let ev = eigenvalues(a.as_ref()).unwrap();
        assert_eq!(ev.len(), 3);
        assert!((ev[0].norm() - r).abs() < 1e-12 && (ev[1].norm() - r).abs() < 1e-12);
        assert!((ev[0].re - r * th.cos()).abs() < 1e-12);
        assert!((ev[0].im.abs() - r * th.sin()).abs() < 1e-12);
        assert!((ev[2].re + 0.5).abs() < 1e-12 && ev[2].im.abs() < 1e-12);
        assert!(eigenvalues(Mat::<f64>::zeros(2, 3).as_ref()).is_err());
    }
}
