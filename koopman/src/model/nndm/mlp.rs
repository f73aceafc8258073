//! Batched forward and backward passes of the NNDM's MLP on preallocated column-major buffers,
//! one block of rows at a time (a block = the rows of one time step of a batch).
//!
//! Every buffer has `ld` rows per column; a block is the row range `row0..row0 + r` of every
//! column, so the blocks of all time steps of a rollout live in one matrix per layer and the
//! weight gradients are one GEMM over all of them.

use super::arch::{LayerLayout, NndmArch};
use crate::model::scalar::Real;
use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};

/// Rows `row0..row0 + r` of the column-major `ld × cols` matrix in `buf`.
#[inline]
pub fn block<T: Real>(buf: &[T], ld: usize, cols: usize, row0: usize, r: usize) -> MatRef<'_, T> {
    MatRef::from_column_major_slice(&buf[..ld * cols], ld, cols).subrows(row0, r)
}

/// Mutable version of [`block`].
#[inline]
pub fn block_mut<T: Real>(
    buf: &mut [T],
    ld: usize,
    cols: usize,
    row0: usize,
    r: usize,
) -> MatMut<'_, T> {
    MatMut::from_column_major_slice_mut(&mut buf[..ld * cols], ld, cols).subrows_mut(row0, r)
}

/// Activations, pre-activations and gradient scratch of the MLP for `ld` rows.
pub struct MlpBufs<T: Real> {
    layers: Vec<LayerLayout>,
    ld: usize,
    max_block: usize,
    /// `acts[l]` is the input of layer l (`ld × fan_in`); `acts[0]` = `[x, u]`.
    acts: Vec<Vec<T>>,
    /// `pre[l] = a_l W_lᵀ + b_l` (`ld × out`); the last one is the MLP's output. The backward
    /// pass replaces them by their gradients.
    pre: Vec<Vec<T>>,
    /// Gradient w.r.t. one layer's input for one block (`max_block × max fan_in`, ld = block rows).
    dact: Vec<T>,
}

impl<T: Real> MlpBufs<T> {
    /// Buffers for `ld` rows in blocks of at most `max_block` rows.
    pub fn new(arch: &NndmArch, ld: usize, max_block: usize) -> Self {
        let layers = arch.layout();
        let acts = layers
            .iter()
            .map(|l| vec![T::default(); ld * l.fan_in])
            .collect();
        let pre = layers
            .iter()
            .map(|l| vec![T::default(); ld * l.out])
            .collect();
        let max_in = layers.iter().map(|l| l.fan_in).max().unwrap_or(0);
        MlpBufs {
            layers,
            ld,
            max_block,
            acts,
            pre,
            dact: vec![T::default(); max_block * max_in],
        }
    }

    /// Rows per column of every buffer.
    pub fn ld(&self) -> usize {
        self.ld
    }

    /// The input buffer `[x, u]` (column-major, `ld × (nx + nu)`), to fill before a forward pass.
    pub fn input_mut(&mut self) -> &mut [T] {
        &mut self.acts[0]
    }

    /// The output (or, after [`MlpBufs::set_output_grad`], its gradient): column-major
    /// `ld × nx`.
    pub fn output(&self) -> &[T] {
        self.pre.last().expect("at least one layer")
    }

    /// The output buffer, to write `dL/d(output)` into before [`MlpBufs::backward_block`].
    pub fn output_mut(&mut self) -> &mut [T] {
        self.pre.last_mut().expect("at least one layer")
    }

    /// Forward pass of rows `row0..row0 + r` with parameters `params` (flat,
    /// [`NndmArch::layout`] order); the input block must be filled.
    pub fn forward_block(&mut self, params: &[T], row0: usize, r: usize) {
        let ld = self.ld;
        let last = self.layers.len() - 1;
        for (l, lay) in self.layers.iter().enumerate() {
            let w = MatRef::from_row_major_slice(
                &params[lay.w..lay.w + lay.out * lay.fan_in],
                lay.out,
                lay.fan_in,
            );
            matmul(
                block_mut(&mut self.pre[l], ld, lay.out, row0, r),
                Accum::Replace,
                block(&self.acts[l], ld, lay.fan_in, row0, r),
                w.transpose(),
                T::one(),
                Par::Seq,
            );
            let bias = &params[lay.b..lay.b + lay.out];
            if l < last {
                let (pre, next) = (&mut self.pre[l], &mut self.acts[l + 1]);
                for (j, &bj) in bias.iter().enumerate() {
                    let o = j * ld + row0;
                    for (a, p) in next[o..o + r].iter_mut().zip(&mut pre[o..o + r]) {
                        *p += bj;
                        *a = p.relu();
                    }
                }
            } else {
                let pre = &mut self.pre[l];
                for (j, &bj) in bias.iter().enumerate() {
                    let o = j * ld + row0;
                    for p in &mut pre[o..o + r] {
                        *p += bj;
                    }
                }
            }
        }
    }

    /// Backward pass of rows `row0..row0 + r` (after [`MlpBufs::forward_block`] of the same
    /// rows), with `dL/d(output)` written into the output block: replaces every layer's
    /// pre-activation block by its gradient. With `input_grad` it also forms the gradient
    /// w.r.t. the input block, returned as an `r × (nx + nu)` view.
    pub fn backward_block(
        &mut self,
        params: &[T],
        row0: usize,
        r: usize,
        input_grad: bool,
    ) -> Option<MatRef<'_, T>> {
        assert!(
            r <= self.max_block,
            "block of {r} rows > {}",
            self.max_block
        );
        let ld = self.ld;
        for (l, lay) in self.layers.iter().enumerate().rev() {
            if l == 0 && !input_grad {
                return None;
            }
            let w = MatRef::from_row_major_slice(
                &params[lay.w..lay.w + lay.out * lay.fan_in],
                lay.out,
                lay.fan_in,
            );
            matmul(
                MatMut::from_column_major_slice_mut(
                    &mut self.dact[..r * lay.fan_in],
                    r,
                    lay.fan_in,
                ),
                Accum::Replace,
                block(&self.pre[l], ld, lay.out, row0, r),
                w,
                T::one(),
                Par::Seq,
            );
            if l > 0 {
                let pre = &mut self.pre[l - 1];
                for j in 0..lay.fan_in {
                    let o = j * ld + row0;
                    T::mask_and_sum(&mut pre[o..o + r], &self.dact[j * r..(j + 1) * r]);
                }
            }
        }
        let fan_in = self.layers[0].fan_in;
        Some(MatRef::from_column_major_slice(
            &self.dact[..r * fan_in],
            r,
            fan_in,
        ))
    }

    /// After backward passes of every block of rows `0..rows`: writes (overwrites) the
    /// gradients of every weight and bias into `grad` (flat, parameter layout).
    pub fn param_grads(&self, rows: usize, grad: &mut [T], par: Par) {
        let ld = self.ld;
        for (l, lay) in self.layers.iter().enumerate() {
            let dpre = block(&self.pre[l], ld, lay.out, 0, rows);
            // dW (out × in, row-major) = dpreᵀ a, i.e. column-major (in × out) = aᵀ dpre.
            matmul(
                MatMut::from_column_major_slice_mut(
                    &mut grad[lay.w..lay.w + lay.out * lay.fan_in],
                    lay.fan_in,
                    lay.out,
                ),
                Accum::Replace,
                block(&self.acts[l], ld, lay.fan_in, 0, rows).transpose(),
                dpre,
                T::one(),
                par,
            );
            for j in 0..lay.out {
                grad[lay.b + j] = T::sum(&self.pre[l][j * ld..j * ld + rows]);
            }
        }
    }
}
