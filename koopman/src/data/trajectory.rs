//! Windows cut from one trajectory (a closed loop's states and inputs), so that the dataset
//! metrics — `L_pred` above all — can be computed along a trajectory the data never saw.

use super::{Dataset, DatasetMeta};
use crate::{Error, Result};

impl Dataset {
    /// The windows of `steps` transitions of the trajectory `x_0..x_K`, `u_0..u_{K−1}`
    /// (`x_{k+1} = f(x_k, u_k)`), one starting at every `stride`-th step; `meta` describes them.
    /// A trajectory shorter than one window gives an empty dataset (`n = 0`).
    pub fn from_trajectory(
        x: &[Vec<f64>],
        u: &[Vec<f64>],
        steps: usize,
        stride: usize,
        meta: DatasetMeta,
    ) -> Result<Dataset> {
        if steps == 0 || stride == 0 {
            return Err(Error::InvalidArgument(format!(
                "windows need steps ≥ 1 and stride ≥ 1 (got {steps}, {stride})"
            )));
        }
        if x.len() != u.len() + 1 {
            return Err(Error::dimension(
                "trajectory states (inputs + 1)",
                u.len() + 1,
                x.len(),
            ));
        }
        let nx = x.first().map_or(0, Vec::len);
        let nu = u.first().map_or(0, Vec::len);
        if let Some(bad) = x.iter().find(|s| s.len() != nx) {
            return Err(Error::dimension("trajectory state", nx, bad.len()));
        }
        if let Some(bad) = u.iter().find(|s| s.len() != nu) {
            return Err(Error::dimension("trajectory input", nu, bad.len()));
        }
        let starts: Vec<usize> = (0..u.len().saturating_sub(steps - 1))
            .step_by(stride)
            .collect();
        let mut data = Dataset {
            n: starts.len(),
            steps,
            nx,
            nu,
            x: Vec::with_capacity(starts.len() * (steps + 1) * nx),
            u: Vec::with_capacity(starts.len() * steps * nu),
            meta,
        };
        for &k in &starts {
            x[k..=k + steps]
                .iter()
                .for_each(|s| data.x.extend_from_slice(s));
            u[k..k + steps]
                .iter()
                .for_each(|s| data.u.extend_from_slice(s));
        }
        Ok(data)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn windows_are_the_trajectory_slices_at_each_stride() {
        let x: Vec<Vec<f64>> = (0..8).map(|k| vec![k as f64, -(k as f64)]).collect();
        let u: Vec<Vec<f64>> = (0..7).map(|k| vec![10.0 + k as f64]).collect();
        let meta = crate::data::DatasetMeta {
            state_names: vec!["a".into(), "b".into()],
            input_names: vec!["u".into()],
            ..Default::default()
        };
        let d = Dataset::from_trajectory(&x, &u, 3, 2, meta.clone()).unwrap();
        // Starts 0, 2, 4 (a window from 6 would need u_6..u_8).
        assert_eq!((d.n, d.steps, d.nx, d.nu), (3, 3, 2, 1));
        for (i, k) in [0usize, 2, 4].into_iter().enumerate() {
            for t in 0..=3 {
                assert_eq!(d.state(i, t), x[k + t].as_slice());
            }
            for t in 0..3 {
                assert_eq!(d.input(i, t), u[k + t].as_slice());
            }
        }
        d.validate().unwrap();
        let short = Dataset::from_trajectory(&x[..2], &u[..1], 3, 1, meta.clone()).unwrap();
        assert_eq!(short.n, 0);
        assert!(Dataset::from_trajectory(&x, &u[..3], 3, 1, meta.clone()).is_err());
        assert!(Dataset::from_trajectory(&x, &u, 0, 1, meta).is_err());
    }
}
