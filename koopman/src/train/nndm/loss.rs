//! The NNDM's multi-step discounted prediction loss (SPEC's `L_pred`, normalised exactly as the
//! Koopman model's) and its gradient by backpropagation through time, written by hand.
//!
//! The rollout starts at the true first state, `x̂_0 = x_0`, and applies the model with the
//! window's inputs: `x̂_{t+1} = x̂_t + g([x̂_t, u_t])`. The loss is
//! `L = (1/W) Σ_t γ^t mean((x̂_{t+1} − x_{t+1})²)` (mean over batch and state dimensions,
//! `W = Σ γ^t`). Backward: with `D_{t+1} = dL/dx̂_{t+1}`,
//! `D_t = 2c_{t−1}(x̂_t − x_t) + D_{t+1} + [J_g(x̂_t, u_t)ᵀ D_{t+1}]_x`.
//!
//! The batch's windows are split into parts (one per thread), each with its own buffers; rows
//! of a part's matrices are time-major (row `t·b_p + i` = step t of window i), so the weight
//! gradients are one GEMM over all steps.

use crate::data::Dataset;
use crate::model::nndm::mlp::MlpBufs;
use crate::model::nndm::NndmArch;
use crate::model::scalar::Real;
use crate::{Error, Result};
use faer::Par;
use rayon::prelude::*;

/// The buffers of one part of the batch.
struct Part<T: Real> {
    /// Windows in this part.
    b: usize,
    mlp: MlpBufs<T>,
    /// True states, column-major `((T+1)·b) × nx`.
    x: Vec<T>,
    /// Predicted states, same shape.
    xh: Vec<T>,
    /// `D` (column-major `b × nx`).
    d: Vec<T>,
    /// This part's parameter gradient.
    grad: Vec<T>,
}

/// Every buffer one loss-and-gradient evaluation of an NNDM needs, allocated once.
pub struct NndmLossWs<T: Real> {
    arch: NndmArch,
    /// Windows per batch.
    pub b: usize,
    /// Transitions per window.
    pub steps: usize,
    parts: Vec<Part<T>>,
    /// First window of each part.
    starts: Vec<usize>,
}

impl<T: Real> NndmLossWs<T> {
    /// Buffers for batches of `b` windows of `steps` transitions. With `Par::Rayon(k)` the
    /// windows are split into `k` parts computed on `k` threads (sequential products inside a
    /// part); `Par::Seq` uses one part.
    pub fn new(arch: &NndmArch, b: usize, steps: usize, par: Par) -> Self {
        let nparts = match par {
            Par::Seq => 1,
            Par::Rayon(k) => k.get().clamp(1, b.max(1)),
        };
        let starts: Vec<usize> = (0..=nparts).map(|p| p * b / nparts).collect();
        let (nx, len) = (arch.nx, arch.num_params());
        let parts = starts
            .windows(2)
            .map(|w| {
                let bp = w[1] - w[0];
                Part {
                    b: bp,
                    mlp: MlpBufs::new(arch, steps * bp, bp),
                    x: vec![T::default(); (steps + 1) * bp * nx],
                    xh: vec![T::default(); (steps + 1) * bp * nx],
                    d: vec![T::default(); bp * nx],
                    grad: vec![T::default(); if nparts > 1 { len } else { 0 }],
                }
            })
            .collect();
        NndmLossWs {
            arch: arch.clone(),
            b,
            steps,
            parts,
            starts,
        }
    }

    /// Loads windows `windows[i]` of `data` as the batch (`windows.len()` must be `b`).
    pub fn fill(&mut self, data: &Dataset, windows: &[usize]) -> Result<()> {
        let (nx, nu, steps) = (self.arch.nx, self.arch.nu, self.steps);
        if windows.len() != self.b {
            return Err(Error::dimension("batch windows", self.b, windows.len()));
        }
        if data.nx != nx || data.nu != nu || data.steps != steps {
            return Err(Error::InvalidArgument(format!(
                "batch data has nx = {}, nu = {}, T = {}; the workspace expects {nx}, {nu}, {steps}",
                data.nx, data.nu, data.steps
            )));
        }
        if let Some(&w) = windows.iter().find(|&&w| w >= data.n) {
            return Err(Error::InvalidArgument(format!(
                "window {w} out of range ({} windows)",
                data.n
            )));
        }
        for (part, s) in self.parts.iter_mut().zip(&self.starts) {
            let bp = part.b;
            let rows = (steps + 1) * bp;
            let ld = part.mlp.ld();
            let inp = part.mlp.input_mut();
            for (i, &w) in windows[*s..*s + bp].iter().enumerate() {
                for t in 0..=steps {
                    for (j, &v) in data.state(w, t).iter().enumerate() {
                        part.x[j * rows + t * bp + i] = T::from_f64(v);
                    }
                }
                for t in 0..steps {
                    for (j, &v) in data.input(w, t).iter().enumerate() {
                        inp[(nx + j) * ld + t * bp + i] = T::from_f64(v);
                    }
                }
            }
        }
        Ok(())
    }

