//! The prediction error (SPEC's metric, the test `L_pred`) over a whole dataset, encoding only
//! each window's first state, in chunks.

use crate::data::Dataset;
use crate::model::arch::Arch;
use crate::model::encoder::{view, view_mut, EncoderWs};
use crate::model::scalar::Real;
use crate::{Error, Result};
use faer::linalg::matmul::matmul;
use faer::reborrow::ReborrowMut;
use faer::{Accum, MatRef, Par};

/// Buffers to evaluate `L_pred` over datasets in chunks of up to `chunk` windows.
pub struct PredEval<T: Real> {
    arch: Arch,
    chunk: usize,
    enc: EncoderWs<T>,
    zc: Vec<T>,
    zn: Vec<T>,
    uk: Vec<T>,
    /// Bilinear dynamics (the parameters end with N_1..N_nu); `tmp` is its scratch.
    bil: bool,
    tmp: Vec<T>,
}

impl<T: Real> PredEval<T> {
    /// Buffers for `arch`, `chunk` windows at a time; `par` for the encoder.
    pub fn new(arch: &Arch, chunk: usize, par: Par) -> Self {
        Self::with_dynamics(arch, chunk, par, false)
    }

    /// Like [`PredEval::new`]; with `bilinear` the rollout is `ẑ⁺ = A ẑ + B u + Σ_i u_i N_i ẑ`
    /// and parameter vectors end with the N_i (see [`super::bilinear`]).
    pub fn with_dynamics(arch: &Arch, chunk: usize, par: Par, bilinear: bool) -> Self {
        let chunk = chunk.max(1);
        let nn = arch.latent_dim();
        PredEval {
            arch: arch.clone(),
            chunk,
            enc: EncoderWs::new(arch, chunk, par),
            zc: vec![T::default(); chunk * nn],
            zn: vec![T::default(); chunk * nn],
            uk: vec![T::default(); chunk * arch.nu],
            bil: bilinear,
            tmp: vec![T::default(); if bilinear { chunk * nn } else { 0 }],
        }
    }

    /// `L_pred = (1/W) Σ_k γ^k mean((P ẑ_{k+1} − x_{k+1})²)` over every window of `data`, with
    /// `ẑ_0 = Φ(x_0)`; the mean is over all windows and state dimensions.
    pub fn pred_loss(&mut self, params: &[T], data: &Dataset, gamma: f64) -> Result<f64> {
        let (nx, nu, nn) = (self.arch.nx, self.arch.nu, self.arch.latent_dim());
        check_dataset(data, nx, nu)?;
        let lay = self.arch.layout();
        let total = lay.len + if self.bil { nu * nn * nn } else { 0 };
        if params.len() != total {
            return Err(Error::dimension("parameter vector", total, params.len()));
        }
        let d = self.arch.n_enc();
        let steps = data.steps;
        let a = MatRef::from_row_major_slice(&params[lay.a..lay.a + nn * nn], nn, nn);
        let bm = MatRef::from_row_major_slice(&params[lay.b..lay.len], nn, nu);
        let dynamics = super::bilinear::Dynamics {
            a,
            b: bm,
            n: &params[lay.len..],
        };
        let mut sums = vec![0.0f64; steps];
        let mut start = 0;
        while start < data.n {
            let r = self.chunk.min(data.n - start);
            {
                let inp = self.enc.input_mut(r);
                for i in 0..r {
                    let s = data.state(start + i, 0);
                    for j in 0..nx {
                        inp[j * r + i] = T::from_f64(s[j]);
                    }
                }
            }
            self.enc.forward(params);
            {
                let mut zc = view_mut(&mut self.zc, r, nn);
                zc.rb_mut().subcols_mut(0, nx).copy_from(self.enc.input());
                zc.subcols_mut(nx, d).copy_from(self.enc.output());
            }
            for (k, sum) in sums.iter_mut().enumerate() {
                for i in 0..r {
                    let u = data.input(start + i, k);
                    for (j, &uj) in u.iter().enumerate() {
                        self.uk[j * r + i] = T::from_f64(uj);
                    }
                }
                {
                    let mut zn = view_mut(&mut self.zn, r, nn);
                    matmul(
                        zn.rb_mut(),
                        Accum::Replace,
                        view(&self.zc, r, nn),
                        a.transpose(),
                        T::one(),
                        Par::Seq,
                    );
                    if nu > 0 {
                        matmul(
                            zn.rb_mut(),
                            Accum::Add,
                            view(&self.uk, r, nu),
                            bm.transpose(),
                            T::one(),
                            Par::Seq,
                        );
                    }
                    if self.bil {
                        dynamics.add_forward(
                            zn,
                            view(&self.zc, r, nn),
                            view(&self.uk, r, nu),
                            &mut self.tmp,
                        );
                    }
                }
                let mut s = 0.0;
                for j in 0..nx {
                    let col = &self.zn[j * r..(j + 1) * r];
                    for (i, v) in col.iter().enumerate() {
                        let diff = v.to_f64() - data.state(start + i, k + 1)[j];
                        s += diff * diff;
                    }
                }
                *sum += s;
                std::mem::swap(&mut self.zc, &mut self.zn);
            }
            start += r;
        }
        let wsum: f64 = (0..steps).map(|k| gamma.powi(k as i32)).sum();
        let denom = (data.n * nx) as f64;
        let loss = sums
            .iter()
            .enumerate()
            .map(|(k, s)| gamma.powi(k as i32) * s / denom)
            .sum::<f64>()
            / wsum;
        if !loss.is_finite() {
            return Err(Error::NonFinite(
                "prediction error (the model diverges on this data)".into(),
            ));
        }
        Ok(loss)
    }
}

/// Checks that `data` has `nx` states and `nu` inputs, at least one window and transition,
/// consistent buffer sizes and only finite values.
pub fn check_dataset(data: &Dataset, nx: usize, nu: usize) -> Result<()> {
    if data.nx != nx {
        return Err(Error::dimension("dataset state dimension nx", nx, data.nx));
    }
    if data.nu != nu {
        return Err(Error::dimension("dataset input dimension nu", nu, data.nu));
    }
    if data.n == 0 || data.steps == 0 {
        return Err(Error::InvalidArgument(format!(
            "dataset '{}' is empty ({} windows of {} transitions)",
            data.meta.env, data.n, data.steps
        )));
    }
    let nxv = data.n * (data.steps + 1) * nx;
    if data.x.len() != nxv {
        return Err(Error::dimension("dataset x values", nxv, data.x.len()));
    }
    let nuv = data.n * data.steps * nu;
    if data.u.len() != nuv {
        return Err(Error::dimension("dataset u values", nuv, data.u.len()));
    }
    crate::error::ensure_finite("dataset states x", &data.x)?;
    crate::error::ensure_finite("dataset inputs u", &data.u)?;
    Ok(())
}
