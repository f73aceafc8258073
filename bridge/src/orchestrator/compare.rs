//! The models of a run side by side (`report.json`'s `models`): per simulator and model kind,
//! the test prediction error and the closed-loop result, so that the user sees at once whether a
//! difficulty is the system, the data or the model.

use serde::{Deserialize, Serialize};

use super::{ControlReport, TrainReport};
use crate::services::model_kind::ModelKind;

/// One simulator's model of one kind.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelResult {
    /// Simulator id.
    pub sim: String,
    /// The model's kind.
    pub kind: ModelKind,
    /// Its name in the store.
    pub model: String,
    /// Its test prediction error (SPEC's `L_pred` on the test windows), as the trainer reported
    /// it; `None` without test windows.
    pub test_prediction_error: Option<f64>,
    /// True when that error is in z-scored units (a model trained with `normalise = true`),
    /// false in the data's own units.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub test_error_normalised: bool,
    /// The control run with it; `None` when the simulator is not controlled.
    pub control: Option<ControlSummary>,
}

/// The figures of one control run that compare models.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ControlSummary {
    /// Closed-loop steps.
    pub steps: usize,
    /// Final error norm (angles wrapped).
    pub final_error: f64,
    /// Tracking RMS over every state and step.
    pub tracking_rms_total: f64,
    /// First step from which the goal was held; `None` = never.
    pub time_to_goal_steps: Option<usize>,
    /// Solves whose status was not `solved`.
    pub not_solved: usize,
}

/// The side-by-side table of `trained` (each model with its kind, in training order) and the
/// control runs `controls` (matched by simulator and model name; the model's first MPC row, not a
/// baseline's).
pub fn side_by_side(
    trained: &[(ModelKind, TrainReport)],
    controls: &[ControlReport],
) -> Vec<ModelResult> {
    trained
        .iter()
        .map(|(kind, t)| ModelResult {
            sim: t.sim.clone(),
            kind: *kind,
            model: t.model.clone(),
            test_prediction_error: t
                .metrics
                .get("test_prediction_error")
                .and_then(serde_json::Value::as_f64),
            test_error_normalised: t.metrics["config"]["normalise"] == true,
            control: controls
                .iter()
                .find(|c| {
                    c.sim == t.sim
                        && c.model == t.model
                        && c.controller == crate::scenario::Controller::Mpc
                })
                .map(|c| ControlSummary {
                    steps: c.u.len(),
                    final_error: c.final_error,
                    tracking_rms_total: c.tracking_rms_total,
                    time_to_goal_steps: c.time_to_goal_steps,
                    not_solved: c.not_solved,
                }),
        })
        .collect()
}

/// `results` as text, one header and one line per model, simulators together:
/// `sim  kind  test L_pred  final error  tracking RMS  time to goal  not solved` (an error in
/// z-scored units marked `(z)`).
pub fn table(results: &[ModelResult]) -> String {
    let mut rows = vec![[
        "simulator".to_string(),
        "model".into(),
        "test L_pred".into(),
        "final error".into(),
        "tracking RMS".into(),
        "time to goal".into(),
        "not solved".into(),
    ]];
    let mut order: Vec<&ModelResult> = results.iter().collect();
    // Stable: the kinds keep their listed order within each simulator.
    order.sort_by_key(|r| results.iter().position(|o| o.sim == r.sim));
    for r in order {
        let dash = || "-".to_string();
        let c = r.control.as_ref();
        rows.push([
            r.sim.clone(),
            r.kind.to_string(),
            r.test_prediction_error.map_or_else(dash, |e| {
                let z = if r.test_error_normalised { " (z)" } else { "" };
                format!("{e:.3e}{z}")
            }),
            c.map_or_else(dash, |c| format!("{:.4}", c.final_error)),
            c.map_or_else(dash, |c| format!("{:.4}", c.tracking_rms_total)),
            c.map_or_else(dash, |c| {
                c.time_to_goal_steps
                    .map_or_else(|| "never".into(), |k| format!("{k} steps"))
            }),
            c.map_or_else(dash, |c| format!("{} of {}", c.not_solved, c.steps)),
        ]);
    }
    let widths: Vec<usize> = (0..7)
        .map(|i| rows.iter().map(|r| r[i].chars().count()).max().unwrap_or(0))
        .collect();
    rows.iter()
        .map(|r| {
            let cells: Vec<String> = r
                .iter()
                .zip(&widths)
                .map(|(c, w)| format!("{c:<w$}"))
                .collect();
            cells.join("  ").trim_end().to_string()
        })
        .collect::<Vec<_>>()
        .join("\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trained(sim: &str, model: &str, err: serde_json::Value) -> TrainReport {
        TrainReport {
            sim: sim.into(),
            model: model.into(),
            job: "j".into(),
            metrics: serde_json::json!({ "test_prediction_error": err }),
            reused: false,
        }
    }

    #[test]
    fn each_model_meets_its_own_control_run() {
        let t = vec![
            (ModelKind::Koopman, trained("a", "s-a", 0.02.into())),
            (ModelKind::Edmd, trained("a", "s-a-edmd", 0.5.into())),
            (ModelKind::Koopman, trained("b", "s-b", 0.3.into())),
        ];
        let control = |model: &str, final_error: f64| {
            let mut c: ControlReport = serde_json::from_value(serde_json::json!({
                "sim": "a", "model": model, "state_names": [], "input_names": [], "dt": 0.1,
                "reference": [], "x": [], "u": [[0.0], [0.0]], "final_error": final_error,
                "time_to_goal_steps": null, "solve_median_us": 0.0,
                "solve_round_trip_median_us": 0.0, "not_solved": 1,
            }))
            .unwrap();
            c.time_to_goal_steps = (final_error < 0.1).then_some(7);
            c
        };
        let mut t = t;
        t[2].1.metrics["config"] = serde_json::json!({"normalise": true});
        let r = side_by_side(&t, &[control("s-a-edmd", 0.9), control("s-a", 0.01)]);
        assert_eq!(r.len(), 3);
        assert_eq!(
            (r[0].kind, r[0].test_prediction_error),
            (ModelKind::Koopman, Some(0.02))
        );
        assert_eq!(r[0].control.as_ref().unwrap().final_error, 0.01);
        assert_eq!(r[1].control.as_ref().unwrap().final_error, 0.9);
        assert_eq!(r[1].control.as_ref().unwrap().steps, 2);
        assert_eq!(
            (r[2].test_prediction_error, &r[2].control),
            (Some(0.3), &None)
        );
        assert!(r[2].test_error_normalised && !r[0].test_error_normalised);
        let text = table(&r);
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 4, "{text}");
        assert!(
            lines[1].starts_with("a          koopman  2.000e-2"),
            "{text}"
        );
        assert!(lines[1].ends_with("7 steps       1 of 2"), "{text}");
        assert!(
            lines[2].contains("edmd") && lines[2].contains("never"),
            "{text}"
        );
        assert!(
            lines[3].starts_with("b ") && lines[3].ends_with('-'),
            "{text}"
        );
        assert!(lines[3].contains("3.000e-1 (z)"), "{text}");
    }
}
