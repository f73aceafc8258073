//! Adaptive Dormand–Prince RK45 (DOPRI5) integration of `ẋ = f(x)` over one interval.
//!
//! Local error control: a step of size `h` is accepted when the weighted RMS norm of the
//! embedded 5(4) error estimate, `sqrt(mean((e_i / (atol + rtol · max(|x_i|, |x⁺_i|)))²))`, is at
//! most 1. The step size follows the standard controller `h ← h · clamp(0.9 · err^(−1/5), 0.2, 5)`
//! and the last step is shortened to land exactly on the end of the interval. The defaults
//! ([`Tolerance::TIGHT`], rtol 1e-10, atol 1e-12) keep the per-step error of the reference systems
//! around 1e-11 or below, far under anything a learned model can resolve.

/// Relative and absolute tolerances of the adaptive integrator.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tolerance {
    /// Relative tolerance.
    pub rtol: f64,
    /// Absolute tolerance.
    pub atol: f64,
}

impl Tolerance {
    /// The tolerances used by every reference system: rtol 1e-10, atol 1e-12.
    pub const TIGHT: Tolerance = Tolerance {
        rtol: 1e-10,
        atol: 1e-12,
    };
}

impl Default for Tolerance {
    fn default() -> Self {
        Tolerance::TIGHT
    }
}

/// Counters of one integration.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Stats {
    /// Accepted steps.
    pub accepted: usize,
    /// Rejected steps.
    pub rejected: usize,
    /// Evaluations of the right-hand side.
    pub evaluations: usize,
}

/// The most steps (accepted + rejected) one call may take before it gives up and returns NaN;
/// never reached by the reference systems (they need well under 100 per interval).
const MAX_STEPS: usize = 100_000;

// Dormand–Prince 5(4) tableau (the nodes c_i are not needed: the systems are autonomous over a
// step because u is held constant).
const A21: f64 = 1.0 / 5.0;
const A31: f64 = 3.0 / 40.0;
const A32: f64 = 9.0 / 40.0;
const A41: f64 = 44.0 / 45.0;
const A42: f64 = -56.0 / 15.0;
const A43: f64 = 32.0 / 9.0;
const A51: f64 = 19372.0 / 6561.0;
const A52: f64 = -25360.0 / 2187.0;
const A53: f64 = 64448.0 / 6561.0;
const A54: f64 = -212.0 / 729.0;
const A61: f64 = 9017.0 / 3168.0;
const A62: f64 = -355.0 / 33.0;
const A63: f64 = 46732.0 / 5247.0;
const A64: f64 = 49.0 / 176.0;
const A65: f64 = -5103.0 / 18656.0;
const A71: f64 = 35.0 / 384.0;
const A73: f64 = 500.0 / 1113.0;
const A74: f64 = 125.0 / 192.0;
const A75: f64 = -2187.0 / 6784.0;
const A76: f64 = 11.0 / 84.0;
// Error coefficients: 5th-order weights minus 4th-order weights.
const E1: f64 = 71.0 / 57600.0;
const E3: f64 = -71.0 / 16695.0;
const E4: f64 = 71.0 / 1920.0;
const E5: f64 = -17253.0 / 339200.0;
const E6: f64 = 22.0 / 525.0;
const E7: f64 = -1.0 / 40.0;

fn combine<const N: usize>(x: &[f64; N], h: f64, terms: &[(f64, &[f64; N])]) -> [f64; N] {
    let mut y = *x;
    for (c, k) in terms {
        for i in 0..N {
            y[i] += h * c * k[i];
        }
    }
    y
}

fn error_norm<const N: usize>(err: &[f64; N], x: &[f64; N], y: &[f64; N], tol: Tolerance) -> f64 {
    let mut s = 0.0;
    for i in 0..N {
        let sc = tol.atol + tol.rtol * x[i].abs().max(y[i].abs());
        let r = err[i] / sc;
        s += r * r;
    }
    (s / N as f64).sqrt()
}

