//! The NNDM's prediction error over a whole dataset (SPEC's metric, the test `L_pred`, with the
//! same normalisation as the Koopman model's): roll the model out from every window's first
//! state with the window's inputs, in chunks, the window ranges split over threads.

use crate::data::Dataset;
use crate::model::nndm::mlp::MlpBufs;
use crate::model::nndm::{NndmArch, NndmModel};
use crate::model::scalar::Real;
use crate::train::eval::check_dataset;
use crate::{Error, Result};
use faer::Par;
use rayon::prelude::*;

/// One worker's buffers: the MLP for `chunk` rows and the predicted states (`chunk × nx`).
struct Worker<T: Real> {
    mlp: MlpBufs<T>,
    xh: Vec<T>,
}

/// Buffers to evaluate an NNDM's `L_pred` over datasets, `chunk` windows at a time per worker.
pub struct NndmEval<T: Real> {
    arch: NndmArch,
    chunk: usize,
    workers: Vec<Worker<T>>,
}

impl<T: Real> NndmEval<T> {
    /// Buffers for `arch`, `chunk` windows at a time; `Par::Rayon(k)` evaluates `k` window
    /// ranges in parallel.
    pub fn new(arch: &NndmArch, chunk: usize, par: Par) -> Self {
        let chunk = chunk.max(1);
        let k = match par {
            Par::Seq => 1,
            Par::Rayon(k) => k.get().max(1),
        };
        let workers = (0..k)
            .map(|_| Worker {
                mlp: MlpBufs::new(arch, chunk, 0),
                xh: vec![T::default(); chunk * arch.nx],
            })
            .collect();
        NndmEval {
            arch: arch.clone(),
            chunk,
            workers,
        }
    }

    /// `L_pred = (1/W) Σ_k γ^k mean((x̂_{k+1} − x_{k+1})²)` over every window of `data`, with
    /// `x̂_0 = x_0`; the mean is over all windows and state dimensions.
    pub fn pred_loss(&mut self, params: &[T], data: &Dataset, gamma: f64) -> Result<f64> {
        let (nx, nu) = (self.arch.nx, self.arch.nu);
        check_dataset(data, nx, nu)?;
        let len = self.arch.num_params();
        if params.len() != len {
            return Err(Error::dimension("parameter vector", len, params.len()));
        }
        let steps = data.steps;
        let k = self.workers.len().min(data.n);
        let bounds: Vec<usize> = (0..=k).map(|p| p * data.n / k).collect();
        let chunk = self.chunk;
        let sums: Vec<Vec<f64>> = self.workers[..k]
            .par_iter_mut()
            .zip(bounds.par_windows(2))
            .map(|(w, range)| w.sums(params, data, range[0], range[1], chunk, nx))
            .collect();
        let wsum: f64 = (0..steps).map(|k| gamma.powi(k as i32)).sum();
        let denom = (data.n * nx) as f64;
        let loss = (0..steps)
            .map(|t| gamma.powi(t as i32) * sums.iter().map(|s| s[t]).sum::<f64>() / denom)
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

impl<T: Real> Worker<T> {
    /// Per step t, `Σ (x̂_{t+1} − x_{t+1})²` over windows `lo..hi` and every state dimension.
    fn sums(
        &mut self,
        params: &[T],
        data: &Dataset,
        lo: usize,
        hi: usize,
        chunk: usize,
        nx: usize,
    ) -> Vec<f64> {
        let steps = data.steps;
        let mut sums = vec![0.0; steps];
        let ld = self.mlp.ld();
        let mut start = lo;
        while start < hi {
            let r = chunk.min(hi - start);
            for i in 0..r {
                for (j, &v) in data.state(start + i, 0).iter().enumerate() {
                    self.xh[j * r + i] = T::from_f64(v);
                }
            }
            for (t, sum) in sums.iter_mut().enumerate() {
                let inp = self.mlp.input_mut();
                for i in 0..r {
                    for j in 0..nx {
                        inp[j * ld + i] = self.xh[j * r + i];
                    }
                    for (j, &v) in data.input(start + i, t).iter().enumerate() {
                        inp[(nx + j) * ld + i] = T::from_f64(v);
                    }
                }
                self.mlp.forward_block(params, 0, r);
                let out = self.mlp.output();
                let mut s = 0.0;
                for j in 0..nx {
                    for i in 0..r {
                        let v = self.xh[j * r + i] + out[j * ld + i];
                        self.xh[j * r + i] = v;
                        let diff = v.to_f64() - data.state(start + i, t + 1)[j];
                        s += diff * diff;
                    }
                }
                *sum += s;
            }
            start += r;
        }
        sums
    }
}

/// SPEC's prediction error of an NNDM on `data` (f64, all threads).
pub fn prediction_error(model: &NndmModel, data: &Dataset, gamma: f64) -> Result<f64> {
    NndmEval::<f64>::new(model.arch(), 1024, Par::rayon(0)).pred_loss(model.params(), data, gamma)
}
