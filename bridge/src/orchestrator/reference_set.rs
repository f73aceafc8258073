//! The references of a tracking task (`[control] references = "FILE.npz"`): `x.npy` (N, T+1, nx)
//! and optionally `u.npy` (N, T, nu), the inputs that realised them (a collected dataset's
//! layout), read and checked against the simulator before any loop starts.

use std::path::Path;

use koopman::data::npz::read_npz_arrays;

use crate::error::{Error, Result};

/// N references of T transitions each.
#[derive(Clone, Debug, PartialEq)]
pub struct ReferenceSet {
    /// `x[i][k]`: reference i's state at step k (T+1 rows of nx).
    pub x: Vec<Vec<Vec<f64>>>,
    /// `u[i][k]`: the input that drove reference i from step k to k+1 (T rows of nu), when the
    /// file has them.
    pub u: Option<Vec<Vec<Vec<f64>>>>,
}

impl ReferenceSet {
    /// Reads `path` for a simulator with `nx` states and `nu` inputs; every error names the key
    /// (`[control].references`), the file and what is wrong.
    pub fn load(path: &Path, nx: usize, nu: usize) -> Result<ReferenceSet> {
        let bad =
            |m: String| Error::Config(format!("[control].references {}: {m}", path.display()));
        let arrays = read_npz_arrays(path, &["x.npy", "u.npy"]).map_err(|e| bad(e.to_string()))?;
        let mut it = arrays.into_iter();
        let (x, u) = (it.next().flatten(), it.next().flatten());
        let x = x.ok_or_else(|| bad("no member x (N, T+1, nx)".into()))?;
        let [n, t1, xw] = x.shape[..] else {
            return Err(bad(format!(
                "x has shape {:?}, expected (N, T+1, nx)",
                x.shape
            )));
        };
        if xw != nx {
            return Err(bad(format!(
                "x has {xw} states per row, the simulator has nx = {nx}"
            )));
        }
        if n == 0 || t1 < 2 {
            return Err(bad(format!(
                "x has shape {:?}: at least one reference of at least one transition is needed",
                x.shape
            )));
        }
        if let Some(v) = x.data.iter().find(|v| !v.is_finite()) {
            return Err(bad(format!("x must be finite, it holds {v}")));
        }
        let x = split(&x.data, n, t1, nx);
        let u = match u {
            None => None,
            Some(u) => {
                if u.shape != [n, t1 - 1, nu] {
                    return Err(bad(format!(
                        "u has shape {:?}, expected ({n}, {}, {nu}) for x of shape ({n}, {t1}, \
                         {nx}) and a simulator with nu = {nu}",
                        u.shape,
                        t1 - 1
                    )));
                }
                if let Some(v) = u.data.iter().find(|v| !v.is_finite()) {
                    return Err(bad(format!("u must be finite, it holds {v}")));
                }
                Some(split(&u.data, n, t1 - 1, nu))
            }
        };
        Ok(ReferenceSet { x, u })
    }

    /// How many references.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Transitions per reference (T).
    pub fn steps(&self) -> usize {
        self.x[0].len() - 1
    }
}

/// `data` (n · rows · width values) as n blocks of `rows` rows.
fn split(data: &[f64], n: usize, rows: usize, width: usize) -> Vec<Vec<Vec<f64>>> {
    (0..n)
        .map(|i| {
            (0..rows)
                .map(|k| data[(i * rows + k) * width..(i * rows + k + 1) * width].to_vec())
                .collect()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use koopman::data::{npy, npz::write_npz};

    fn write(path: &Path, x: (&[usize], &[f64]), u: Option<(&[usize], &[f64])>) {
        let xb = npy::encode(x.0, x.1);
        let ub = u.map(|(s, d)| npy::encode(s, d));
        let mut m: Vec<(&str, &[u8])> = vec![("x.npy", &xb)];
        if let Some(ub) = &ub {
            m.push(("u.npy", ub));
        }
        write_npz(path, &m).unwrap();
    }

    #[test]
    fn references_are_read_and_every_disagreement_is_named() {
        let d = std::env::temp_dir().join(format!("kb-refset-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        let p = d.join("r.npz");
        let xs: Vec<f64> = (0..12).map(f64::from).collect(); // 2 refs × 3 states × nx 2
        let us: Vec<f64> = (0..4).map(f64::from).collect(); // 2 refs × 2 steps × nu 1
        write(&p, (&[2, 3, 2], &xs), Some((&[2, 2, 1], &us)));
        let r = ReferenceSet::load(&p, 2, 1).unwrap();
        assert_eq!((r.len(), r.steps()), (2, 2));
        assert_eq!(r.x[1][2], vec![10.0, 11.0]);
        assert_eq!(r.u.as_ref().unwrap()[1], vec![vec![2.0], vec![3.0]]);
        let err = |nx, nu| ReferenceSet::load(&p, nx, nu).unwrap_err().to_string();
        assert!(err(3, 1).contains("nx = 3"), "{}", err(3, 1));
        assert!(err(2, 2).contains("u has shape [2, 2, 1]"), "{}", err(2, 2));
        write(&p, (&[2, 3, 2], &xs), Some((&[2, 3, 1], &[0.0; 6])));
        assert!(err(2, 1).contains("expected (2, 2, 1)"), "{}", err(2, 1));
        let mut nan = xs.clone();
        nan[5] = f64::NAN;
        write(&p, (&[2, 3, 2], &nan), None);
        assert!(err(2, 1).contains("finite"), "{}", err(2, 1));
        write(&p, (&[2, 3, 2], &xs), None);
        assert!(ReferenceSet::load(&p, 2, 1).unwrap().u.is_none());
        std::fs::write(&p, b"not a zip").unwrap();
        assert!(err(2, 1).contains("[control].references"));
        assert!(ReferenceSet::load(&d.join("none.npz"), 2, 1).is_err());
        std::fs::remove_dir_all(&d).ok();
    }
}
