//! What a control run that missed its goal can say about why: how well the model predicts the
//! closed loop against how well it predicts the test set (did the loop leave the data?), how
//! often the commands sat at a bound, the input authority at the goal (the model's input gain
//! against the simulator's: [`super::authority`]), how fast deviations grow there in the model and
//! in the simulator ([`super::growth`]), what the data say ([`super::data_quality`]: windows the
//! simulator ended, the model's error against the data's spread, the loop outside the data), and
//! one concrete next step.

use koopman::data::Dataset;
use serde::{Deserialize, Serialize};

use super::authority::InputAuthority;
use super::closed_loop::ControlReport;
use super::data_quality::{data_quality, DataQuality, ENDED_WINDOWS, UNEXPLAINED};
use super::growth::Growth;
use crate::error::{Error, Result};
use koopman::analysis::gain::WEAK_AUTHORITY;

/// Closed-loop prediction error this many times the test set's means the loop left the data.
pub const OFF_DATA_RATIO: f64 = 3.0;
/// Commands at a bound more often than this means the input lacks authority (or the model
/// asks for the wrong amount).
pub const SATURATED_FRACTION: f64 = 0.5;

/// The diagnosis of one control run (`report.json`'s `diagnoses`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ControlDiagnosis {
    /// Simulator id.
    pub sim: String,
    /// Model name.
    pub model: String,
    /// Fraction of the input components the MPC sent at a bound (within 1e-6 of the range).
    pub saturated_fraction: f64,
    /// Transitions per prediction window of the two errors below: the dataset's T.
    pub window_steps: usize,
    /// Mean squared prediction error (raw units, γ = 1) of the one-step predictions along the
    /// closed loop; `None` for a model kind without a lifted form (nndm, bilinear) or a loop
    /// shorter than a window.
    pub one_step_closed_loop: Option<f64>,
    /// The same on the test set.
    pub one_step_test: Option<f64>,
    /// Mean squared error of the `window_steps`-step predictions along the closed loop.
    pub window_closed_loop: Option<f64>,
    /// The same on the test set.
    pub window_test: Option<f64>,
    /// The model's one-step input gain at the goal against the simulator's (`None`: a model
    /// without a lifted form, a trajectory reference, or not measured).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub input_authority: Option<InputAuthority>,
    /// The simulator's and the model's growth rate at the goal (`None`: as `input_authority`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub growth: Option<Growth>,
    /// What the data say: windows the simulator ended, the model's error against the data's
    /// spread, the share of the loop outside the data.
    pub data: DataQuality,
    /// One concrete next step.
    pub next_step: String,
}

/// Diagnoses `c` with its lifted `model` (`None`: a kind without one), the run's test windows
/// `test`, and the
/// input authority and growth rates measured at the goal ([`super::authority::input_authority`],
/// [`super::growth::growth`]).
pub fn diagnose(
    c: &ControlReport,
    model: Option<&dyn koopman::model::LiftedModel>,
    test: &Dataset,
    input_authority: Option<InputAuthority>,
    growth: Option<Growth>,
) -> Result<ControlDiagnosis> {
    let saturated_fraction = saturated_fraction(c);
    let errors = model
        .map(|model| prediction_errors(model, c, test))
        .transpose()?;
    let [one_cl, one_test, win_cl, win_test] = errors.unwrap_or([None; 4]);
    let ratio = match (win_cl.or(one_cl), win_test.or(one_test)) {
        (Some(cl), Some(t)) if t > 0.0 => Some(cl / t),
        _ => None,
    };
    let data = data_quality(test, win_test, &c.x);
    let next_step = next_step(
        c,
        ratio,
        saturated_fraction,
        input_authority.as_ref(),
        growth.as_ref(),
        &data,
    );
    Ok(ControlDiagnosis {
        sim: c.sim.clone(),
        model: c.model.clone(),
        saturated_fraction,
        window_steps: test.steps,
        one_step_closed_loop: one_cl,
        one_step_test: one_test,
        window_closed_loop: win_cl,
        window_test: win_test,
        input_authority,
        growth,
        data,
        next_step,
    })
}

