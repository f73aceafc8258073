//! The EDMD dictionary's degree chosen by validation error: every degree from 1 to the feature
//! budget's is fitted on the training split and scored by its multi-step prediction error on the
//! validation split; the lowest error wins (a tie goes to the lower degree).

use super::{dictionary, fit, EdmdConfig, EdmdModel};
use crate::data::Dataset;
use crate::Result;
use serde::{Deserialize, Serialize};

/// One degree tried: its feature count and validation error (`None`: the rollout left the
/// floats — a degree that extrapolates wildly — or the fit failed).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DegreeTrial {
    /// Total polynomial degree.
    pub degree: usize,
    /// Dictionary size N at that degree.
    pub features: usize,
    /// Discounted multi-step prediction error on the validation split.
    pub validation_error: Option<f64>,
}

/// What the selection chose and why.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DegreeSelection {
    /// The degree of the returned model.
    pub chosen: usize,
    /// `true` when the degree was chosen by validation, `false` when `cfg.degree` fixed it.
    pub by_validation: bool,
    /// Every degree tried, in increasing order.
    pub trials: Vec<DegreeTrial>,
}

/// Fits EDMD on `train`. With `cfg.degree` set, that degree alone; otherwise every degree from
/// 1 to [`dictionary::auto_degree`]`(nx, cfg.max_features)`, keeping the one with the lowest
/// validation prediction error on `val` (discount `gamma`). Errors: the fit's, or every degree
/// failing.
pub fn fit_by_validation(
    train: &Dataset,
    val: &Dataset,
    cfg: &EdmdConfig,
    gamma: f64,
) -> Result<(EdmdModel, DegreeSelection)> {
    if let Some(d) = cfg.degree {
        let model = fit(train, cfg)?;
        let err = model.prediction_error(val, gamma)?;
        let trial = DegreeTrial {
            degree: d,
            features: model.dict.len(),
            validation_error: err.is_finite().then_some(err),
        };
        let selection = DegreeSelection {
            chosen: d,
            by_validation: false,
            trials: vec![trial],
        };
        return Ok((model, selection));
    }
    let top = dictionary::auto_degree(train.nx, cfg.max_features).max(1);
    let mut best: Option<(f64, EdmdModel)> = None;
    let mut trials = Vec::with_capacity(top);
    let mut first_error = None;
    for degree in 1..=top {
        let c = EdmdConfig {
            degree: Some(degree),
            ..cfg.clone()
        };
        let scored = fit(train, &c).and_then(|m| {
            let e = m.prediction_error(val, gamma)?;
            Ok((e, m))
        });
        let validation_error = match scored {
            Ok((e, m)) if e.is_finite() => {
                if best.as_ref().is_none_or(|(b, _)| e < *b) {
                    best = Some((e, m));
                }
                Some(e)
            }
            Ok(_) => None,
            Err(e) => {
                first_error.get_or_insert(e);
                None
            }
        };
        trials.push(DegreeTrial {
            degree,
            features: dictionary::feature_count(train.nx, degree),
            validation_error,
        });
    }
    match best {
        Some((_, model)) => {
            let chosen = model.config.degree.unwrap_or(1);
            let selection = DegreeSelection {
                chosen,
                by_validation: true,
                trials,
            };
            Ok((model, selection))
        }
        None => Err(first_error.unwrap_or_else(|| {
            crate::Error::InvalidArgument(format!(
                "EDMD: no degree from 1 to {top} predicts the validation split with a finite error"
            ))
        })),
    }
}
