//! The general linear constraints `G U ≤ h(z_0, u_prev)` of the condensed MPC: input bounds,
//! input-rate bounds and state bounds (linear in U because `x = P z`).

use faer::Mat;

use super::condensed::Condensed;
use super::config::MpcConfig;
use crate::error::{Error, Result};

/// Where a row's right-hand side gets its step-dependent part from.
#[derive(Clone, Copy, Debug)]
enum Varying {
    /// Constant row.
    None,
    /// `+ sign · (Φ z_0)[k]` (state bounds).
    Free { k: usize, sign: f64 },
    /// `+ sign · u_prev[i]` (the first input-rate rows).
    Previous { i: usize, sign: f64 },
}

/// One constraint row: its nonzero coefficients, its constant bound and its varying part.
type Row = (Vec<(usize, f64)>, f64, Varying);

/// `G U ≤ h` with `h = h0 + (terms from Φ z_0 and u_prev)`; G is fixed.
#[derive(Clone, Debug)]
pub struct LinearConstraints {
    /// The constraint matrix G (m × H·nu).
    pub g: Mat<f64>,
    h0: Vec<f64>,
    varying: Vec<Varying>,
}

/// Per-variable box bounds of the stacked inputs from the config (±∞ where unset).
pub fn input_box(cfg: &MpcConfig, nu: usize, horizon: usize) -> Result<(Vec<f64>, Vec<f64>)> {
    let lo = bound_vec("u_min", cfg.u_min.as_deref(), nu, f64::NEG_INFINITY)?;
    let hi = bound_vec("u_max", cfg.u_max.as_deref(), nu, f64::INFINITY)?;
    if let Some(i) = (0..nu).find(|&i| lo[i] > hi[i]) {
        return Err(Error::InvalidArgument(format!(
            "infeasible input bounds: u_min[{i}] = {} > u_max[{i}] = {}",
            lo[i], hi[i]
        )));
    }
    Ok((
        (0..horizon * nu).map(|k| lo[k % nu]).collect(),
        (0..horizon * nu).map(|k| hi[k % nu]).collect(),
    ))
}

fn bound_vec(what: &str, v: Option<&[f64]>, n: usize, default: f64) -> Result<Vec<f64>> {
    match v {
        None => Ok(vec![default; n]),
        Some(v) if v.len() != n => Err(Error::dimension(what, n, v.len())),
        Some(v) if v.iter().any(|x| x.is_nan()) => Err(Error::NonFinite(what.to_string())),
        Some(v) => Ok(v.to_vec()),
    }
}

impl LinearConstraints {
    /// Builds every finite bound of the config as rows of `G U ≤ h`.
    pub fn build(cfg: &MpcConfig, c: &Condensed) -> Result<Self> {
        let (nu, nx, hz) = (c.nu, c.nx, c.horizon);
        let n = c.n_vars();
        let mut rows: Vec<Row> = Vec::new();
        let (lo, hi) = input_box(cfg, nu, hz)?;
        for k in 0..n {
            if hi[k].is_finite() {
                rows.push((vec![(k, 1.0)], hi[k], Varying::None));
            }
            if lo[k].is_finite() {
                rows.push((vec![(k, -1.0)], -lo[k], Varying::None));
            }
        }
        if let Some(du) = &cfg.du_max {
            if du.len() != nu {
                return Err(Error::dimension("du_max", nu, du.len()));
            }
            if du.iter().any(|v| v.is_nan() || *v < 0.0) {
                return Err(Error::InvalidArgument("du_max must be ≥ 0".into()));
            }
            for t in 0..hz {
                for (i, &dui) in du.iter().enumerate() {
                    if !dui.is_finite() {
                        continue;
                    }
                    let k = t * nu + i;
                    if t == 0 {
                        rows.push((vec![(k, 1.0)], dui, Varying::Previous { i, sign: 1.0 }));
                        rows.push((vec![(k, -1.0)], dui, Varying::Previous { i, sign: -1.0 }));
                    } else {
                        let p = k - nu;
                        rows.push((vec![(k, 1.0), (p, -1.0)], dui, Varying::None));
                        rows.push((vec![(k, -1.0), (p, 1.0)], dui, Varying::None));
                    }
                }
            }
        }
        let xmax = bound_vec("x_max", cfg.x_max.as_deref(), nx, f64::INFINITY)?;
        let xmin = bound_vec("x_min", cfg.x_min.as_deref(), nx, f64::NEG_INFINITY)?;
        if let Some(i) = (0..nx).find(|&i| xmin[i] > xmax[i]) {
            return Err(Error::InvalidArgument(format!(
                "infeasible state bounds: x_min[{i}] > x_max[{i}]"
            )));
        }
        for t in 0..hz {
            for i in 0..nx {
                let k = t * nx + i;
                let gam: Vec<(usize, f64)> = (0..n)
                    .map(|j| (j, c.gamma[(k, j)]))
                    .filter(|p| p.1 != 0.0)
                    .collect();
                if xmax[i].is_finite() {
                    rows.push((gam.clone(), xmax[i], Varying::Free { k, sign: -1.0 }));
                }
                if xmin[i].is_finite() {
                    let neg = gam.iter().map(|&(j, v)| (j, -v)).collect();
                    rows.push((neg, -xmin[i], Varying::Free { k, sign: 1.0 }));
                }
            }
        }
        let m = rows.len();
        let mut g = Mat::<f64>::zeros(m, n);
        let mut h0 = Vec::with_capacity(m);
        let mut varying = Vec::with_capacity(m);
        for (r, (coefs, b, v)) in rows.into_iter().enumerate() {
            for (j, val) in coefs {
                g[(r, j)] = val;
            }
            h0.push(b);
            varying.push(v);
        }
        Ok(LinearConstraints { g, h0, varying })
    }

    /// Number of rows m.
    pub fn len(&self) -> usize {
        self.h0.len()
    }

    /// True if there are no constraints.
    pub fn is_empty(&self) -> bool {
        self.h0.is_empty()
    }

    /// The right-hand side for a step: `free` = Φ z_0 (H·nx), `u_prev` = previous input (nu).
    pub fn rhs(&self, free: &[f64], u_prev: &[f64], h: &mut Vec<f64>) {
        h.clear();
        h.extend(self.h0.iter().zip(&self.varying).map(|(&b, v)| match *v {
            Varying::None => b,
            Varying::Free { k, sign } => b + sign * free[k],
            Varying::Previous { i, sign } => b + sign * u_prev[i],
        }));
    }

    /// The largest violation `max(G u − h, 0)` (for tests and reports).
    pub fn max_violation(&self, u: &[f64], h: &[f64]) -> f64 {
        let mut gu = vec![0.0; self.len()];
        super::condensed::gemv_acc(self.g.as_ref(), u, &mut gu);
        gu.iter().zip(h).map(|(a, b)| a - b).fold(0.0f64, f64::max)
    }
}
