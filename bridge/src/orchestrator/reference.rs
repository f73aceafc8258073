//! The reference a closed loop follows: a fixed state (or stacked horizon) from `reference`, a
//! time-varying trajectory from `reference_file` (a float64 `.npy` of shape (T, nx)), or a plan
//! (that trajectory and its feed-forward inputs from `feedforward_file`), and what of it the MPC
//! service is given at each step.

use std::path::{Path, PathBuf};

use koopman::data::npy;

use super::commands::Placeholders;
use crate::error::{Error, Result};
use crate::scenario::ControlSpec;

/// What a closed loop tracks.
#[derive(Clone, Debug, PartialEq)]
pub enum Reference {
    /// One state (`nx` values, held over the horizon) or the stacked x_1..x_H (`H·nx`).
    Fixed(Vec<f64>),
    /// Row k is the reference state at step k; rows past the end repeat the last.
    Trajectory(Vec<Vec<f64>>),
    /// A planned trajectory with the inputs that realise it: the MPC plans the deviation from
    /// the plan (error-state MPC). Rows past the end of either repeat their last.
    Plan {
        /// Row k: the planned state at step k (nx values).
        states: Vec<Vec<f64>>,
        /// Row k: the planned input at step k (nu values).
        inputs: Vec<Vec<f64>>,
    },
}

impl Reference {
    /// The reference state at step `k` (`nx` values): for [`Reference::Fixed`] its first `nx`
    /// values.
    pub fn at(&self, k: usize, nx: usize) -> Vec<f64> {
        match self {
            Reference::Fixed(r) => r[..nx.min(r.len())].to_vec(),
            Reference::Trajectory(rows) | Reference::Plan { states: rows, .. } => {
                row(rows, k).to_vec()
            }
        }
    }

    /// The `reference` the MPC service is given at step `k` with horizon `h`: the fixed vector
    /// as it is; the stacked rows k+1..=k+h of a trajectory (the states the planned inputs lead
    /// to); a plan's state at step k (its feed-forward carries the rest).
    pub fn window(&self, k: usize, h: usize) -> Vec<f64> {
        match self {
            Reference::Fixed(r) => r.clone(),
            Reference::Trajectory(rows) => stacked(rows, k + 1, h),
            Reference::Plan { states, .. } => row(states, k).to_vec(),
        }
    }

    /// The `feedforward` the MPC service is given at step `k` with horizon `h`: a plan's inputs
    /// at steps k..k+h−1, stacked; empty for the other references.
    pub fn feedforward(&self, k: usize, h: usize) -> Vec<f64> {
        match self {
            Reference::Plan { inputs, .. } => stacked(inputs, k, h),
            _ => Vec::new(),
        }
    }

    /// The trajectory's (or plan's) state rows, `None` for a fixed reference.
    pub fn rows(&self) -> Option<&[Vec<f64>]> {
        match self {
            Reference::Fixed(_) => None,
            Reference::Trajectory(rows) | Reference::Plan { states: rows, .. } => Some(rows),
        }
    }
}

/// Row `k` of `rows`, the last one past the end.
fn row(rows: &[Vec<f64>], k: usize) -> &[f64] {
    &rows[k.min(rows.len() - 1)]
}

/// Rows `first..first + n` of `rows` (the last one repeated past the end), stacked.
fn stacked(rows: &[Vec<f64>], first: usize, n: usize) -> Vec<f64> {
    (first..first + n)
        .flat_map(|i| row(rows, i).iter().copied())
        .collect()
}

/// The path `reference_file` names: `{out}` expanded, a relative path taken in `ph.base`.
pub fn reference_path(file: &str, ph: &Placeholders) -> PathBuf {
    let p = PathBuf::from(ph.expand(file, false));
    if p.is_relative() {
        ph.base.join(p)
    } else {
        p
    }
}

/// Reads a reference trajectory: a float64 `.npy` of shape (T, nx), T ≥ 1, finite values.
pub fn load_trajectory(path: &Path, nx: usize) -> Result<Vec<Vec<f64>>> {
    load_rows(path, nx, "reference_file", "the reference state")
}

/// Reads a plan's feed-forward inputs: a float64 `.npy` of shape (T, nu), T ≥ 1, finite values.
pub fn load_feedforward(path: &Path, nu: usize) -> Result<Vec<Vec<f64>>> {
    load_rows(path, nu, "feedforward_file", "the planned input")
}

