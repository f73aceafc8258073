//! The survival metric of a tracking task, without the network: the per-step error over the
//! scored states, the first failing step, the steps survived, their summary over references, and
//! the closed loops cut into training windows.
//!
//! Survival of a run `x_0 .. x_n` against a reference `r_0 .. r_L`: with `e_k = mean_{j ∈ S}
//! |x_k,j − r_k,j|` and `fail_k` = `e_k > threshold`, a fall at step k (the simulator flagged the
//! step `terminated`) or a non-finite state, survival = `min{k ≥ 1 : fail_k} − 1` — the steps
//! completed before the first failing one — or `L` when no step fails. Step 0 (the shared
//! start) never counts.

use serde::{Deserialize, Serialize};

use crate::scenario::SurvivalSpec;

/// `e`: the mean absolute error of `x` against `r` over the state indices `states`; NaN when a
/// value is not finite.
pub fn mean_abs_error(x: &[f64], r: &[f64], states: &[usize]) -> f64 {
    let sum: f64 = states.iter().map(|&j| (x[j] - r[j]).abs()).sum();
    sum / states.len().max(1) as f64
}

/// Whether the step that brought `x` fails: a non-finite state or error, an error above the
/// threshold, or a fall.
pub fn fails(x: &[f64], r: &[f64], fell: bool, spec: &SurvivalSpec) -> bool {
    let e = mean_abs_error(x, r, &spec.states);
    fell || !e.is_finite() || e > spec.threshold || x.iter().any(|v| !v.is_finite())
}

/// Survival steps of a run whose states `1..=n` failed or not (`failed[k]` for state k; entry 0,
/// the start, is ignored) against a reference of `length` transitions: the index of the first
/// failing state minus one, or `length` when none of states 1..=min(n, length) fails. A run
/// that ended before `length` without a failure cannot be scored (`Err`).
pub fn survival_steps(failed: &[bool], length: usize) -> Result<usize, String> {
    let n = failed.len().saturating_sub(1).min(length);
    match (1..=n).find(|&k| failed[k]) {
        Some(k) => Ok(k - 1),
        None if n < length => Err(format!(
            "a run of {n} steps without a failure cannot be scored against {length} steps"
        )),
        None => Ok(length),
    }
}

/// Survival steps of a run of states `xs` (`xs[0]` the shared start) with the simulator's fall
/// flags `terminated` (one per state) against `reference` (states `r_0 .. r_L`, the last held
/// past its end), over `length` transitions: every state scored by [`fails`], then
/// [`survival_steps`].
pub fn survival_of_run(
    xs: &[Vec<f64>],
    terminated: &[bool],
    reference: &[Vec<f64>],
    length: usize,
    spec: &SurvivalSpec,
) -> Result<usize, String> {
    if reference.is_empty() || xs.len() != terminated.len() {
        return Err(format!(
            "survival: {} states with {} fall flags against a reference of {} states",
            xs.len(),
            terminated.len(),
            reference.len()
        ));
    }
    let failed: Vec<bool> = xs
        .iter()
        .zip(terminated)
        .enumerate()
        .map(|(k, (s, &fell))| fails(s, &reference[k.min(reference.len() - 1)], fell, spec))
        .collect();
    survival_steps(&failed, length)
}

/// Mean, spread, quartiles, range and count of per-reference figures (the quartiles and median
/// interpolated linearly between order statistics, as numpy's `percentile`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// How many.
    pub n: usize,
    /// Mean.
    pub mean: f64,
    /// Sample standard deviation (0 for one value).
    pub std: f64,
    /// Standard error of the mean.
    pub sem: f64,
    /// Median.
    pub median: f64,
    /// 25th percentile.
    pub q25: f64,
    /// 75th percentile.
    pub q75: f64,
    /// Smallest.
    pub min: f64,
    /// Largest.
    pub max: f64,
    /// How many reached `cap` (the references' length); absent without a cap.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub at_cap: Option<usize>,
}

impl Summary {
    /// The summary of `v` (all zeros for none); `cap`: count the values ≥ it.
    pub fn of(v: &[f64], cap: Option<f64>) -> Summary {
        if v.is_empty() {
            return Summary::default();
        }
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let std = if v.len() > 1 {
            (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
        } else {
            0.0
        };
        let mut s = v.to_vec();
        s.sort_by(f64::total_cmp);
        Summary {
            n: v.len(),
            mean,
            std,
            sem: std / n.sqrt(),
            median: percentile(&s, 50.0),
            q25: percentile(&s, 25.0),
            q75: percentile(&s, 75.0),
            min: s[0],
            max: s[s.len() - 1],
            at_cap: cap.map(|c| v.iter().filter(|&&x| x >= c).count()),
        }
    }
}

/// The `p`-th percentile of sorted values, linear between order statistics.
fn percentile(sorted: &[f64], p: f64) -> f64 {
    let pos = (sorted.len() - 1) as f64 * p / 100.0;
    let (lo, frac) = (pos.floor() as usize, pos - pos.floor());
    match sorted.get(lo + 1) {
        Some(hi) if frac > 0.0 => sorted[lo] + frac * (hi - sorted[lo]),
        _ => sorted[lo],
    }
}

/// One run's states (`n+1` rows), inputs (`n` rows) and whether each state is usable as
/// training data (finite, not fallen).
pub struct RunForWindows<'a> {
    /// States x_0..x_n.
    pub x: &'a [Vec<f64>],
    /// Inputs u_0..u_{n−1}.
    pub u: &'a [Vec<f64>],
    /// `good[k]`: state k is finite and upright.
    pub good: &'a [bool],
}

