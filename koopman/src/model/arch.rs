//! The shape of a neural Koopman model and where each parameter group lives in one flat vector.

use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// Dimensions of a neural Koopman model: encoder widths `[nx, hidden.., n_enc]`, and nu.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Arch {
    /// State dimension.
    pub nx: usize,
    /// Input dimension (0 for autonomous systems).
    pub nu: usize,
    /// Encoder widths, first = nx, last = n_enc.
    pub widths: Vec<usize>,
}

/// Offsets of one encoder block's parameters inside the flat vector.
///
/// The main weight `W` (out × in) and, when present, the residual weight `R` (out × in) are stored
/// stacked as one row-major `(k·out) × in` matrix (`k` = 2 with a residual map, 1 otherwise), and
/// likewise their biases `[b; r]`, so that one GEMM computes both branches.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BlockLayout {
    /// Input width.
    pub fan_in: usize,
    /// Output width.
    pub out: usize,
    /// Whether the residual map is a linear layer (widths differ) rather than the identity.
    pub linear_residual: bool,
    /// Offset of the stacked weights.
    pub w: usize,
    /// Offset of the stacked biases.
    pub b: usize,
}

impl BlockLayout {
    /// Rows of the stacked weight matrix: `2·out` with a linear residual, `out` otherwise.
    pub fn rows(&self) -> usize {
        if self.linear_residual {
            2 * self.out
        } else {
            self.out
        }
    }
}

/// Where every parameter group lives in the flat parameter vector.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Layout {
    /// One entry per encoder block.
    pub blocks: Vec<BlockLayout>,
    /// Offset of A (N × N, row-major).
    pub a: usize,
    /// Offset of B (N × nu, row-major).
    pub b: usize,
    /// Total number of parameters.
    pub len: usize,
}

impl Arch {
    /// The SPEC architecture: widths `[nx, hidden.., n_mult·nx]`.
    pub fn new(nx: usize, nu: usize, hidden: &[usize], n_mult: usize) -> Result<Self> {
        let mut widths = vec![nx];
        widths.extend_from_slice(hidden);
        widths.push(n_mult * nx);
        let arch = Arch { nx, nu, widths };
        arch.check()?;
        Ok(arch)
    }

    /// Checks that the dimensions are usable.
    pub fn check(&self) -> Result<()> {
        if self.nx == 0 {
            return Err(Error::InvalidArgument(
                "state dimension nx must be > 0".into(),
            ));
        }
        if self.widths.len() < 2 {
            return Err(Error::InvalidArgument(
                "the encoder needs at least one block (widths [nx, .., n_enc])".into(),
            ));
        }
        if self.widths[0] != self.nx {
            return Err(Error::dimension(
                "encoder input width",
                self.nx,
                self.widths[0],
            ));
        }
        if self.widths.contains(&0) {
            return Err(Error::InvalidArgument("encoder widths must be > 0".into()));
        }
        Ok(())
    }

    /// Encoder output width n_enc.
    pub fn n_enc(&self) -> usize {
        *self.widths.last().expect("checked")
    }

    /// Latent dimension N = nx + n_enc.
    pub fn latent_dim(&self) -> usize {
        self.nx + self.n_enc()
    }

    /// The parameter layout.
    pub fn layout(&self) -> Layout {
        let mut off = 0;
        let mut blocks = Vec::with_capacity(self.widths.len() - 1);
        for w in self.widths.windows(2) {
            let (fan_in, out) = (w[0], w[1]);
            let linear_residual = fan_in != out;
            let k = if linear_residual { 2 } else { 1 };
            let wo = off;
            off += k * out * fan_in;
            let bo = off;
            off += k * out;
            blocks.push(BlockLayout {
                fan_in,
                out,
                linear_residual,
                w: wo,
                b: bo,
            });
        }
        let n = self.latent_dim();
        let a = off;
        off += n * n;
        let b = off;
        off += n * self.nu;
        Layout {
            blocks,
            a,
            b,
            len: off,
        }
    }

    /// Number of parameters.
    pub fn num_params(&self) -> usize {
        self.layout().len
    }
}
