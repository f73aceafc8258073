//! Splitting one large product of the losses over threads by disjoint blocks of its destination
//! (rows = windows of one time step, or columns), each block a sequential GEMM, so the latent
//! rollouts and their adjoint use every thread without a reduction.

use crate::model::scalar::Real;
use faer::reborrow::ReborrowMut;
use faer::MatMut;
use rayon::prelude::*;

/// Products below this many multiply-adds run on one thread: splitting them costs more in
/// synchronisation (a few µs) than it saves (the pendulum's 64 × 34 × 34 steps stay whole; the
/// Go2's 64 × 595 × 595 ones are split).
pub(crate) const SPLIT_MIN_MACS: usize = 1 << 22;

/// `len` split into `parts` nearly equal blocks: the `parts + 1` cut points.
pub(crate) fn cuts(len: usize, parts: usize) -> Vec<usize> {
    let parts = parts.clamp(1, len.max(1));
    (0..=parts).map(|p| p * len / parts).collect()
}

/// Runs `f(first, block)` on the blocks of `dst` between consecutive `cuts` (rows when `by_rows`,
/// columns otherwise; `cuts` from 0 to that length), in parallel when there are several.
pub(crate) fn for_blocks<T: Real>(
    dst: MatMut<'_, T>,
    cuts: &[usize],
    by_rows: bool,
    f: impl Fn(usize, MatMut<'_, T>) + Sync,
) {
    if cuts.len() <= 2 {
        f(0, dst);
        return;
    }
    let mut blocks = Vec::with_capacity(cuts.len() - 1);
    let mut rest = dst;
    for w in cuts.windows(2) {
        let len = w[1] - w[0];
        let (head, tail) = if by_rows {
            rest.split_at_row_mut(len)
        } else {
            rest.split_at_col_mut(len)
        };
        blocks.push((w[0], head));
        rest = tail;
    }
    blocks
        .into_par_iter()
        .for_each(|(first, mut block)| f(first, block.rb_mut()));
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::Mat;

    #[test]
    fn blocks_cover_the_destination_once() {
        assert_eq!(cuts(64, 2), vec![0, 32, 64]);
        assert_eq!(cuts(5, 3), vec![0, 1, 3, 5]);
        assert_eq!(cuts(1, 4), vec![0, 1]);
        for by_rows in [true, false] {
            let mut m = Mat::<f64>::zeros(7, 5);
            let len = if by_rows { 7 } else { 5 };
            for parts in [1, 2, 3] {
                for_blocks(m.as_mut(), &cuts(len, parts), by_rows, |first, mut b| {
                    for j in 0..b.ncols() {
                        for i in 0..b.nrows() {
                            let k = if by_rows { first + i } else { first + j };
                            b[(i, j)] += 1.0 + k as f64;
                        }
                    }
                });
            }
            for j in 0..5 {
                for i in 0..7 {
                    let k = if by_rows { i } else { j };
                    assert_eq!(m[(i, j)], 3.0 * (1.0 + k as f64));
                }
            }
        }
    }
}
