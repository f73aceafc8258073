//! What the data of a control run say about it, for the diagnosis: how many collection windows
//! the simulator ended (a fall, a stop) or clipped, how much of the data's own spread the model
//! leaves unexplained, and how much of the closed loop ran outside the states the data cover.

use koopman::data::{Dataset, WindowFlags};
use serde::{Deserialize, Serialize};

/// A share of collection windows the simulator ended above this makes the data the first
/// suspect: the model learned the plant after the fall.
pub const ENDED_WINDOWS: f64 = 0.2;
/// A model whose prediction error is more than this share of the data's variance predicts its
/// own data poorly, whatever the units.
pub const UNEXPLAINED: f64 = 0.1;
/// Margin around the data's range, as a share of it, before a loop state counts as outside.
pub const RANGE_MARGIN: f64 = 0.1;

/// `report.json`'s `diagnoses[].data`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DataQuality {
    /// Windows of the split the figures below are about (the test split).
    pub windows: usize,
    /// How many windows of that collection the simulator flagged (`None`: not counted — windows
    /// the simulator ran itself, or data made in-process).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub window_flags: Option<WindowFlags>,
    /// The model's mean squared prediction error per state and step over the test windows
    /// against the test states' mean variance: 0 = exact, 1 = no better than the mean state.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unexplained_share: Option<f64>,
    /// The share of the closed loop's states with a component outside the test states' range
    /// (widened by [`RANGE_MARGIN`] of it on each side).
    pub loop_outside_data: f64,
}

impl DataQuality {
    /// The share of windows the simulator ended (`None` when not counted or no windows).
    pub fn ended_share(&self) -> Option<f64> {
        let f = self.window_flags?;
        (self.windows > 0).then(|| f.terminated as f64 / self.windows as f64)
    }
}

/// The data figures of a control run whose closed loop visited `loop_x`, with the model's
/// `window_test` error (the diagnosis's T-step error on `test`, γ = 1: a sum over the T steps of
/// the mean squared error per state).
pub fn data_quality(test: &Dataset, window_test: Option<f64>, loop_x: &[Vec<f64>]) -> DataQuality {
    let nx = test.nx;
    let states = test.x.chunks_exact(nx.max(1));
    let count = states.len().max(1) as f64;
    let mut mean = vec![0.0; nx];
    let mut lo = vec![f64::INFINITY; nx];
    let mut hi = vec![f64::NEG_INFINITY; nx];
    for s in test.x.chunks_exact(nx.max(1)) {
        for d in 0..nx {
            mean[d] += s[d] / count;
            lo[d] = lo[d].min(s[d]);
            hi[d] = hi[d].max(s[d]);
        }
    }
    let mut var = 0.0;
    for s in states {
        for d in 0..nx {
            var += (s[d] - mean[d]).powi(2) / count;
        }
    }
    let mean_var = var / nx.max(1) as f64;
    let unexplained_share = window_test
        .filter(|e| e.is_finite() && test.steps > 0 && mean_var > 0.0)
        .map(|e| e / test.steps as f64 / mean_var);
    let outside = loop_x
        .iter()
        .filter(|x| {
            x.iter().take(nx).enumerate().any(|(d, &v)| {
                let m = RANGE_MARGIN * (hi[d] - lo[d]);
                !(v >= lo[d] - m && v <= hi[d] + m)
            })
        })
        .count();
    DataQuality {
        windows: test.n,
        window_flags: test.meta.window_flags,
        unexplained_share,
        loop_outside_data: if loop_x.is_empty() {
            0.0
        } else {
            outside as f64 / loop_x.len() as f64
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data(x: Vec<f64>, flags: Option<WindowFlags>) -> Dataset {
        let n = x.len() / 3;
        Dataset {
            n,
            steps: 2,
            nx: 1,
            nu: 1,
            x,
            u: vec![0.0; n * 2],
            meta: koopman::data::DatasetMeta {
                window_flags: flags,
                ..Default::default()
            },
        }
    }

    #[test]
    fn the_figures_follow_their_definitions() {
        // States 0..=5: mean 2.5, variance 35/12, range [0, 5] widened by 0.5 on each side.
        let d = data(
            vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0],
            Some(WindowFlags {
                terminated: 1,
                truncated: 0,
                clipped: 0,
            }),
        );
        let loop_x = vec![vec![-0.4], vec![5.4], vec![5.6], vec![f64::NAN]];
        let q = data_quality(&d, Some(2.0 * 35.0 / 12.0 * 0.5), &loop_x);
        assert_eq!(q.windows, 2);
        assert_eq!(q.ended_share(), Some(0.5));
        assert!((q.unexplained_share.unwrap() - 0.5).abs() < 1e-12);
        // 5.6 is outside, and so is a non-finite state.
        assert_eq!(q.loop_outside_data, 0.5);
        let none = data_quality(&data(vec![1.0; 3], None), None, &[]);
        assert_eq!((none.ended_share(), none.unexplained_share), (None, None));
        assert_eq!(none.loop_outside_data, 0.0);
    }
}
