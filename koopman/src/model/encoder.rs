//! Batched forward and backward passes of the residual encoder `ψ`, on preallocated buffers.
//!
//! Every block computes `y = ReLU(W x + b) + R(x)` for all rows (states) at once: one GEMM of the
//! rows against the stacked `[W; R]`, then one fused pass adds the biases, applies the ReLU and
//! the residual. Buffers are column-major with leading dimension = the number of rows in use, so
//! a smaller batch (e.g. the last validation chunk) reuses the same memory.

use super::arch::{Arch, Layout};
use super::scalar::Real;
use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};

/// Preallocated activations and gradients of the encoder for up to `capacity` rows.
pub struct EncoderWs<T: Real> {
    layout: Layout,
    widths: Vec<usize>,
    capacity: usize,
    rows: usize,
    /// `acts[0]` is the input (rows × nx), `acts[l+1]` the output of block l.
    acts: Vec<Vec<T>>,
    /// Pre-activations `[W;R] x + [b;r]` of block l (rows × stacked rows); reused for their
    /// gradient in the backward pass.
    pre: Vec<Vec<T>>,
    /// `grads[l]` is the gradient w.r.t. `acts[l]` (l ≥ 1; `grads[0]` is never formed).
    grads: Vec<Vec<T>>,
    par: Par,
}

/// A column-major `rows × cols` view of the first `rows·cols` values of `buf`.
#[inline]
pub fn view<T: Real>(buf: &[T], rows: usize, cols: usize) -> MatRef<'_, T> {
    MatRef::from_column_major_slice(&buf[..rows * cols], rows, cols)
}

/// Mutable version of [`view`].
#[inline]
pub fn view_mut<T: Real>(buf: &mut [T], rows: usize, cols: usize) -> MatMut<'_, T> {
    MatMut::from_column_major_slice_mut(&mut buf[..rows * cols], rows, cols)
}

impl<T: Real> EncoderWs<T> {
    /// Buffers for `capacity` rows of `arch`'s encoder; `par` is used for the large products.
    pub fn new(arch: &Arch, capacity: usize, par: Par) -> Self {
        let layout = arch.layout();
        let widths = arch.widths.clone();
        let acts = widths
            .iter()
            .map(|&w| vec![T::default(); capacity * w])
            .collect();
        let pre = layout
            .blocks
            .iter()
            .map(|b| vec![T::default(); capacity * b.rows()])
            .collect();
        let grads = widths
            .iter()
            .enumerate()
            .map(|(l, &w)| {
                if l == 0 {
                    Vec::new()
                } else {
                    vec![T::default(); capacity * w]
                }
            })
            .collect();
        EncoderWs {
            layout,
            widths,
            capacity,
            rows: capacity,
            acts,
            pre,
            grads,
            par,
        }
    }

    /// Maximum number of rows.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Rows of the last forward pass.
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Sets the number of rows of the next pass (≤ capacity) and returns the input buffer
    /// (column-major, `rows × nx`) to fill.
    pub fn input_mut(&mut self, rows: usize) -> &mut [T] {
        assert!(
            rows <= self.capacity,
            "encoder workspace holds {} rows",
            self.capacity
        );
        self.rows = rows;
        let nx = self.widths[0];
        &mut self.acts[0][..rows * nx]
    }