/// One training window: `t+1` states and the `t` inputs between them.
pub type Window = (Vec<Vec<f64>>, Vec<Vec<f64>>);

/// The runs cut into back-to-back windows of `t` transitions (the dataset layout: `t+1` states
/// and `t` inputs each), each run only up to the state before its first bad one (a window never
/// holds a fallen or non-finite state).
pub fn windows(runs: &[RunForWindows<'_>], t: usize) -> Vec<Window> {
    let mut out = Vec::new();
    for r in runs {
        let usable = r.good.iter().position(|g| !g).unwrap_or(r.x.len());
        let transitions = usable.saturating_sub(1).min(r.u.len());
        let mut s = 0;
        while t > 0 && s + t <= transitions {
            out.push((r.x[s..=s + t].to_vec(), r.u[s..s + t].to_vec()));
            s += t;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> SurvivalSpec {
        SurvivalSpec {
            threshold: 0.1,
            states: vec![1, 2],
        }
    }

    #[test]
    fn the_error_is_the_mean_over_the_scored_states_only() {
        let (x, r) = ([9.0, 0.3, -0.1], [0.0, 0.0, 0.0]);
        assert!((mean_abs_error(&x, &r, &[1, 2]) - 0.2).abs() < 1e-15);
        assert!(fails(&x, &r, false, &spec()));
        assert!(
            !fails(&[9.0, 0.1, -0.1], &r, false, &spec()),
            "0.1 is not above 0.1"
        );
        assert!(fails(&[9.0, 0.0, 0.0], &r, true, &spec()), "a fall fails");
        assert!(
            fails(&[f64::NAN, 0.0, 0.0], &r, false, &spec()),
            "non-finite fails"
        );
    }

    #[test]
    fn survival_counts_the_steps_before_the_first_failure() {
        // States 0..=4; state 3 fails first: steps 1 and 2 completed.
        assert_eq!(survival_steps(&[true, false, false, true, true], 10), Ok(2));
        // The start never counts, a failure at state 1 survives 0 steps.
        assert_eq!(survival_steps(&[true, true], 10), Ok(0));
        // No failure over the whole reference: its length.
        assert_eq!(survival_steps(&[false; 4], 3), Ok(3));
        // States past the reference's end are not scored.
        assert_eq!(
            survival_steps(&[false, false, false, false, true], 3),
            Ok(3)
        );
        assert!(survival_steps(&[false; 3], 5).is_err());
    }

    #[test]
    fn the_summary_matches_numpy() {
        // numpy: mean 4.6, std(ddof=1) 3.5777087639996634, percentile 25/50/75 = 2, 4, 6.
        let s = Summary::of(&[6.0, 1.0, 10.0, 4.0, 2.0], Some(6.0));
        assert!((s.mean - 4.6).abs() < 1e-12);
        let std = 3.577_708_763_999_663_4;
        assert!((s.std - std).abs() < 1e-12 && (s.sem - std / 5f64.sqrt()).abs() < 1e-12);
        assert_eq!(
            (s.q25, s.median, s.q75, s.min, s.max),
            (2.0, 4.0, 6.0, 1.0, 10.0)
        );
        assert_eq!(s.at_cap, Some(2));
        // Between order statistics: [1, 2, 3, 4] → 25th 1.75, median 2.5.
        let s = Summary::of(&[4.0, 3.0, 2.0, 1.0], None);
        assert_eq!((s.q25, s.median, s.q75), (1.75, 2.5, 3.25));
        assert_eq!(Summary::of(&[], None).n, 0);
    }

    #[test]
    fn windows_stop_before_the_first_bad_state() {
        let x: Vec<Vec<f64>> = (0..8).map(|k| vec![k as f64]).collect();
        let u: Vec<Vec<f64>> = (0..7).map(|k| vec![10.0 + k as f64]).collect();
        let mut good = vec![true; 8];
        good[6] = false; // states 0..=5 usable: 5 transitions → one window of 2, one of 2.
        let w = windows(
            &[RunForWindows {
                x: &x,
                u: &u,
                good: &good,
            }],
            2,
        );
        assert_eq!(w.len(), 2);
        assert_eq!(w[1].0, vec![vec![2.0], vec![3.0], vec![4.0]]);
        assert_eq!(w[1].1, vec![vec![12.0], vec![13.0]]);
        let all = windows(
            &[RunForWindows {
                x: &x,
                u: &u,
                good: &[true; 8],
            }],
            7,
        );
        assert_eq!(all.len(), 1, "7 transitions make one window of 7");
    }
}
