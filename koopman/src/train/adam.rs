//! Adam with torch's semantics, torch's `StepLR` schedule and `clip_grad_norm_`.

use crate::model::scalar::Real;

/// Adam state (first and second moments) over a flat parameter vector, as `torch.optim.Adam`
/// (β = (0.9, 0.999), eps = 1e-8, bias correction, no weight decay).
pub struct Adam<T: Real> {
    m: Vec<T>,
    v: Vec<T>,
    t: u64,
    /// β1.
    pub beta1: f64,
    /// β2.
    pub beta2: f64,
    /// ε added to √v̂.
    pub eps: f64,
}

impl<T: Real> Adam<T> {
    /// Zero moments for `len` parameters.
    pub fn new(len: usize) -> Self {
        Adam {
            m: vec![T::default(); len],
            v: vec![T::default(); len],
            t: 0,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
        }
    }

    /// Steps taken so far.
    pub fn steps(&self) -> u64 {
        self.t
    }

    /// The moments `(m, v)` (to checkpoint a run).
    pub fn moments(&self) -> (&[T], &[T]) {
        (&self.m, &self.v)
    }

    /// Adam with the given moments after `t` steps (restores a checkpoint); `None` if the
    /// moments' lengths differ.
    pub fn from_state(m: Vec<T>, v: Vec<T>, t: u64) -> Option<Self> {
        (m.len() == v.len()).then(|| Adam {
            m,
            v,
            t,
            ..Adam::new(0)
        })
    }

    /// One step with learning rate `lr`: `p −= lr/(1−β1ᵗ) · m / (√v/√(1−β2ᵗ) + ε)`.
    pub fn step(&mut self, params: &mut [T], grad: &[T], lr: f64) {
        self.t += 1;
        let bc1 = 1.0 - self.beta1.powi(self.t as i32);
        let bc2 = 1.0 - self.beta2.powi(self.t as i32);
        let k = AdamConsts {
            step: T::from_f64(lr / bc1),
            inv_sqrt_bc2: T::from_f64(1.0 / bc2.sqrt()),
            b1: T::from_f64(self.beta1),
            b2: T::from_f64(self.beta2),
            c1: T::from_f64(1.0 - self.beta1),
            c2: T::from_f64(1.0 - self.beta2),
            eps: T::from_f64(self.eps),
        };
        pulp::Arch::new().dispatch(AdamPass {
            k,
            params,
            grad,
            m: &mut self.m,
            v: &mut self.v,
        });
    }
}

/// The per-step constants of [`Adam::step`].
#[derive(Clone, Copy)]
struct AdamConsts<T> {
    step: T,
    inv_sqrt_bc2: T,
    b1: T,
    b2: T,
    c1: T,
    c2: T,
    eps: T,
}

/// The elementwise pass of [`Adam::step`], compiled for the CPU's vector extension (found at run
/// time): the same IEEE operations in the same order as a scalar loop, so the same result.
struct AdamPass<'a, T> {
    k: AdamConsts<T>,
    params: &'a mut [T],
    grad: &'a [T],
    m: &'a mut [T],
    v: &'a mut [T],
}

impl<T: Real> pulp::WithSimd for AdamPass<'_, T> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let k = self.k;
        for (((p, g), m), v) in self
            .params
            .iter_mut()
            .zip(self.grad)
            .zip(self.m.iter_mut())
            .zip(self.v.iter_mut())
        {
            *m = k.b1 * *m + k.c1 * *g;
            *v = k.b2 * *v + k.c2 * *g * *g;
            let denom = v.sqrt_() * k.inv_sqrt_bc2 + k.eps;
            *p -= k.step * *m / denom;
        }
    }
}

/// `torch.optim.lr_scheduler.StepLR` stepped once per iteration: the learning rate of
/// iteration `it` (0-based) is `lr0 · decay^⌊it / every⌋`.
pub fn step_lr(lr0: f64, decay: f64, every: usize, it: usize) -> f64 {
    lr0 * decay.powi((it / every.max(1)) as i32)
}

/// `torch.nn.utils.clip_grad_norm_`: scales `grad` by `max_norm / (‖grad‖ + 1e-6)` when that is
/// below 1; returns the norm before clipping.
pub fn clip_grad_norm<T: Real>(grad: &mut [T], max_norm: f64) -> f64 {
    let norm = pulp::Arch::new().dispatch(SumSquares(grad)).sqrt();
    let coef = max_norm / (norm + 1e-6);
    if coef < 1.0 {
        let c = T::from_f64(coef);
        for g in grad.iter_mut() {
            *g *= c;
        }
    }
    norm
}

/// `Σ g²` in f64 with eight partial sums (vectorised; f64 keeps the reordering far below f32's
/// rounding of the gradient).
struct SumSquares<'a, T>(&'a [T]);

impl<T: Real> pulp::WithSimd for SumSquares<'_, T> {
    type Output = f64;
    #[inline(always)]
    #[allow(clippy::needless_range_loop)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> f64 {
        let mut acc = [0.0f64; 8];
        let chunks = self.0.chunks_exact(8);
        let rest = chunks.remainder();
        for c in chunks {
            for i in 0..8 {
                let g = c[i].to_f64();
                acc[i] += g * g;
            }
        }
        let mut s =
            ((acc[0] + acc[4]) + (acc[2] + acc[6])) + ((acc[1] + acc[5]) + (acc[3] + acc[7]));
        for g in rest {
            s += g.to_f64() * g.to_f64();
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn adam_first_steps_match_the_closed_form() {
        // With a constant gradient g, m̂ = g and v̂ = g² at every step, so each step moves every
        // parameter by lr·g/(|g| + ε·…) ≈ lr·sign(g).
        let mut p = vec![1.0f64, -2.0];
        let g = vec![0.5, -3.0];
        let mut adam = Adam::new(2);
        adam.step(&mut p, &g, 0.1);
        // Step 1 by hand: m = 0.1 g, v = 0.001 g², bc1 = 0.1, bc2 = 0.001.
        let expect0 =
            1.0 - 0.1 * (0.1 * 0.5 / 0.1) / ((0.001f64 * 0.25).sqrt() / 0.001f64.sqrt() + 1e-8);
        assert!((p[0] - expect0).abs() < 1e-14);
        adam.step(&mut p, &g, 0.1);
        assert!((p[0] - (1.0 - 0.2)).abs() < 1e-7, "{}", p[0]);
        assert!((p[1] - (-2.0 + 0.2)).abs() < 1e-7, "{}", p[1]);
    }

    #[test]
    fn clipping_and_schedule_follow_torch() {
        let mut g = vec![3.0f64, 4.0];
        let n = clip_grad_norm(&mut g, 0.1);
        assert_eq!(n, 5.0);
        let want = 0.1 / (5.0 + 1e-6);
        assert!((g[0] - 3.0 * want).abs() < 1e-15 && (g[1] - 4.0 * want).abs() < 1e-15);
        let mut small = vec![0.01f64, 0.0];
        clip_grad_norm(&mut small, 0.1);
        assert_eq!(small, vec![0.01, 0.0]);
        assert_eq!(step_lr(1e-3, 0.9, 1000, 999), 1e-3);
        assert!((step_lr(1e-3, 0.9, 1000, 1000) - 9e-4).abs() < 1e-18);
        assert!((step_lr(1e-3, 0.9, 1000, 2500) - 1e-3 * 0.81).abs() < 1e-18);
    }
}