    /// The input of the last pass (rows × nx).
    pub fn input(&self) -> MatRef<'_, T> {
        view(&self.acts[0], self.rows, self.widths[0])
    }

    /// The encoder output ψ of the last forward pass (rows × n_enc, column-major).
    pub fn output(&self) -> MatRef<'_, T> {
        let l = self.widths.len() - 1;
        view(&self.acts[l], self.rows, self.widths[l])
    }

    /// Buffer for the gradient w.r.t. ψ (rows × n_enc, column-major), to fill before
    /// [`EncoderWs::backward`].
    pub fn output_grad_mut(&mut self) -> MatMut<'_, T> {
        let l = self.widths.len() - 1;
        view_mut(&mut self.grads[l], self.rows, self.widths[l])
    }

    /// Forward pass over the rows set by [`EncoderWs::input_mut`], with parameters `params`
    /// (flat, [`Arch::layout`] order).
    pub fn forward(&mut self, params: &[T]) {
        let rows = self.rows;
        for (l, blk) in self.layout.blocks.iter().enumerate() {
            let (prev, rest) = self.acts.split_at_mut(l + 1);
            let x = &prev[l][..rows * blk.fan_in];
            let y = &mut rest[0][..rows * blk.out];
            let k = blk.rows();
            let pre = &mut self.pre[l][..rows * k];
            let w =
                MatRef::from_row_major_slice(&params[blk.w..blk.w + k * blk.fan_in], k, blk.fan_in);
            matmul(
                view_mut(pre, rows, k),
                Accum::Replace,
                view(x, rows, blk.fan_in),
                w.transpose(),
                T::one(),
                self.par,
            );
            let bias = &params[blk.b..blk.b + k];
            for j in 0..blk.out {
                let bj = bias[j];
                let (main, res) = pre.split_at_mut(blk.out * rows);
                let pj = &mut main[j * rows..(j + 1) * rows];
                let yj = &mut y[j * rows..(j + 1) * rows];
                if blk.linear_residual {
                    let rj = bias[blk.out + j];
                    let qj = &res[j * rows..(j + 1) * rows];
                    for ((yv, pv), qv) in yj.iter_mut().zip(pj.iter_mut()).zip(qj) {
                        *pv += bj;
                        *yv = pv.relu() + *qv + rj;
                    }
                } else {
                    let xj = &x[j * rows..(j + 1) * rows];
                    for ((yv, pv), xv) in yj.iter_mut().zip(pj.iter_mut()).zip(xj) {
                        *pv += bj;
                        *yv = pv.relu() + *xv;
                    }
                }
            }
        }
    }

    /// Backward pass after [`EncoderWs::forward`] and a filled [`EncoderWs::output_grad_mut`]:
    /// writes (overwrites) the encoder's parameter gradients into `grad` (flat, same layout as
    /// the parameters). The gradient w.r.t. the input is not formed. Destroys the stored
    /// pre-activations.
    pub fn backward(&mut self, params: &[T], grad: &mut [T]) {
        let rows = self.rows;
        for (l, blk) in self.layout.blocks.iter().enumerate().rev() {
            let k = blk.rows();
            let (gprev, grest) = self.grads.split_at_mut(l + 1);
            let dy = &grest[0][..rows * blk.out];
            let pre = &mut self.pre[l][..rows * k];
            // dpre = [dY ⊙ (pre > 0), dY] in place of pre, and the bias gradients with it.
            {
                let (main, res) = pre.split_at_mut(blk.out * rows);
                let gb = &mut grad[blk.b..blk.b + k];
                for j in 0..blk.out {
                    let pj = &mut main[j * rows..(j + 1) * rows];
                    let dj = &dy[j * rows..(j + 1) * rows];
                    gb[j] = T::mask_and_sum(pj, dj);
                    if blk.linear_residual {
                        res[j * rows..(j + 1) * rows].copy_from_slice(dj);
                        gb[blk.out + j] = T::sum(dj);
                    }
                }
            }
            let x = &self.acts[l][..rows * blk.fan_in];
            // d[W;R] (k × fan_in, row-major) = dpreᵀ x, i.e. column-major (fan_in × k) = xᵀ dpre.
            matmul(
                MatMut::from_column_major_slice_mut(
                    &mut grad[blk.w..blk.w + k * blk.fan_in],
                    blk.fan_in,
                    k,
                ),
                Accum::Replace,
                view(x, rows, blk.fan_in).transpose(),
                view(pre, rows, k),
                T::one(),
                self.par,
            );
            if l == 0 {
                break;
            }
            let dx = &mut gprev[l][..rows * blk.fan_in];
            let w =
                MatRef::from_row_major_slice(&params[blk.w..blk.w + k * blk.fan_in], k, blk.fan_in);
            let accum = if blk.linear_residual {
                Accum::Replace
            } else {
                dx.copy_from_slice(dy);
                Accum::Add
            };
            matmul(
                view_mut(dx, rows, blk.fan_in),
                accum,
                view(pre, rows, k),
                w,
                T::one(),
                self.par,
            );
        }
    }
}