/// Integrates the autonomous system `ẋ = f(x)` from `x0` over a time span `t_end > 0`; returns
/// the final state and counters. Never panics: if the solution cannot be followed (non-finite
/// state, step size collapsing, or more than 100,000 steps) the returned state is non-finite, for
/// the caller to detect (dataset validation rejects non-finite values).
pub fn dopri5<const N: usize, F>(
    f: F,
    x0: [f64; N],
    t_end: f64,
    tol: Tolerance,
) -> ([f64; N], Stats)
where
    F: Fn(&[f64; N]) -> [f64; N],
{
    let mut stats = Stats::default();
    if t_end <= 0.0 || !t_end.is_finite() {
        return (x0, stats);
    }
    let mut x = x0;
    let mut k1 = f(&x);
    stats.evaluations += 1;
    let mut h = initial_step(&f, &x, &k1, t_end, tol, &mut stats);
    let mut t = 0.0;
    while t < t_end {
        let last = t + h >= t_end * (1.0 - 1e-14);
        let hh = if last { t_end - t } else { h };
        let k2 = f(&combine(&x, hh, &[(A21, &k1)]));
        let k3 = f(&combine(&x, hh, &[(A31, &k1), (A32, &k2)]));
        let k4 = f(&combine(&x, hh, &[(A41, &k1), (A42, &k2), (A43, &k3)]));
        let k5 = f(&combine(
            &x,
            hh,
            &[(A51, &k1), (A52, &k2), (A53, &k3), (A54, &k4)],
        ));
        let k6 = f(&combine(
            &x,
            hh,
            &[(A61, &k1), (A62, &k2), (A63, &k3), (A64, &k4), (A65, &k5)],
        ));
        let y = combine(
            &x,
            hh,
            &[(A71, &k1), (A73, &k3), (A74, &k4), (A75, &k5), (A76, &k6)],
        );
        let k7 = f(&y);
        stats.evaluations += 6;
        let mut err = [0.0; N];
        for i in 0..N {
            err[i] =
                hh * (E1 * k1[i] + E3 * k3[i] + E4 * k4[i] + E5 * k5[i] + E6 * k6[i] + E7 * k7[i]);
        }
        let en = error_norm(&err, &x, &y, tol);
        if en <= 1.0 {
            stats.accepted += 1;
            t = if last { t_end } else { t + hh };
            x = y;
            k1 = k7; // first-same-as-last
            if !x.iter().all(|v| v.is_finite()) {
                return (x, stats);
            }
            let fac = if en == 0.0 {
                5.0
            } else {
                (0.9 * en.powf(-0.2)).clamp(0.2, 5.0)
            };
            h = hh * fac;
        } else {
            stats.rejected += 1;
            let fac = if en.is_finite() {
                (0.9 * en.powf(-0.2)).clamp(0.2, 1.0)
            } else {
                0.2
            };
            h = hh * fac;
        }
        if stats.accepted + stats.rejected >= MAX_STEPS || h < 1e-13 * t_end {
            // The solution cannot be followed (finite-time blow-up or extreme stiffness).
            return ([f64::NAN; N], stats);
        }
    }
    (x, stats)
}

/// Hairer–Wanner's starting step heuristic (Solving ODEs I, II.4), capped at `t_end`.
fn initial_step<const N: usize, F>(
    f: &F,
    x: &[f64; N],
    k1: &[f64; N],
    t_end: f64,
    tol: Tolerance,
    stats: &mut Stats,
) -> f64
where
    F: Fn(&[f64; N]) -> [f64; N],
{
    let sc: Vec<f64> = x.iter().map(|v| tol.atol + tol.rtol * v.abs()).collect();
    let rms = |v: &[f64; N]| -> f64 {
        (v.iter()
            .zip(&sc)
            .map(|(a, s)| (a / s) * (a / s))
            .sum::<f64>()
            / N as f64)
            .sqrt()
    };
    let d0 = rms(x);
    let d1 = rms(k1);
    let h0 = if d0 < 1e-5 || d1 < 1e-5 {
        1e-6
    } else {
        0.01 * d0 / d1
    };
    let h0 = h0.min(t_end);
    let x1 = combine(x, h0, &[(1.0, k1)]);
    let k2 = f(&x1);
    stats.evaluations += 1;
    let mut diff = [0.0; N];
    for i in 0..N {
        diff[i] = k2[i] - k1[i];
    }
    let d2 = rms(&diff) / h0;
    let h1 = if d1.max(d2) <= 1e-15 {
        (h0 * 1e-3).max(1e-6)
    } else {
        (0.01 / d1.max(d2)).powf(0.2)
    };
    let h = (100.0 * h0).min(h1).min(t_end);
    if h.is_finite() && h > 0.0 {
        h
    } else {
        t_end
    }
}