/// The warning a run that missed a fixed goal deserves (`None` when it reached it or tracked a
/// trajectory, whose goal is the whole path): the diagnosis in one sentence.
pub fn missed_goal_warning(c: &ControlReport, d: &ControlDiagnosis) -> Option<String> {
    if c.time_to_goal_steps.is_some() || c.reference_trajectory.is_some() {
        return None;
    }
    let prediction = match (d.window_closed_loop, d.window_test) {
        (Some(cl), Some(t)) => format!(
            "{}-step prediction error {cl:.3e} along the closed loop vs {t:.3e} on the test set; ",
            d.window_steps
        ),
        _ => String::new(),
    };
    Some(format!(
        "control of '{}' (model '{}') did not reach its goal (final error {:.4}): {prediction}\
         {:.0}% of the commands at a bound; next: {}",
        c.sim,
        c.model,
        c.final_error,
        100.0 * d.saturated_fraction,
        d.next_step
    ))
}

/// The share of input components within 1e-6 of the range of a finite MPC bound.
fn saturated_fraction(c: &ControlReport) -> f64 {
    let Some(mpc) = &c.mpc else { return 0.0 };
    let bound = |b: &Option<Vec<f64>>, i: usize| b.as_ref().and_then(|v| v.get(i).copied());
    let (mut at, mut all) = (0usize, 0usize);
    for u in &c.u {
        for (i, &ui) in u.iter().enumerate() {
            all += 1;
            let (lo, hi) = (bound(&mpc.u_min, i), bound(&mpc.u_max, i));
            let tol = match (lo, hi) {
                (Some(l), Some(h)) if l.is_finite() && h.is_finite() => 1e-6 * (h - l).max(1e-12),
                _ => 1e-9,
            };
            let near = |b: Option<f64>| b.is_some_and(|b| b.is_finite() && (ui - b).abs() <= tol);
            at += usize::from(near(lo) || near(hi));
        }
    }
    if all == 0 {
        0.0
    } else {
        at as f64 / all as f64
    }
}

/// [one-step closed loop, one-step test, T-step closed loop, T-step test].
fn prediction_errors(
    model: &dyn koopman::model::LiftedModel,
    c: &ControlReport,
    test: &Dataset,
) -> Result<[Option<f64>; 4]> {
    let err = |d: &Dataset| -> Result<Option<f64>> {
        if d.n == 0 {
            return Ok(None);
        }
        koopman::analysis::prediction_error(model, d, 1.0)
            .map(Some)
            .map_err(|e| Error::Config(format!("diagnosing '{}': {e}", c.model)))
    };
    let loop_windows = |steps: usize| {
        Dataset::from_trajectory(&c.x, &c.u, steps, 1, test.meta.clone())
            .map_err(|e| Error::Config(format!("closed loop of '{}': {e}", c.sim)))
    };
    let t = test.steps;
    Ok([
        err(&loop_windows(1)?)?,
        err(&first_step_windows(test))?,
        err(&loop_windows(t)?)?,
        err(test)?,
    ])
}

/// Every transition of `d` as its own one-step window.
fn first_step_windows(d: &Dataset) -> Dataset {
    let mut x = Vec::with_capacity(d.transitions() * 2 * d.nx);
    for i in 0..d.n {
        for t in 0..d.steps {
            x.extend_from_slice(d.state(i, t));
            x.extend_from_slice(d.state(i, t + 1));
        }
    }
    Dataset {
        n: d.transitions(),
        steps: 1,
        nx: d.nx,
        nu: d.nu,
        x,
        u: d.u.clone(),
        meta: d.meta.clone(),
    }
}

