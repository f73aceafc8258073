//! The shape of an NNDM (an MLP on `[x, u]`), where each layer's parameters live in one flat
//! vector, and the hidden width that matches a Koopman model's parameter count.

use crate::model::arch::Arch;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// Dimensions of an NNDM: layer widths `[nx + nu, hidden.., nx]`, ReLU after every hidden layer,
/// the last layer linear.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct NndmArch {
    /// State dimension.
    pub nx: usize,
    /// Input dimension (0 for autonomous systems).
    pub nu: usize,
    /// Hidden widths (at least one layer).
    pub hidden: Vec<usize>,
}

/// Offsets of one layer's weight (row-major `out × fan_in`) and bias in the flat vector.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LayerLayout {
    /// Input width.
    pub fan_in: usize,
    /// Output width.
    pub out: usize,
    /// Offset of the weight matrix (row-major, `out × fan_in`).
    pub w: usize,
    /// Offset of the bias.
    pub b: usize,
}

impl NndmArch {
    /// An NNDM with the given hidden widths (checked).
    pub fn new(nx: usize, nu: usize, hidden: &[usize]) -> Result<Self> {
        let arch = NndmArch {
            nx,
            nu,
            hidden: hidden.to_vec(),
        };
        arch.check()?;
        Ok(arch)
    }

    /// The NNDM with `depth` equal hidden layers whose parameter count is closest to `target`
    /// (the smaller width on a tie).
    pub fn matching(nx: usize, nu: usize, depth: usize, target: usize) -> Result<Self> {
        if depth == 0 {
            return Err(Error::InvalidArgument(
                "an NNDM needs at least one hidden layer".into(),
            ));
        }
        let count = |w: usize| NndmArch::new(nx, nu, &vec![w; depth]).map(|a| a.num_params());
        let mut w = 1;
        while count(w + 1)? <= target {
            w += 1;
        }
        // Now count(w) ≤ target < count(w + 1), unless even w = 1 is above the target.
        let (lo, hi) = (count(w)?, count(w + 1)?);
        let best = if lo <= target && target - lo <= hi - target {
            w
        } else if lo > target {
            1
        } else {
            w + 1
        };
        NndmArch::new(nx, nu, &vec![best; depth])
    }

    /// The NNDM whose parameter count matches the Koopman model of the same training
    /// configuration (`Arch::new(nx, nu, hidden, n_mult)`), with as many equal hidden layers
    /// as the Koopman encoder has hidden layers.
    pub fn matching_koopman(nx: usize, nu: usize, hidden: &[usize], n_mult: usize) -> Result<Self> {
        let koopman = Arch::new(nx, nu, hidden, n_mult)?;
        Self::matching(nx, nu, hidden.len(), koopman.num_params())
    }

    /// Checks that the dimensions are usable.
    pub fn check(&self) -> Result<()> {
        if self.nx == 0 {
            return Err(Error::InvalidArgument(
                "state dimension nx must be > 0".into(),
            ));
        }
        if self.hidden.is_empty() {
            return Err(Error::InvalidArgument(
                "an NNDM needs at least one hidden layer".into(),
            ));
        }
        if self.hidden.contains(&0) {
            return Err(Error::InvalidArgument("hidden widths must be > 0".into()));
        }
        Ok(())
    }

    /// Layer widths `[nx + nu, hidden.., nx]`.
    pub fn widths(&self) -> Vec<usize> {
        let mut w = vec![self.nx + self.nu];
        w.extend_from_slice(&self.hidden);
        w.push(self.nx);
        w
    }

    /// Where every layer lives in the flat parameter vector (weights, then bias, layer by
    /// layer).
    pub fn layout(&self) -> Vec<LayerLayout> {
        let widths = self.widths();
        let mut off = 0;
        widths
            .windows(2)
            .map(|p| {
                let (fan_in, out) = (p[0], p[1]);
                let w = off;
                off += out * fan_in;
                let b = off;
                off += out;
                LayerLayout { fan_in, out, w, b }
            })
            .collect()
    }

    /// Number of parameters.
    pub fn num_params(&self) -> usize {
        self.layout().last().map_or(0, |l| l.b + l.out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_and_matching_width() {
        let a = NndmArch::new(2, 1, &[4, 5]).unwrap();
        // 3·4+4 + 4·5+5 + 5·2+2
        assert_eq!(a.num_params(), 16 + 25 + 12);
        let lay = a.layout();
        assert_eq!(lay[1].w, 16);
        assert_eq!(lay[2].b, 16 + 25 + 10);
        // The SPEC damped-pendulum Koopman model (n_mult 16, hidden 256×3): 150,758 parameters;
        // three hidden layers of 273 give 151,244 (272 would give 150,146, farther away).
        let k = Arch::new(2, 1, &[256, 256, 256], 16).unwrap().num_params();
        assert_eq!(k, 150_758);
        let n = NndmArch::matching_koopman(2, 1, &[256, 256, 256], 16).unwrap();
        assert_eq!(n.hidden, vec![273; 3]);
        assert_eq!(n.num_params(), 2 * 273 * 273 + 8 * 273 + 2);
        let below = NndmArch::new(2, 1, &[272; 3]).unwrap().num_params();
        assert!(n.num_params().abs_diff(k) < below.abs_diff(k));
        assert!(NndmArch::new(2, 1, &[]).is_err());
        assert!(NndmArch::new(0, 1, &[3]).is_err());
        assert!(NndmArch::matching(2, 1, 0, 100).is_err());
        assert_eq!(NndmArch::matching(2, 1, 1, 1).unwrap().hidden, vec![1]);
    }
}
