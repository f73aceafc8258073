//! Closed-loop metrics of SPEC.md: final error with wrapped angles, time to goal (held for 50
//! steps), tracking RMS and Frobenius error, solve-time statistics, constraint violations.

use serde::Serialize;

/// Wraps an angle to (−π, π].
pub fn wrap_angle(a: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    let w = a.rem_euclid(TAU); // [0, 2π)
    if w > PI {
        w - TAU
    } else {
        w
    }
}

/// `x − r` with the components in `angles` wrapped to (−π, π].
pub fn wrapped_error(x: &[f64], r: &[f64], angles: &[usize]) -> Vec<f64> {
    x.iter()
        .zip(r)
        .enumerate()
        .map(|(i, (a, b))| {
            if angles.contains(&i) {
                wrap_angle(a - b)
            } else {
                a - b
            }
        })
        .collect()
}

/// Thresholds of "at the goal": angles within `angle_tol` (rad), every other component within
/// `rate_tol`, for `hold` consecutive samples (SPEC: 0.05 rad, 0.1 rad/s, 50 steps).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct GoalSpec {
    /// Tolerance on angle components.
    pub angle_tol: f64,
    /// Tolerance on the other components.
    pub rate_tol: f64,
    /// Consecutive samples the state must stay within tolerance.
    pub hold: usize,
}

impl Default for GoalSpec {
    fn default() -> Self {
        GoalSpec {
            angle_tol: 0.05,
            rate_tol: 0.1,
            hold: 50,
        }
    }
}

/// The first sample index k such that samples k..k+hold all satisfy the goal tolerances
/// (`errors[k]` is the wrapped error of sample k); `None` if it never happens.
pub fn time_to_goal(errors: &[Vec<f64>], angles: &[usize], spec: &GoalSpec) -> Option<usize> {
    let ok: Vec<bool> = errors
        .iter()
        .map(|e| {
            e.iter().enumerate().all(|(i, v)| {
                let tol = if angles.contains(&i) {
                    spec.angle_tol
                } else {
                    spec.rate_tol
                };
                v.abs() <= tol
            })
        })
        .collect();
    let mut run = 0;
    for (k, &good) in ok.iter().enumerate() {
        run = if good { run + 1 } else { 0 };
        if run >= spec.hold.max(1) {
            return Some(k + 1 - spec.hold.max(1));
        }
    }
    None
}

/// The Euclidean norm of the last error vector (the closed loop's final error); NaN when there
/// is none.
pub fn final_error(errors: &[Vec<f64>]) -> f64 {
    errors
        .last()
        .map_or(f64::NAN, |e| e.iter().map(|v| v * v).sum::<f64>().sqrt())
}

/// Root mean square of every component of every error vector.
pub fn rms(errors: &[Vec<f64>]) -> f64 {
    let n: usize = errors.iter().map(Vec::len).sum();
    if n == 0 {
        return 0.0;
    }
    (errors.iter().flatten().map(|v| v * v).sum::<f64>() / n as f64).sqrt()
}

/// Frobenius norm of the error matrix (samples × components).
pub fn frobenius(errors: &[Vec<f64>]) -> f64 {
    errors.iter().flatten().map(|v| v * v).sum::<f64>().sqrt()
}

/// The `p`-quantile (nearest rank on the sorted values); 0 for an empty slice.
pub fn quantile(values: &[f64], p: f64) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let mut v = values.to_vec();
    v.sort_by(|a, b| a.total_cmp(b));
    v[((v.len() - 1) as f64 * p.clamp(0.0, 1.0)).round() as usize]
}

/// How far `u` lies outside `[lo, hi]` (0 inside).
pub fn bound_violation(u: &[f64], lo: &[f64], hi: &[f64]) -> f64 {
    u.iter()
        .enumerate()
        .map(|(i, &v)| (lo[i] - v).max(v - hi[i]).max(0.0))
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn wrapping_and_goal_detection() {
        assert!((wrap_angle(2.0 * PI + 0.1) - 0.1).abs() < 1e-12);
        assert!((wrap_angle(-PI - 0.1) - (PI - 0.1)).abs() < 1e-12);
        assert_eq!(wrap_angle(PI), PI);
        let e = wrapped_error(&[2.0 * PI - 0.01, 3.0], &[0.0, 1.0], &[0]);
        assert!((e[0] + 0.01).abs() < 1e-12 && (e[1] - 2.0).abs() < 1e-12);
        // Within tolerance from sample 10 on, except a blip at 30: goal reached at 31.
        let errs: Vec<Vec<f64>> = (0..100)
            .map(|k| {
                if k < 10 || k == 30 {
                    vec![0.2, 0.0]
                } else {
                    vec![0.04, 0.09]
                }
            })
            .collect();
        let spec = GoalSpec::default();
        assert_eq!(time_to_goal(&errs, &[0], &spec), Some(31));
        assert_eq!(time_to_goal(&errs[..80], &[0], &spec), None);
        // The rate tolerance applies to non-angle components.
        let errs2: Vec<Vec<f64>> = (0..60).map(|_| vec![0.0, 0.11]).collect();
        assert_eq!(time_to_goal(&errs2, &[0], &spec), None);
        assert!((final_error(&[vec![9.0], vec![3.0, 4.0]]) - 5.0).abs() < 1e-12);
        assert!(final_error(&[]).is_nan());
        assert!((rms(&[vec![3.0, 4.0]]) - (12.5f64).sqrt()).abs() < 1e-12);
        assert!((frobenius(&[vec![3.0], vec![4.0]]) - 5.0).abs() < 1e-12);
        assert_eq!(quantile(&[3.0, 1.0, 2.0], 0.5), 2.0);
        assert_eq!(
            bound_violation(&[1.5, -3.0], &[-1.0, -1.0], &[1.0, 1.0]),
            2.0
        );
    }
}