/// The one next step the numbers point to.
fn next_step(
    c: &ControlReport,
    off_data: Option<f64>,
    saturated: f64,
    authority: Option<&InputAuthority>,
    growth: Option<&Growth>,
    data: &DataQuality,
) -> String {
    if c.time_to_goal_steps.is_some() {
        return "none: the goal was reached".into();
    }
    if c.not_solved * 2 > c.u.len() {
        return "the MPC did not solve most steps: raise [control].mpc max_iterations or \
                time_limit, or loosen x_min/x_max"
            .into();
    }
    if let Some(a) = authority.filter(|a| a.projection < WEAK_AUTHORITY) {
        let what = if a.cosine < 0.0 {
            "has the wrong sign"
        } else {
            "is far smaller than the simulator's"
        };
        return format!(
            "the model's input gain at the goal {what} (projection on the simulator's {:.3}, \
             cosine {:.2}): a linear-input model learns one gain for all its data, and where the \
             true gain changes sign or size across the data it learns a useless one — collect \
             around the goal where the input's effect keeps its sign ([[sims]] or [collect] \
             x0_center/x0_radius), or train a bilinear model ([train] model = \"bilinear\")",
            a.projection, a.cosine
        );
    }
    if let Some(e) = data.ended_share().filter(|e| *e > ENDED_WINDOWS) {
        return format!(
            "{:.0}% of the collection windows reached a state where the simulator ended the \
             episode (a fall, a stop): much of the data is the plant after it failed, not where \
             the task is — collect where the task is: smaller inputs ([collect] policy low/high), \
             a [collect] x0 box around the goal, shorter windows ([collect] steps)",
            100.0 * e
        );
    }
    if let Some(g) = growth.filter(|g| g.model_too_slow()) {
        return format!(
            "the goal is unstable (the simulator's deviations grow {:.2}x per step there) and the \
             model's lifted dynamics grow at most {:.2}x: over the {}-step horizon it predicts the \
             departure {:.0}x too slow, so the MPC pushes too late — a model whose A is right over \
             the horizon: EDMD ([train] model = \"edmd\", its degree chosen by validation), data \
             closer to the goal (a smaller [collect] x0 box, smaller inputs, short windows), or a \
             shorter horizon (docs/your-own-simulator.md §8)",
            g.sim_spectral_radius, g.model_spectral_radius, g.horizon, g.too_slow_over_horizon
        );
    }
    if let Some(u) = data.unexplained_share.filter(|u| *u > UNEXPLAINED) {
        return format!(
            "the model leaves {:.0}% of its own test data's variance unexplained: it does not \
             predict the data it learned from — more iterations or windows ([train].config, \
             [collect]), a second kind of model ([train] model), or data from a smaller region",
            100.0 * u
        );
    }
    if let Some(r) = off_data.filter(|r| *r > OFF_DATA_RATIO) {
        return format!(
            "the model predicts the closed loop {r:.1}x worse than its test set ({:.0}% of the \
             loop's states outside the data's range): the loop left the data — collect around the task ([collect] x0 box around the goal or reference, \
             input bounds the task needs) or run on-policy aggregation (--aggregate 2)",
            100.0 * data.loop_outside_data
        );
    }
    if saturated > SATURATED_FRACTION {
        return format!(
            "{:.0}% of the commands sat at a bound: the input lacks authority for this task at \
             these bounds, or the model's input gain is wrong — check the input's effect in the \
             data, widen the bounds only where the data had such inputs",
            100.0 * saturated
        );
    }
    "the model predicts the loop as well as its test set and the inputs have room: tune the \
     MPC ([control].mpc q, r, horizon; offset_free for a steady offset) or train longer \
     ([train].config iterations)"
        .into()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn report(u: Vec<Vec<f64>>, goal: Option<usize>) -> ControlReport {
        let mut r: ControlReport = serde_json::from_value(serde_json::json!({
            "sim": "s", "model": "m", "state_names": ["x"], "input_names": ["u"], "dt": 0.1,
            "reference": [0.0], "x": [[0.0]], "u": [], "final_error": 1.0,
            "time_to_goal_steps": null, "error": [1.0], "tracking_rms": [1.0],
            "tracking_rms_total": 1.0, "solve_median_us": 1.0, "solve_round_trip_median_us": 1.0,
            "step_round_trip_median_us": 1.0, "not_solved": 0, "not_solved_by_status": {},
            "error_state": false
        }))
        .unwrap();
        r.x = vec![vec![0.0]; u.len() + 1];
        r.u = u;
        r.time_to_goal_steps = goal;
        r.mpc = Some(koopman::mpc::MpcConfig {
            u_min: Some(vec![-2.0]),
            u_max: Some(vec![2.0]),
            ..Default::default()
        });
        r
    }

    #[test]
    fn saturation_counts_commands_at_either_bound() {
        let r = report(vec![vec![2.0], vec![-2.0], vec![1.9], vec![0.0]], None);
        assert_eq!(saturated_fraction(&r), 0.5);
        let r = report(
            vec![vec![2.0], vec![-2.0], vec![2.0 - 1e-7], vec![0.0]],
            None,
        );
        assert_eq!(saturated_fraction(&r), 0.75);
    }

    #[test]
    fn the_next_step_follows_the_numbers() {
        let clean = DataQuality::default();
        let reached = report(vec![vec![0.0]], Some(0));
        assert!(next_step(&reached, Some(10.0), 1.0, None, None, &clean).starts_with("none"));
        let missed = report(vec![vec![0.0]], None);
        assert!(next_step(&missed, Some(10.0), 0.0, None, None, &clean).contains("left the data"));
        assert!(
            next_step(&missed, Some(1.2), 0.9, None, None, &clean).contains("90% of the commands")
        );
        assert!(next_step(&missed, Some(1.2), 0.1, None, None, &clean).contains("tune the MPC"));
        let mut unsolved = report(vec![vec![0.0]; 4], None);
        unsolved.not_solved = 3;
        assert!(next_step(&unsolved, None, 0.0, None, None, &clean).contains("did not solve"));
        let gain = |projection: f64, cosine: f64| InputAuthority {
            at: vec![0.0],
            nominal: vec![0.0],
            delta: vec![1e-3],
            model_gain: vec![vec![projection]],
            sim_gain: vec![vec![1.0]],
            projection,
            cosine,
            norm_ratio: projection.abs(),
        };
        let wrong = gain(-0.007, -1.0);
        let s = next_step(&missed, Some(10.0), 0.9, Some(&wrong), None, &clean);
        assert!(s.contains("wrong sign") && s.contains("-0.007"), "{s}");
        let weak = gain(0.1, 1.0);
        assert!(next_step(&missed, None, 0.0, Some(&weak), None, &clean).contains("far smaller"));
        let good = gain(0.9, 1.0);
        assert!(
            next_step(&missed, Some(1.2), 0.1, Some(&good), None, &clean).contains("tune the MPC")
        );
        // An unstable goal and a model that grows too slowly over the horizon: that, before the
        // loop leaving the data (its consequence); a model fast enough, or a stable goal: not.
        let grow = |sim: f64, model: f64| Growth {
            at: vec![0.0],
            input: vec![0.0],
            sim_spectral_radius: sim,
            model_spectral_radius: model,
            horizon: 30,
            too_slow_over_horizon: (sim / model).powi(30),
        };
        let slow = grow(1.56, 1.29);
        let s = next_step(&missed, Some(1e5), 0.9, Some(&good), Some(&slow), &clean);
        assert!(s.contains("unstable") && s.contains("299x too slow"), "{s}");
        let fine = grow(1.56, 1.51);
        assert!(
            next_step(&missed, Some(1e5), 0.9, Some(&good), Some(&fine), &clean)
                .contains("left the data")
        );
        let stable = grow(0.99, 0.5);
        assert!(
            next_step(&missed, Some(1e5), 0.9, Some(&good), Some(&stable), &clean)
                .contains("left the data")
        );
    }

    #[test]
    fn the_data_come_first_when_they_are_the_cause() {
        use koopman::data::WindowFlags;
        let missed = report(vec![vec![0.0]], None);
        let ended = DataQuality {
            windows: 100,
            window_flags: Some(WindowFlags {
                terminated: 48,
                truncated: 0,
                clipped: 0,
            }),
            unexplained_share: Some(0.4),
            loop_outside_data: 0.9,
        };
        let s = next_step(&missed, Some(50.0), 0.9, None, None, &ended);
        assert!(s.contains("48% of the collection windows"), "{s}");
        let few = DataQuality {
            window_flags: Some(WindowFlags {
                terminated: 5,
                ..Default::default()
            }),
            ..ended.clone()
        };
        let s = next_step(&missed, Some(50.0), 0.9, None, None, &few);
        assert!(s.contains("40% of its own test data's variance"), "{s}");
        let explained = DataQuality {
            unexplained_share: Some(0.01),
            ..few
        };
        let s = next_step(&missed, Some(50.0), 0.9, None, None, &explained);
        assert!(s.contains("(90% of the loop's states outside"), "{s}");
    }

    #[test]
    fn one_step_windows_hold_every_transition() {
        let d = Dataset {
            n: 2,
            steps: 2,
            nx: 1,
            nu: 1,
            x: vec![0.0, 1.0, 2.0, 10.0, 11.0, 12.0],
            u: vec![5.0, 6.0, 7.0, 8.0],
            meta: koopman::data::DatasetMeta {
                state_names: vec!["x".into()],
                input_names: vec!["u".into()],
                ..Default::default()
            },
        };
        let one = first_step_windows(&d);
        assert_eq!(one.n, 4);
        assert_eq!(one.x, vec![0.0, 1.0, 1.0, 2.0, 10.0, 11.0, 11.0, 12.0]);
        one.validate().unwrap();
    }
}
