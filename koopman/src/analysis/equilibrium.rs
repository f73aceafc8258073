//! Whether a regulation target can be held at all: the constant input that makes a state a fixed
//! point of the true system (`f(x_ref, u) = x_ref`), found by Gauss–Newton on the one-step map,
//! and whether it lies within the input bounds.
//!
//! A target that needs more input than the bounds allow cannot be held by any controller; the
//! `control` command reports this before blaming the model.

use faer::linalg::solvers::Solve;
use faer::{Mat, Side};

use crate::error::{ensure_finite, Error, Result};
use crate::systems::System;

/// The input that holds a state, as well as the system allows.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct HoldingInput {
    /// The least-squares holding input (unbounded).
    pub u: Vec<f64>,
    /// `‖f(x_ref, u) − x_ref‖₂` at that input (0 for an equilibrium).
    pub residual: f64,
    /// True when every component of `u` lies within the bounds.
    pub within_bounds: bool,
    /// The largest factor by which a component exceeds its bound (≤ 1 when within bounds).
    pub bound_ratio: f64,
}

/// Solves `min_u ‖f(x_ref, u) − x_ref‖²` by Gauss–Newton with a central-difference Jacobian,
/// starting from u = 0, and compares the result with `[u_min, u_max]`.
pub fn holding_input(
    system: &dyn System,
    x_ref: &[f64],
    u_min: &[f64],
    u_max: &[f64],
) -> Result<HoldingInput> {
    let (nx, nu) = (system.nx(), system.nu());
    if x_ref.len() != nx {
        return Err(Error::dimension("target state", nx, x_ref.len()));
    }
    if u_min.len() != nu || u_max.len() != nu {
        return Err(Error::dimension("input bounds", nu, u_min.len()));
    }
    ensure_finite("target state", x_ref)?;
    if nu == 0 {
        return Err(Error::InvalidArgument(format!(
            "{} has no inputs",
            system.name()
        )));
    }
    let residual_at = |u: &[f64]| {
        let mut next = vec![0.0; nx];
        system.step(x_ref, u, &mut next);
        next.iter()
            .zip(x_ref)
            .map(|(a, b)| a - b)
            .collect::<Vec<_>>()
    };
    let norm = |v: &[f64]| v.iter().map(|e| e * e).sum::<f64>().sqrt();
    let mut u = vec![0.0; nu];
    let mut r = residual_at(&u);
    for _ in 0..50 {
        // Jacobian J (nx × nu) by central differences, step scaled to the input range.
        let mut jac = Mat::<f64>::zeros(nx, nu);
        for j in 0..nu {
            let h = 1e-5 * (u_max[j] - u_min[j]).abs().max(1.0);
            let (mut up, mut um) = (u.clone(), u.clone());
            up[j] += h;
            um[j] -= h;
            let (rp, rm) = (residual_at(&up), residual_at(&um));
            for i in 0..nx {
                jac[(i, j)] = (rp[i] - rm[i]) / (2.0 * h);
            }
        }
        let jtj = jac.transpose() * &jac;
        let jtr = jac.transpose() * Mat::from_fn(nx, 1, |i, _| r[i]);
        let scale = (0..nu).map(|i| jtj[(i, i)]).fold(0.0f64, f64::max);
        if scale == 0.0 {
            break; // the input does not move the state: u = 0 is as good as any
        }
        let mut damped = jtj.clone();
        for i in 0..nu {
            damped[(i, i)] += 1e-12 * scale;
        }
        let llt = damped
            .llt(Side::Lower)
            .map_err(|_| Error::Numerical("holding input: singular normal equations".into()))?;
        let du = llt.solve(&jtr);
        let before = norm(&r);
        let mut step = 1.0;
        loop {
            let trial: Vec<f64> = (0..nu).map(|i| u[i] - step * du[(i, 0)]).collect();
            let rt = residual_at(&trial);
            if norm(&rt) <= before || step < 1e-6 {
                u = trial;
                r = rt;
                break;
            }
            step *= 0.5;
        }
        if (before - norm(&r)).abs() <= 1e-14 * before.max(1e-300) {
            break;
        }
    }
    ensure_finite("holding input", &u)?;
    let bound_ratio = u
        .iter()
        .zip(u_min.iter().zip(u_max))
        .map(|(&v, (&lo, &hi))| {
            if v > 0.0 && hi > 0.0 {
                v / hi
            } else if v < 0.0 && lo < 0.0 {
                v / lo
            } else if v == 0.0 {
                0.0
            } else {
                f64::INFINITY
            }
        })
        .fold(0.0f64, f64::max);
    let within_bounds = u
        .iter()
        .zip(u_min.iter().zip(u_max))
        .all(|(&v, (&lo, &hi))| v >= lo && v <= hi);
    Ok(HoldingInput {
        residual: norm(&r),
        u,
        within_bounds,
        bound_ratio,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::systems::by_name;

    #[test]
    fn damped_pendulum_holds_any_angle_below_the_horizontal_with_u_equal_g_tan_theta() {
        let sys = by_name("damped-pendulum").unwrap();
        let (lo, hi) = sys.input_bounds();
        let at_rest = holding_input(sys.as_ref(), &[0.0, 0.0], &lo, &hi).unwrap();
        assert!(at_rest.u[0].abs() < 1e-9 && at_rest.residual < 1e-12 && at_rest.within_bounds);
        // θ̈ = −9.8 sin θ + cos θ u = 0  ⇒  u = 9.8 tan θ (closed form).
        let h = holding_input(sys.as_ref(), &[0.5, 0.0], &lo, &hi).unwrap();
        assert!((h.u[0] - 9.8 * 0.5f64.tan()).abs() < 1e-6, "{h:?}");
        assert!(h.residual < 1e-9 && h.within_bounds);
        let far = holding_input(sys.as_ref(), &[1.3, 0.0], &lo, &hi).unwrap();
        assert!((far.u[0] - 9.8 * 1.3f64.tan()).abs() < 1e-5 && !far.within_bounds);
        assert!((far.bound_ratio - 9.8 * 1.3f64.tan() / 8.0).abs() < 1e-6);
    }

    #[test]
    fn double_pendulum_target_of_the_spec_needs_the_gravity_torque_g_of_theta() {
        let sys = by_name("double-pendulum").unwrap();
        let (lo, hi) = sys.input_bounds();
        let (t1, t2) = (1.2f64, -0.8f64);
        let h = holding_input(sys.as_ref(), &[t1, t2, 0.0, 0.0], &lo, &hi).unwrap();
        // At rest C = 0, so τ = G (SPEC): G1 = 2·9.8 cos θ1 + 9.8 cos(θ1 + θ2), G2 = 9.8 cos(θ1 + θ2).
        let g1 = 2.0 * 9.8 * t1.cos() + 9.8 * (t1 + t2).cos();
        let g2 = 9.8 * (t1 + t2).cos();
        assert!(
            (h.u[0] - g1).abs() < 1e-5 && (h.u[1] - g2).abs() < 1e-5,
            "{h:?}"
        );
        assert!(h.residual < 1e-9);
        assert!(!h.within_bounds && h.bound_ratio > 2.0, "{h:?}");
    }

    #[test]
    fn bad_arguments_are_typed_errors() {
        let sys = by_name("damped-pendulum").unwrap();
        assert!(holding_input(sys.as_ref(), &[0.0], &[-8.0], &[8.0]).is_err());
        assert!(holding_input(sys.as_ref(), &[0.0, f64::NAN], &[-8.0], &[8.0]).is_err());
        assert!(holding_input(sys.as_ref(), &[0.0, 0.0], &[-8.0, 0.0], &[8.0]).is_err());
    }
}