    /// The prediction loss of the loaded batch; its gradient w.r.t. every parameter is written
    /// into `grad` (overwritten, parameter layout).
    pub fn loss_and_grad(&mut self, params: &[T], grad: &mut [T], gamma: f64) -> Result<f64> {
        let len = self.arch.num_params();
        if params.len() != len || grad.len() != len {
            return Err(Error::dimension(
                "parameter vector",
                len,
                params.len().min(grad.len()),
            ));
        }
        let (nx, steps, b) = (self.arch.nx, self.steps, self.b);
        let weights: Vec<f64> = (0..steps).map(|k| gamma.powi(k as i32)).collect();
        let wsum: f64 = weights.iter().sum();
        let coefs: Vec<f64> = weights
            .iter()
            .map(|w| w / (wsum * (b * nx) as f64))
            .collect();
        let run = |part: &mut Part<T>, g: &mut [T]| part_loss(part, params, g, nx, steps, &coefs);
        if self.parts.len() == 1 {
            return Ok(run(&mut self.parts[0], grad));
        }
        let losses: Vec<f64> = self
            .parts
            .par_iter_mut()
            .map(|p| {
                let mut g = std::mem::take(&mut p.grad);
                let l = run(p, &mut g);
                p.grad = g;
                l
            })
            .collect();
        grad.copy_from_slice(&self.parts[0].grad);
        for p in &self.parts[1..] {
            for (a, v) in grad.iter_mut().zip(&p.grad) {
                *a += *v;
            }
        }
        Ok(losses.iter().sum())
    }
}

/// Forward rollout, loss and backward pass of one part; returns its share of the loss.
fn part_loss<T: Real>(
    part: &mut Part<T>,
    params: &[T],
    grad: &mut [T],
    nx: usize,
    steps: usize,
    coefs: &[f64],
) -> f64 {
    let bp = part.b;
    let rows = (steps + 1) * bp;
    let ld = part.mlp.ld();
    // Forward: x̂_0 = x_0, x̂_{t+1} = x̂_t + g([x̂_t, u_t]).
    for j in 0..nx {
        part.xh[j * rows..j * rows + bp].copy_from_slice(&part.x[j * rows..j * rows + bp]);
    }
    for t in 0..steps {
        let inp = part.mlp.input_mut();
        for j in 0..nx {
            inp[j * ld + t * bp..j * ld + (t + 1) * bp]
                .copy_from_slice(&part.xh[j * rows + t * bp..j * rows + (t + 1) * bp]);
        }
        part.mlp.forward_block(params, t * bp, bp);
        let out = part.mlp.output();
        for j in 0..nx {
            for i in 0..bp {
                let c = j * rows + t * bp + i;
                part.xh[c + bp] = part.xh[c] + out[j * ld + t * bp + i];
            }
        }
    }
    // Backward through time.
    part.d.fill(T::default());
    let mut loss = 0.0;
    for t in (0..steps).rev() {
        let c2 = T::from_f64(2.0 * coefs[t]);
        let mut s = 0.0;
        {
            let out = part.mlp.output_mut();
            for j in 0..nx {
                for i in 0..bp {
                    let r = j * rows + (t + 1) * bp + i;
                    let diff = part.xh[r] - part.x[r];
                    s += diff.to_f64() * diff.to_f64();
                    let dv = &mut part.d[j * bp + i];
                    *dv += c2 * diff;
                    out[j * ld + t * bp + i] = *dv;
                }
            }
        }
        loss += coefs[t] * s;
        if let Some(gin) = part.mlp.backward_block(params, t * bp, bp, t > 0) {
            for j in 0..nx {
                for i in 0..bp {
                    part.d[j * bp + i] += gin[(i, j)];
                }
            }
        }
    }
    part.mlp.param_grads(steps * bp, grad, Par::Seq);
    loss
}
