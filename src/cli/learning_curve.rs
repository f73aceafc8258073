//! The learning curve of a gradient-trained run — the training prediction loss averaged between
//! validations next to the validation prediction error — kept for `metrics.json` and drawn as
//! `learning-curve.png` beside the model.

use std::path::Path;

use koopman::train::Progress;
use serde::Serialize;

use crate::plot::{time_series_png, Panel, Series};

/// One validation point of the curve.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CurvePoint {
    /// Iterations done when the validation ran (1-based).
    pub iteration: usize,
    /// Mean of the batches' prediction loss since the previous validation point.
    pub train_prediction_loss: f64,
    /// Validation prediction error of the parameters after `iteration`.
    pub validation_prediction_error: f64,
}

/// Collects [`CurvePoint`]s from the trainer's progress reports.
#[derive(Debug, Default)]
pub struct LearningCurve {
    points: Vec<CurvePoint>,
    loss_sum: f64,
    loss_count: usize,
}

impl LearningCurve {
    /// Takes one iteration's report: adds its batch loss to the running mean and, when it carries
    /// a validation, closes a point.
    pub fn record(&mut self, progress: &Progress) {
        self.loss_sum += progress.loss.pred;
        self.loss_count += 1;
        if let Some(validation) = progress.validation {
            self.points.push(CurvePoint {
                iteration: progress.iteration,
                train_prediction_loss: self.loss_sum / self.loss_count as f64,
                validation_prediction_error: validation,
            });
            self.loss_sum = 0.0;
            self.loss_count = 0;
        }
    }

    /// The points so far, in iteration order.
    pub fn points(&self) -> &[CurvePoint] {
        &self.points
    }

    /// Draws both curves on a log₁₀ scale against the iteration, the best validation marked,
    /// into a PNG at `path` (atomically). Nothing is drawn for a run without validations.
    pub fn write_png(&self, path: &Path, title: &str) -> anyhow::Result<()> {
        if self.points.is_empty() {
            return Ok(());
        }
        let it: Vec<f64> = self.points.iter().map(|p| p.iteration as f64).collect();
        let log = |v: f64| if v > 0.0 { v.log10() } else { f64::NAN };
        let train: Vec<f64> = self
            .points
            .iter()
            .map(|p| log(p.train_prediction_loss))
            .collect();
        let val: Vec<f64> = self
            .points
            .iter()
            .map(|p| log(p.validation_prediction_error))
            .collect();
        let best = self
            .points
            .iter()
            .filter(|p| p.validation_prediction_error.is_finite())
            .min_by(|a, b| {
                a.validation_prediction_error
                    .total_cmp(&b.validation_prediction_error)
            });
        let mut series = vec![
            Series::new("training L_pred (mean since last validation)", &it, &train),
            Series::new("validation prediction error", &it, &val),
        ];
        if let Some(b) = best {
            series.push(
                Series::new(
                    format!(
                        "best validation {:.5} at {}",
                        b.validation_prediction_error, b.iteration
                    ),
                    &[b.iteration as f64],
                    &[log(b.validation_prediction_error)],
                )
                .markers(),
            );
        }
        let panel = Panel {
            title: "prediction loss".into(),
            y_label: "log10 L_pred".into(),
            series,
        };
        time_series_png(path, title, "iteration", &[panel], 900)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use koopman::train::loss::LossParts;

    fn progress(iteration: usize, pred: f64, validation: Option<f64>) -> Progress {
        Progress {
            iteration,
            total: 4,
            loss: LossParts {
                pred,
                ctrl: 0.0,
                cov: 0.0,
                total: pred,
            },
            lr: 1e-3,
            validation,
            best_validation: validation,
            iterations_per_second: 1.0,
        }
    }

    #[test]
    fn averages_the_batch_loss_between_validations() {
        let mut curve = LearningCurve::default();
        curve.record(&progress(1, 1.0, None));
        curve.record(&progress(2, 3.0, Some(0.5)));
        curve.record(&progress(3, 0.25, None));
        curve.record(&progress(4, 0.75, Some(0.125)));
        assert_eq!(
            curve.points(),
            &[
                CurvePoint {
                    iteration: 2,
                    train_prediction_loss: 2.0,
                    validation_prediction_error: 0.5
                },
                CurvePoint {
                    iteration: 4,
                    train_prediction_loss: 0.5,
                    validation_prediction_error: 0.125
                },
            ]
        );
        let dir = std::env::temp_dir().join(format!("koopbridge-curve-{}", std::process::id()));
        let path = dir.join("learning-curve.png");
        curve.write_png(&path, "test").unwrap();
        assert_eq!(&std::fs::read(&path).unwrap()[1..4], b"PNG");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
