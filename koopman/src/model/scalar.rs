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
    #[inline(always)]
    fn relu(self) -> Self {
        if self > Self::default() {
            self
        } else {
            Self::default()
        }
    }
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
    #[inline(always)]
    fn sqrt_(self) -> Self {
        self.sqrt()
    }
}
