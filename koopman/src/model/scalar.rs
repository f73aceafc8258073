//! The floating-point types the model and trainer are generic over (f32 for training, f64 for
//! inference and gradient checks).

use faer::traits::RealField;

/// A real scalar usable in faer products and in the hand-written passes: `f32` or `f64`.
pub trait Real:
    RealField + Copy + Send + Sync + Default + std::fmt::Debug + std::ops::Neg<Output = Self> + 'static
{
    /// Converts from f64 (rounding for f32).
    fn from_f64(v: f64) -> Self;
    /// Converts to f64 (exact).
    fn to_f64(self) -> f64;
    /// Short name of the type, as written in configs (`"f32"`, `"f64"`).
    const NAME: &'static str;
    /// Square root.
    fn sqrt_(self) -> Self;
    /// `max(self, 0)`.
    fn relu(self) -> Self;
    /// `p ← (p > 0) ? d : 0` elementwise (the ReLU's backward), returning the sum of the new
    /// `p`; branch-free so that it vectorises.
    fn mask_and_sum(p: &mut [Self], d: &[Self]) -> Self;
    /// The sum of `d` (8 partial sums, so that it vectorises).
    fn sum(d: &[Self]) -> Self;
}

macro_rules! kernels {
    ($t:ty, $u:ty) => {
        #[inline(always)]
        fn relu(self) -> Self {
            self.max(0.0)
        }
        fn mask_and_sum(p: &mut [Self], d: &[Self]) -> Self {
            let mut acc = [0.0 as $t; 8];
            let mut pc = p.chunks_exact_mut(8);
            let mut dc = d.chunks_exact(8);
            for (pp, dd) in (&mut pc).zip(&mut dc) {
                for i in 0..8 {
                    let keep = ((pp[i] > 0.0) as $u).wrapping_neg();
                    let v = <$t>::from_bits(dd[i].to_bits() & keep);
                    pp[i] = v;
                    acc[i] += v;
                }
            }
            for (pv, dv) in pc.into_remainder().iter_mut().zip(dc.remainder()) {
                let v = if *pv > 0.0 { *dv } else { 0.0 };
                *pv = v;
                acc[0] += v;
            }
            acc.iter().sum()
        }
        fn sum(d: &[Self]) -> Self {
            let mut acc = [0.0 as $t; 8];
            let mut dc = d.chunks_exact(8);
            for dd in &mut dc {
                for i in 0..8 {
                    acc[i] += dd[i];
                }
            }
            for v in dc.remainder() {
                acc[0] += *v;
            }
            acc.iter().sum()
        }
    };
}

impl Real for f32 {
    #[inline(always)]
    fn from_f64(v: f64) -> Self {
        v as f32
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self as f64
    }
    const NAME: &'static str = "f32";
    kernels!(f32, u32);
    #[inline(always)]
    fn sqrt_(self) -> Self {
        self.sqrt()
    }
}

impl Real for f64 {
    #[inline(always)]
    fn from_f64(v: f64) -> Self {
        v
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self
    }
    const NAME: &'static str = "f64";
    kernels!(f64, u64);
    #[inline(always)]
    fn sqrt_(self) -> Self {
        self.sqrt()
    }
}
