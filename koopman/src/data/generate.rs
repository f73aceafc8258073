//! Generation of windows from a reference system: parallel over windows, one derived random
//! stream per window, so the result is identical for any number of threads.

use super::{Dataset, DatasetMeta, Pairing};
use crate::rng::Rng;
use crate::systems::System;
use crate::{Error, Result};
use rayon::prelude::*;

/// Windows per parallel work unit (also the granularity of progress reports).
const BLOCK: usize = 512;

/// The number of worker threads generation uses (rayon's pool; `RAYON_NUM_THREADS` sets it).
pub fn worker_threads() -> usize {
    rayon::current_num_threads()
}

/// Generates `windows` windows of `steps` transitions from `system`, with data seed `seed` and
/// the given input pairing (see the module documentation of [`crate::data`]). Window `i` uses
/// the random stream `Rng::derive(seed, i)`: initial state first, then one input per row.
pub fn generate(
    system: &dyn System,
    windows: usize,
    steps: usize,
    seed: u64,
    pairing: Pairing,
) -> Result<Dataset> {
    generate_with_progress(system, windows, steps, seed, pairing, &|_| {})
}

/// Like [`generate`], calling `progress(k)` each time `k` more windows are done (from worker
/// threads, in no particular order).
pub fn generate_with_progress(
    system: &dyn System,
    windows: usize,
    steps: usize,
    seed: u64,
    pairing: Pairing,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Dataset> {
    if windows == 0 {
        return Err(Error::InvalidArgument(
            "number of windows must be positive".into(),
        ));
    }
    if steps == 0 {
        return Err(Error::InvalidArgument(
            "steps per window T must be positive".into(),
        ));
    }
    let (nx, nu) = (system.nx(), system.nu());
    // Refuse sizes that cannot be allocated instead of aborting (16 GiB of values at most).
    const MAX_VALUES: usize = 1 << 31;
    let too_many = || {
        Error::InvalidArgument(format!(
            "{windows} windows of {steps} steps are too many (more than {MAX_VALUES} values)"
        ))
    };
    let sx = steps
        .checked_add(1)
        .and_then(|t| t.checked_mul(nx))
        .ok_or_else(too_many)?;
    let su = steps.checked_mul(nu).ok_or_else(too_many)?;
    sx.checked_add(su)
        .and_then(|per| per.checked_mul(windows))
        .filter(|&v| v <= MAX_VALUES)
        .ok_or_else(too_many)?;
    let mut x = vec![0.0; windows * sx];
    let mut u = vec![0.0; windows * su];
    // Chunk both arrays by blocks of windows; zip keeps the blocks paired. For nu = 0 the input
    // array is empty, so give it one empty chunk per block instead.
    let xs: Vec<&mut [f64]> = x.chunks_mut(BLOCK * sx).collect();
    let mut empty: Vec<Vec<f64>> = Vec::new();
    let us: Vec<&mut [f64]> = if su == 0 {
        empty.resize(xs.len(), Vec::new());
        empty.iter_mut().map(|v| v.as_mut_slice()).collect()
    } else {
        u.chunks_mut(BLOCK * su).collect()
    };
    xs.into_par_iter()
        .zip(us)
        .enumerate()
        .for_each(|(b, (xb, ub))| {
            let count = xb.len() / sx;
            for k in 0..count {
                let i = b * BLOCK + k;
                let mut rng = Rng::derive(seed, i as u64);
                let xw = &mut xb[k * sx..(k + 1) * sx];
                let uw = if su == 0 {
                    &mut [][..]
                } else {
                    &mut ub[k * su..(k + 1) * su]
                };
                window(system, &mut rng, pairing, steps, xw, uw);
            }
            progress(count);
        });
    let meta = DatasetMeta {
        env: system.name().to_string(),
        dt: system.dt(),
        state_names: system.state_names(),
        input_names: system.input_names(),
        pairing,
        seed,
        source: builtin_source(&system.parameters()),
        policy: "uniform random input each step (zero-order hold)".to_string(),
        region: None,
        window_flags: None,
    };
    let data = Dataset {
        n: windows,
        steps,
        nx,
        nu,
        x,
        u,
        meta,
    };
    data.validate()?;
    Ok(data)
}

/// Fills one window: `xw` has `(T+1)·nx` values, `uw` has `T·nu`.
fn window(
    system: &dyn System,
    rng: &mut Rng,
    pairing: Pairing,
    steps: usize,
    xw: &mut [f64],
    uw: &mut [f64],
) {
    let (nx, nu) = (system.nx(), system.nu());
    xw[..nx].copy_from_slice(&system.sample_initial_state(rng));
    match pairing {
        Pairing::Aligned => {
            for t in 0..steps {
                let ut = system.sample_input(rng);
                uw[t * nu..(t + 1) * nu].copy_from_slice(&ut);
                let (cur, next) = xw.split_at_mut((t + 1) * nx);
                system.step(&cur[t * nx..], &ut, &mut next[..nx]);
            }
        }
        Pairing::Reference => {
            // Row 0's input is drawn but never applied; row t (t ≥ 1) holds the input that drove
            // x_{t−1} → x_t. Rows 0..T−1 are stored; row T's input (last transition) is not.
            let u0 = system.sample_input(rng);
            uw[..nu].copy_from_slice(&u0);
            for t in 1..=steps {
                let ut = system.sample_input(rng);
                let (cur, next) = xw.split_at_mut(t * nx);
                system.step(&cur[(t - 1) * nx..], &ut, &mut next[..nx]);
                if t < steps {
                    uw[t * nu..(t + 1) * nu].copy_from_slice(&ut);
                }
            }
        }
    }
}

/// The `source` recorded for data generated from a built-in system: `koopman::systems`, with the
/// instance's parameters in parentheses when it has any (`koopman::systems (n_poly=10)`).
pub fn builtin_source(parameters: &str) -> String {
    if parameters.is_empty() {
        BUILTIN_SOURCE.to_string()
    } else {
        format!("{BUILTIN_SOURCE} ({parameters})")
    }
}

/// The parameters named by a [`builtin_source`] (`n_poly=10`), or `None` for a source without
/// any or one that is not a built-in system's.
pub fn builtin_source_parameters(source: &str) -> Option<&str> {
    source
        .strip_prefix(BUILTIN_SOURCE)?
        .strip_prefix(" (")?
        .strip_suffix(')')
        .filter(|p| !p.is_empty())
}

const BUILTIN_SOURCE: &str = "koopman::systems";

#[cfg(test)]
mod tests {
    use super::*;
    use crate::systems::by_name;

    fn max_diff(a: &[f64], b: &[f64]) -> f64 {
        a.iter()
            .zip(b)
            .map(|(p, q)| (p - q).abs())
            .fold(0.0, f64::max)
    }

    #[test]
    fn aligned_pairing_reproduces_every_transition() {
        for env in ["damped", "double", "polynomial"] {
            let s = by_name(env).unwrap();
            let steps = s.window_steps();
            let d = generate(s.as_ref(), 40, steps, 7, Pairing::Aligned).unwrap();
            assert_eq!((d.nx, d.nu, d.steps), (s.nx(), s.nu(), steps));
            let mut y = vec![0.0; d.nx];
            for i in 0..d.n {
                for t in 0..steps {
                    s.step(d.state(i, t), d.input(i, t), &mut y);
                    assert_eq!(
                        max_diff(&y, d.state(i, t + 1)),
                        0.0,
                        "{env} window {i} t {t}"
                    );
                }
            }
        }
    }

    #[test]
    fn reference_pairing_follows_the_reference_collector() {
        let s = by_name("damped").unwrap();
        let d = generate(s.as_ref(), 30, 15, 7, Pairing::Reference).unwrap();
        let mut y = vec![0.0; 2];
        let mut mismatched = 0;
        for i in 0..d.n {
            // Stored u_t (t ≥ 1) drove x_{t−1} → x_t.
            for t in 1..15 {
                s.step(d.state(i, t - 1), d.input(i, t), &mut y);
                assert_eq!(max_diff(&y, d.state(i, t)), 0.0, "window {i} t {t}");
            }
            // And the stored u_t is not the input of x_t → x_{t+1} (it is an independent draw).
            s.step(d.state(i, 0), d.input(i, 0), &mut y);
            if max_diff(&y, d.state(i, 1)) > 1e-6 {
                mismatched += 1;
            }
        }
        assert_eq!(mismatched, d.n, "u_0 must never be applied");
        // The same seed with the reference collector draws the same x_0 as the aligned one.
        let a = generate(s.as_ref(), 30, 15, 7, Pairing::Aligned).unwrap();
        assert_eq!(a.state(3, 0), d.state(3, 0));
        assert_eq!(a.input(3, 0), d.input(3, 0));
    }

    #[test]
    fn deterministic_for_any_thread_count_and_seed_sensitive() {
        let s = by_name("damped").unwrap();
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| generate(s.as_ref(), 1500, 15, 42, Pairing::Aligned).unwrap())
        };
        let one = run(1);
        let two = run(2);
        let three = run(3);
        assert_eq!(one, two);
        assert_eq!(one, three);
        let other = generate(s.as_ref(), 1500, 15, 43, Pairing::Aligned).unwrap();
        assert_eq!(one.meta.source, "koopman::systems");
        assert_ne!(one.x, other.x);
        // A prefix of a bigger generation is the smaller generation.
        let small = generate(s.as_ref(), 700, 15, 42, Pairing::Aligned).unwrap();
        assert_eq!(small, one.head(700).unwrap());
    }

    #[test]
    fn bad_arguments_are_errors() {
        let s = by_name("damped").unwrap();
        assert!(generate(s.as_ref(), 0, 15, 1, Pairing::Aligned).is_err());
        assert!(generate(s.as_ref(), 5, 0, 1, Pairing::Aligned).is_err());
        assert!(generate(s.as_ref(), usize::MAX / 2, 15, 1, Pairing::Aligned).is_err());
        assert!(generate(s.as_ref(), 5, usize::MAX / 2, 1, Pairing::Aligned).is_err());
    }

    #[test]
    fn builtin_source_parameters_read_back_what_the_source_records() {
        let poly = crate::systems::polynomial::PolynomialSystem::new(10).unwrap();
        let one = generate(&poly, 2, 1, 1, Pairing::Aligned).unwrap();
        assert_eq!(
            builtin_source_parameters(&one.meta.source),
            Some("n_poly=10")
        );
        assert_eq!(builtin_source_parameters(&builtin_source("")), None);
        assert_eq!(builtin_source_parameters("zenoh:sim/fmu0 (n_poly=3)"), None);
        assert_eq!(builtin_source_parameters("koopman::systems ()"), None);
    }
}
