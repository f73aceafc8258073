//! A model trained on z-scored data, presented exactly in raw units: the affine change of
//! coordinates is folded into A and B with one constant latent coordinate.
//!
//! The inner model works on `x_n = (x − μx)/σx`, `u_n = (u − μu)/σu`:
//! `z = Φ(x_n)`, `z⁺ = A z + B u_n`, with `x_n = P z`. With `M = diag(σx, 1, …, 1)` and
//! `c = [μx, 0, …, 0]`, the raw latent state `w = [M z + c, 1]` starts with x itself and evolves as
//! `w⁺ = A_w w + B_w u` with
//! `A_w = [[M A M⁻¹, d], [0, 1]]`, `B_w = [[M B D⁻¹], [0]]`, `D = diag(σu)`,
//! `d = c − M A M⁻¹ c − M B D⁻¹ μu`. Every consumer of [`LiftedModel`] (the MPC, the services,
//! the Python bindings) then sees states, references, weights and bounds in raw units.

use super::LiftedModel;
use crate::data::Normalisation;
use crate::{Error, Result};
use faer::Mat;

/// A [`LiftedModel`] in normalised coordinates, seen in raw units (latent dimension N + 1).
pub struct RawUnits {
    inner: Box<dyn LiftedModel>,
    norm: Normalisation,
    a: Mat<f64>,
    b: Mat<f64>,
}

impl RawUnits {
    /// Wraps `inner`, which works in the coordinates of `norm`.
    pub fn new(inner: Box<dyn LiftedModel>, norm: Normalisation) -> Result<Self> {
        norm.check(inner.nx(), inner.nu())?;
        let (nx, nu, n) = (inner.nx(), inner.nu(), inner.latent_dim());
        if n < nx {
            return Err(Error::InvalidArgument(format!(
                "latent dimension {n} is smaller than the state dimension {nx}"
            )));
        }
        let scale = |i: usize| if i < nx { norm.x_std[i] } else { 1.0 };
        let shift = |i: usize| if i < nx { norm.x_mean[i] } else { 0.0 };
        let (a_n, b_n) = (inner.a(), inner.b());
        let mut a = Mat::<f64>::zeros(n + 1, n + 1);
        let mut b = Mat::<f64>::zeros(n + 1, nu);
        for i in 0..n {
            // Row i of M A M⁻¹ and of M B D⁻¹, and of d.
            let mut mam_c = 0.0;
            for j in 0..n {
                let v = scale(i) * a_n[(i, j)] / scale(j);
                a[(i, j)] = v;
                mam_c += v * shift(j);
            }
            let mut mbd_mu = 0.0;
            for k in 0..nu {
                let v = scale(i) * b_n[(i, k)] / norm.u_std[k];
                b[(i, k)] = v;
                mbd_mu += v * norm.u_mean[k];
            }
            a[(i, n)] = shift(i) - mam_c - mbd_mu;
        }
        a[(n, n)] = 1.0;
        Ok(RawUnits { inner, norm, a, b })
    }

    /// The z-scoring of the inner model.
    pub fn normalisation(&self) -> &Normalisation {
        &self.norm
    }
}

impl LiftedModel for RawUnits {
    fn nx(&self) -> usize {
        self.inner.nx()
    }
    fn nu(&self) -> usize {
        self.inner.nu()
    }
    fn latent_dim(&self) -> usize {
        self.inner.latent_dim() + 1
    }
    fn a(&self) -> Mat<f64> {
        self.a.clone()
    }
    fn b(&self) -> Mat<f64> {
        self.b.clone()
    }
    /// `[x, ψ(x_n), 1]`; panics if `x.len() != nx` (as every [`LiftedModel::lift`]).
    fn lift(&self, x: &[f64]) -> Vec<f64> {
        let mut xn = x.to_vec();
        self.norm.state_in_place(&mut xn);
        let mut w = self.inner.lift(&xn);
        w[..x.len()].copy_from_slice(x);
        w.push(1.0);
        w
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::arch::Arch;
    use crate::model::koopman::KoopmanModel;
    use crate::rng::Rng;

    fn model_and_norm() -> (KoopmanModel, Normalisation) {
        let arch = Arch {
            nx: 3,
            nu: 2,
            widths: vec![3, 8, 6],
        };
        let model = KoopmanModel::init(arch, 7).unwrap();
        let norm = Normalisation {
            x_mean: vec![0.5, -2.0, 10.0],
            x_std: vec![2.0, 0.1, 30.0],
            u_mean: vec![1.0, -0.3],
            u_std: vec![4.0, 0.05],
        };
        (model, norm)
    }

    /// One step of the normalised model done by hand: normalise, lift, A z + B u_n, take x_n,
    /// de-normalise.
    fn reference_step(m: &KoopmanModel, n: &Normalisation, x: &[f64], u: &[f64]) -> Vec<f64> {
        let mut xn = x.to_vec();
        n.state_in_place(&mut xn);
        let mut un = u.to_vec();
        n.input_in_place(&mut un);
        let z = m.lift(&xn);
        let (a, b) = (m.a(), m.b());
        (0..x.len())
            .map(|i| {
                let zi: f64 = (0..z.len()).map(|j| a[(i, j)] * z[j]).sum::<f64>()
                    + (0..u.len()).map(|k| b[(i, k)] * un[k]).sum::<f64>();
                n.x_mean[i] + n.x_std[i] * zi
            })
            .collect()
    }

    #[test]
    fn raw_units_reproduce_the_normalised_model_over_several_steps() {
        let (m, n) = model_and_norm();
        let raw = RawUnits::new(Box::new(m.clone()), n.clone()).unwrap();
        assert_eq!(raw.latent_dim(), m.latent_dim() + 1);
        let mut rng = Rng::new(3);
        let mut x: Vec<f64> = (0..3)
            .map(|i| n.x_mean[i] + n.x_std[i] * (rng.uniform01() - 0.5))
            .collect();
        let mut w = raw.lift(&x);
        assert_eq!(&w[..3], &x[..]);
        assert_eq!(*w.last().unwrap(), 1.0);
        let (a, b) = (raw.a(), raw.b());
        for _ in 0..5 {
            let u: Vec<f64> = (0..2)
                .map(|k| n.u_mean[k] + n.u_std[k] * (rng.uniform01() - 0.5))
                .collect();
            // The raw model propagates its own latent state, re-lifted from the hand-made
            // reference state so that both take exactly one step from the same x.
            w = raw.lift(&x);
            let next: Vec<f64> = (0..w.len())
                .map(|i| {
                    (0..w.len()).map(|j| a[(i, j)] * w[j]).sum::<f64>()
                        + (0..2).map(|k| b[(i, k)] * u[k]).sum::<f64>()
                })
                .collect();
            let want = reference_step(&m, &n, &x, &u);
            for i in 0..3 {
                let tol = 1e-11 * (1.0 + want[i].abs());
                assert!((next[i] - want[i]).abs() < tol, "{i}: {next:?} vs {want:?}");
            }
            assert!((next[w.len() - 1] - 1.0).abs() < 1e-15);
            x = want;
        }
    }

    #[test]
    fn a_normalisation_of_the_wrong_size_is_refused() {
        let (m, mut n) = model_and_norm();
        n.u_std.pop();
        assert!(matches!(
            RawUnits::new(Box::new(m), n),
            Err(Error::Dimension { .. })
        ));
    }
}
