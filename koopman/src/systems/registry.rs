//! The named reference systems (`koopbridge data gen --env NAME`) and their options.

use super::damped::DampedPendulum;
use super::double::DoublePendulum;
use super::polynomial::{self, PolynomialSystem};
use super::system::System;
use crate::{Error, Result};

/// Canonical names accepted by [`by_name`] (aliases: `damped`, `double`).
pub const NAMES: [&str; 3] = ["damped-pendulum", "double-pendulum", "polynomial"];

/// Options of the named systems that have parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SystemOptions {
    /// `n_poly` of the polynomial system (≥ 3).
    pub n_poly: usize,
}

impl Default for SystemOptions {
    fn default() -> Self {
        SystemOptions {
            n_poly: polynomial::DEFAULT_N_POLY,
        }
    }
}

/// The system called `name` (see [`NAMES`]) with default parameters.
pub fn by_name(name: &str) -> Result<Box<dyn System>> {
    by_name_with(name, &SystemOptions::default())
}

/// The system called `name` with the given options; an unknown name is an
/// [`Error::UnknownName`].
pub fn by_name_with(name: &str, opts: &SystemOptions) -> Result<Box<dyn System>> {
    match name {
        "damped-pendulum" | "damped" => Ok(Box::new(DampedPendulum::default())),
        "double-pendulum" | "double" => Ok(Box::new(DoublePendulum::default())),
        "polynomial" | "poly" => Ok(Box::new(PolynomialSystem::new(opts.n_poly)?)),
        _ => Err(Error::UnknownName {
            kind: "environment",
            name: name.to_string(),
            known: format!("{} (aliases: damped, double, poly)", NAMES.join(", ")),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_resolve_and_unknown_is_an_error() {
        for name in NAMES {
            let s = by_name(name).unwrap();
            assert_eq!(s.name(), name);
            assert_eq!(s.state_names().len(), s.nx());
            assert_eq!(s.input_names().len(), s.nu());
            let (lo, hi) = s.input_bounds();
            assert_eq!((lo.len(), hi.len()), (s.nu(), s.nu()));
        }
        assert_eq!(by_name("damped").unwrap().name(), "damped-pendulum");
        assert_eq!(by_name("double").unwrap().dt(), 0.01);
        assert_eq!(by_name("polynomial").unwrap().window_steps(), 1);
        let err = by_name("cartpole").err().expect("unknown name must fail");
        assert!(matches!(err, Error::UnknownName { .. }));
        assert!(err.to_string().contains("damped-pendulum"));
        assert!(by_name_with("polynomial", &SystemOptions { n_poly: 1 }).is_err());
    }

    #[test]
    fn samples_stay_in_the_ranges_of_the_spec() {
        let mut rng = crate::rng::Rng::new(1);
        let d = by_name("damped").unwrap();
        let dp = by_name("double").unwrap();
        let pi = std::f64::consts::PI;
        for _ in 0..2000 {
            let x = d.sample_initial_state(&mut rng);
            assert!(x[0].abs() <= 2.0 * pi && x[1].abs() <= 8.0);
            assert!(d.sample_input(&mut rng)[0].abs() <= 8.0);
            let y = dp.sample_initial_state(&mut rng);
            assert!(y[0].abs() <= 0.1 * pi && y[1].abs() <= 0.1 * pi);
            assert!(y[2].abs() <= 1.0 && y[3].abs() <= 1.0);
            assert!(dp.sample_input(&mut rng).iter().all(|u| u.abs() <= 6.0));
        }
    }
}