/// The classical fixed-step fourth-order Runge–Kutta method with `n` equal steps over `t_end`:
/// an independent integrator used by the tests to check [`dopri5`].
pub fn rk4_fixed<const N: usize, F>(f: F, x0: [f64; N], t_end: f64, n: usize) -> [f64; N]
where
    F: Fn(&[f64; N]) -> [f64; N],
{
    let h = t_end / n as f64;
    let mut x = x0;
    for _ in 0..n {
        let k1 = f(&x);
        let k2 = f(&combine(&x, h, &[(0.5, &k1)]));
        let k3 = f(&combine(&x, h, &[(0.5, &k2)]));
        let k4 = f(&combine(&x, h, &[(1.0, &k3)]));
        x = combine(
            &x,
            h,
            &[
                (1.0 / 6.0, &k1),
                (1.0 / 3.0, &k2),
                (1.0 / 3.0, &k3),
                (1.0 / 6.0, &k4),
            ],
        );
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exponential_and_harmonic_oscillator_match_closed_form() {
        // ẋ = −2x: x(t) = x0 e^{−2t}.
        let (x, s) = dopri5(|x: &[f64; 1]| [-2.0 * x[0]], [1.5], 0.7, Tolerance::TIGHT);
        let exact = 1.5 * (-1.4f64).exp();
        assert!((x[0] - exact).abs() < 1e-10 * exact, "{} vs {exact}", x[0]);
        assert!(s.accepted > 1);
        // Harmonic oscillator ẍ = −ω²x over a long span.
        let w = 3.0;
        let (y, _) = dopri5(
            |y: &[f64; 2]| [y[1], -w * w * y[0]],
            [1.0, 0.0],
            5.0,
            Tolerance::TIGHT,
        );
        assert!((y[0] - (w * 5.0).cos()).abs() < 1e-8, "{y:?}");
        assert!((y[1] + w * (w * 5.0).sin()).abs() < 1e-8, "{y:?}");
    }

    #[test]
    fn tighter_tolerance_gives_smaller_error() {
        let f = |y: &[f64; 2]| [y[1], -y[0].sin() - 0.3 * y[1]];
        let truth = rk4_fixed(f, [2.0, 1.0], 1.0, 20_000);
        let loose = dopri5(
            f,
            [2.0, 1.0],
            1.0,
            Tolerance {
                rtol: 1e-5,
                atol: 1e-7,
            },
        )
        .0;
        let tight = dopri5(f, [2.0, 1.0], 1.0, Tolerance::TIGHT).0;
        let e = |a: [f64; 2]| (a[0] - truth[0]).abs().max((a[1] - truth[1]).abs());
        assert!(e(tight) < 1e-9, "tight error {}", e(tight));
        assert!(
            e(loose) > 10.0 * e(tight),
            "loose {} tight {}",
            e(loose),
            e(tight)
        );
    }

    #[test]
    fn degenerate_span_and_blow_up_do_not_panic() {
        let (x, s) = dopri5(|x: &[f64; 1]| [x[0]], [1.0], 0.0, Tolerance::TIGHT);
        assert_eq!(x, [1.0]);
        assert_eq!(s.evaluations, 0);
        // ẋ = x² blows up at t = 1 from x0 = 1; integrating to 2 must return, not hang or panic.
        let (x, _) = dopri5(|x: &[f64; 1]| [x[0] * x[0]], [1.0], 2.0, Tolerance::TIGHT);
        assert!(!x[0].is_finite() || x[0].abs() > 1e6, "{x:?}");
    }
}
