//! The reference a closed loop follows: a fixed state (or stacked horizon) from `reference`, or
//! a time-varying trajectory from `reference_file` (a float64 `.npy` of shape (T, nx)), and the
//! H-step window of it the MPC service is given at each step.

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
}

impl Reference {
    /// The reference state at step `k` (`nx` values): for [`Reference::Fixed`] its first `nx`
    /// values.
    pub fn at(&self, k: usize, nx: usize) -> Vec<f64> {
        match self {
            Reference::Fixed(r) => r[..nx.min(r.len())].to_vec(),
            Reference::Trajectory(rows) => rows[k.min(rows.len() - 1)].clone(),
        }
    }

    /// What the MPC service is given at step `k` with horizon `h`: the fixed vector as it is,
    /// or the stacked rows k+1..=k+h of the trajectory (the states the planned inputs lead to).
    pub fn window(&self, k: usize, h: usize) -> Vec<f64> {
        match self {
            Reference::Fixed(r) => r.clone(),
            Reference::Trajectory(rows) => (1..=h)
                .flat_map(|i| rows[(k + i).min(rows.len() - 1)].iter().copied())
                .collect(),
        }
    }

    /// The trajectory's rows, `None` for a fixed reference.
    pub fn rows(&self) -> Option<&[Vec<f64>]> {
        match self {
            Reference::Fixed(_) => None,
            Reference::Trajectory(rows) => Some(rows),
        }
    }
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
    let bad = |m: String| Error::Config(format!("reference_file {}: {m}", path.display()));
    let bytes = std::fs::read(path).map_err(|e| bad(format!("cannot be read ({e})")))?;
    let a = npy::decode(&bytes).map_err(bad)?;
    match a.shape.as_slice() {
        [t, n] if *n == nx && *t >= 1 => {}
        s => {
            return Err(bad(format!(
                "shape {s:?}, expected (T, {nx}) with T ≥ 1 (row k = the reference state at step k)"
            )))
        }
    }
    if let Some(v) = a.data.iter().find(|v| !v.is_finite()) {
        return Err(bad(format!("values must be finite, got {v}")));
    }
    Ok(a.data.chunks(nx).map(<[f64]>::to_vec).collect())
}

/// The reference of a control entry for a simulator with `nx` states.
pub fn reference_of(ctrl: &ControlSpec, nx: usize, ph: &Placeholders) -> Result<Reference> {
    match (&ctrl.reference, &ctrl.reference_file) {
        (Some(r), _) => Ok(Reference::Fixed(r.clone())),
        (None, Some(f)) => Ok(Reference::Trajectory(load_trajectory(
            &reference_path(f, ph),
            nx,
        )?)),
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