/// A float64 `.npy` of shape (T, n), T ≥ 1, finite values, as rows; errors name `setting`
/// and say that row k is `row_is` at step k.
fn load_rows(path: &Path, width: usize, setting: &str, row_is: &str) -> Result<Vec<Vec<f64>>> {
    let bad = |m: String| Error::Config(format!("{setting} {}: {m}", path.display()));
    let bytes = std::fs::read(path).map_err(|e| bad(format!("cannot be read ({e})")))?;
    let a = npy::decode(&bytes).map_err(bad)?;
    match a.shape.as_slice() {
        [t, n] if *n == width && *t >= 1 => {}
        s => {
            return Err(bad(format!(
                "shape {s:?}, expected (T, {width}) with T ≥ 1 (row k = {row_is} at step k)"
            )))
        }
    }
    if let Some(v) = a.data.iter().find(|v| !v.is_finite()) {
        return Err(bad(format!("values must be finite, got {v}")));
    }
    Ok(a.data.chunks(width).map(<[f64]>::to_vec).collect())
}

/// The reference of a control entry for a simulator with `nx` states and `nu` inputs.
pub fn reference_of(
    ctrl: &ControlSpec,
    nx: usize,
    nu: usize,
    ph: &Placeholders,
) -> Result<Reference> {
    match (&ctrl.reference, &ctrl.reference_file) {
        (Some(r), _) => Ok(Reference::Fixed(r.clone())),
        (None, Some(f)) => {
            let states = load_trajectory(&reference_path(f, ph), nx)?;
            Ok(match &ctrl.feedforward_file {
                None => Reference::Trajectory(states),
                Some(ff) => Reference::Plan {
                    states,
                    inputs: load_feedforward(&reference_path(ff, ph), nu)?,
                },
            })
        }
        (None, None) => Err(Error::Config(
            "[control] needs `reference` or `reference_file`".into(),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_window_stacks_the_next_rows_and_repeats_the_last() {
        let r = Reference::Trajectory(vec![vec![0.0, 10.0], vec![1.0, 11.0], vec![2.0, 12.0]]);
        assert_eq!(r.window(0, 2), [1.0, 11.0, 2.0, 12.0]);
        assert_eq!(r.window(1, 3), [2.0, 12.0, 2.0, 12.0, 2.0, 12.0]);
        assert_eq!(r.at(7, 2), [2.0, 12.0]);
        assert!(r.feedforward(0, 2).is_empty());
        let p = Reference::Plan {
            states: vec![vec![0.0, 10.0], vec![1.0, 11.0]],
            inputs: vec![vec![-1.0], vec![-2.0], vec![-3.0]],
        };
        assert_eq!(p.window(1, 2), [1.0, 11.0]);
        assert_eq!(p.window(5, 2), [1.0, 11.0]);
        assert_eq!(p.feedforward(1, 3), [-2.0, -3.0, -3.0]);
        assert_eq!(p.rows().unwrap().len(), 2);
        let f = Reference::Fixed(vec![0.5, 0.0]);
        assert_eq!(f.window(9, 4), [0.5, 0.0]);
        assert_eq!(f.at(9, 2), [0.5, 0.0]);
    }

    #[test]
    fn a_trajectory_file_is_checked_for_shape_and_values() {
        let d = std::env::temp_dir().join(format!("kb-ref-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        let p = d.join("r.npy");
        std::fs::write(&p, npy::encode(&[3, 2], &[0.0, 1.0, 2.0, 3.0, 4.0, 5.0])).unwrap();
        assert_eq!(
            load_trajectory(&p, 2).unwrap(),
            vec![vec![0.0, 1.0], vec![2.0, 3.0], vec![4.0, 5.0]]
        );
        let e = load_trajectory(&p, 3).unwrap_err().to_string();
        assert!(e.contains("shape [3, 2]") && e.contains("r.npy"), "{e}");
        std::fs::write(&p, npy::encode(&[1, 2], &[0.0, f64::NAN])).unwrap();
        assert!(load_trajectory(&p, 2)
            .unwrap_err()
            .to_string()
            .contains("finite"));
        assert!(load_trajectory(&d.join("none.npy"), 2).is_err());
        std::fs::remove_dir_all(&d).ok();
    }
}
