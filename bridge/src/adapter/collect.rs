//! The simulator side of `collect`: a request checked against the simulator's info
//! ([`CollectPlan`]), the block's windows run in-process ([`run_windows`], what every backend
//! does unless it has a faster way) and the result cut into reply chunks.

use koopman::rng::Rng;

use crate::codec::{CollectChunk, MAX_VECTOR_LEN};
use crate::error::{ErrorCode, ErrorReply};
use crate::messages::{CollectPolicy, CollectRequest, SimInfo};

use super::backend::{SimBackend, SimError};

/// The most values (`x` and `u` together) one block may hold (64 MiB of `f64`); a larger
/// request is refused with `too_large`.
pub const MAX_BLOCK_VALUES: usize = 1 << 23;

/// About how many values one reply chunk holds (1 MiB of `f64`; at least one window).
pub const CHUNK_VALUES: usize = 1 << 17;

/// A block's windows as a backend returns them: `x` `[windows, steps + 1, nx]` and `u`
/// `[windows, steps, nu]`, row-major.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Windows {
    /// States.
    pub x: Vec<f64>,
    /// Inputs.
    pub u: Vec<f64>,
}

/// How the windows of a checked request choose their inputs.
#[derive(Clone, Debug, PartialEq)]
pub enum PlanInputs {
    /// `u ~ U(low, high)` every step, the bounds resolved to `nu` values each.
    Uniform {
        /// Lower input bounds.
        low: Vec<f64>,
        /// Upper input bounds.
        high: Vec<f64>,
    },
    /// Windows of trajectories the simulator plans itself ([`CollectPolicy::Planned`]): only a
    /// backend with a planner runs them; [`run_windows`] answers `unsupported`.
    Planned {
        /// Windows per plan (≥ 1; `None` = the simulator's default).
        windows_per_plan: Option<u32>,
        /// Exploration amplitude on the planned commands (finite, ≥ 0; `None` = none).
        dither: Option<f64>,
    },
    /// A policy the simulator runs itself with its own settings ([`CollectPolicy::Expert`],
    /// [`CollectPolicy::ExpertNoise`]): passed on as it is; [`run_windows`] answers
    /// `unsupported`.
    Simulator(CollectPolicy),
}

/// A `collect` request checked against the simulator: which windows, how long, the policy
/// (a uniform policy's bounds resolved to `nu` values each).
#[derive(Clone, Debug, PartialEq)]
pub struct CollectPlan {
    /// The collection's seed.
    pub seed: u64,
    /// The block index.
    pub block: u64,
    /// The collection index of the block's first window.
    pub first: u64,
    /// Windows to run.
    pub windows: usize,
    /// Transitions per window.
    pub steps: usize,
    /// How the inputs are chosen.
    pub inputs: PlanInputs,
    nx: usize,
    nu: usize,
}

fn refuse(code: ErrorCode, msg: impl Into<String>) -> ErrorReply {
    ErrorReply::new(code, format!("collect request: {}", msg.into()))
}

impl CollectPlan {
    /// Checks `req` against `info`: `steps`, `block_windows` and `windows` at least 1 and
    /// `windows ≤ block_windows` (`bad_request`), a block no larger than [`MAX_BLOCK_VALUES`]
    /// (`too_large`), bounds of `nu` values (`dimension`), finite with `low ≤ high`
    /// (`bad_request`; absent bounds are the simulator's, which must then be finite); a
    /// planned policy's `windows_per_plan` at least 1 (`bad_request`).
    pub fn new(info: &SimInfo, req: &CollectRequest) -> Result<Self, ErrorReply> {
        let (nx, nu) = (info.nx(), info.nu());
        let windows = req.window_count();
        if req.steps == 0 || req.block_windows == 0 || windows == 0 {
            return Err(refuse(
                ErrorCode::BadRequest,
                "steps, block_windows and windows must be at least 1",
            ));
        }
        if windows > req.block_windows {
            return Err(refuse(
                ErrorCode::BadRequest,
                format!(
                    "windows = {windows} is more than block_windows = {}",
                    req.block_windows
                ),
            ));
        }
        let first = req.first_window().ok_or_else(|| {
            refuse(
                ErrorCode::BadRequest,
                format!(
                    "block {} of {} windows is past the last window index",
                    req.block, req.block_windows
                ),
            )
        })?;
        let (n, t) = (windows as usize, req.steps as usize);
        let per_window = (t + 1) * nx + t * nu;
        if per_window > MAX_VECTOR_LEN || n * per_window > MAX_BLOCK_VALUES {
            return Err(refuse(
                ErrorCode::TooLarge,
                format!(
                    "{n} windows of {t} steps are {} values; a block holds at most {MAX_BLOCK_VALUES} \
                     (ask for smaller blocks)",
                    n * per_window
                ),
            ));
        }
        let (low, high) = match &req.policy {
            CollectPolicy::Uniform { low, high } => (low, high),
            p @ (CollectPolicy::Expert(_) | CollectPolicy::ExpertNoise(_)) => {
                return Ok(CollectPlan {
                    seed: req.seed,
                    block: req.block,
                    first,
                    windows: n,
                    steps: t,
                    inputs: PlanInputs::Simulator(p.clone()),
                    nx,
                    nu,
                });
            }
            CollectPolicy::Planned {
                windows_per_plan,
                dither,
            } => {
                if *windows_per_plan == Some(0) {
                    return Err(refuse(
                        ErrorCode::BadRequest,
                        "planned policy: windows_per_plan must be at least 1",
                    ));
                }
                if let Some(d) = dither.filter(|d| !(d.is_finite() && *d >= 0.0)) {
                    return Err(refuse(
                        ErrorCode::BadRequest,
                        format!("planned policy: dither must be finite and >= 0, got {d}"),
                    ));
                }
                return Ok(CollectPlan {
                    seed: req.seed,
                    block: req.block,
                    first,
                    windows: n,
                    steps: t,
                    inputs: PlanInputs::Planned {
                        windows_per_plan: *windows_per_plan,
                        dither: *dither,
                    },
                    nx,
                    nu,
                });
            }
        };
        let bound = |b: &Option<crate::messages::InputBound>, default: &[f64], what: &str| {
            let v = match b {
                Some(b) => b.resolve(nu).ok_or_else(|| {
                    refuse(
                        ErrorCode::Dimension,
                        format!("uniform policy: `{what}` must have 1 or {nu} values"),
                    )
                })?,
                None => default.to_vec(),
            };
            if !v.iter().all(|x| x.is_finite()) {
                return Err(refuse(
                    ErrorCode::BadRequest,
                    format!(
                        "uniform policy: `{what}` must be finite (the simulator's bounds are used \
                         when it is absent), got {v:?}"
                    ),
                ));
            }
            Ok(v)
        };
        let low = bound(low, &info.u_min, "low")?;
        let high = bound(high, &info.u_max, "high")?;
        if let Some(i) = (0..nu).find(|&i| low[i] > high[i]) {
            return Err(refuse(
                ErrorCode::BadRequest,
                format!(
                    "uniform policy: input {i} has low {} > high {}",
                    low[i], high[i]
                ),
            ));
        }
        Ok(CollectPlan {
            seed: req.seed,
            block: req.block,
            first,
            windows: n,
            steps: t,
            inputs: PlanInputs::Uniform { low, high },
            nx,
            nu,
        })
    }

    /// The policy with its bounds made explicit (what a backend of another language reads).
    pub fn policy(&self) -> CollectPolicy {
        use crate::messages::InputBound::Each;
        match &self.inputs {
            PlanInputs::Uniform { low, high } => CollectPolicy::Uniform {
                low: Some(Each(low.clone())),
                high: Some(Each(high.clone())),
            },
            PlanInputs::Planned {
                windows_per_plan,
                dither,
            } => CollectPolicy::Planned {
                windows_per_plan: *windows_per_plan,
                dither: *dither,
            },
            PlanInputs::Simulator(p) => p.clone(),
        }
    }

    /// Checks what a backend returned: `x` and `u` of the block's sizes, every value finite
    /// (`sim_failure` otherwise).
    pub fn check(&self, w: &Windows) -> Result<(), ErrorReply> {
        let (n, t) = (self.windows, self.steps);
        let (want_x, want_u) = (n * (t + 1) * self.nx, n * t * self.nu);
        if w.x.len() != want_x || w.u.len() != want_u {
            return Err(ErrorReply::new(
                ErrorCode::SimFailure,
                format!(
                    "collect: the simulator returned {} state and {} input values, {n} windows of \
                     {t} steps need {want_x} and {want_u}",
                    w.x.len(),
                    w.u.len()
                ),
            ));
        }
        if !w.x.iter().chain(&w.u).all(|v| v.is_finite()) {
            return Err(ErrorReply::new(
                ErrorCode::SimFailure,
                "collect: the simulator returned a non-finite state or input",
            ));
        }
        Ok(())
    }

    /// The reply chunks of `w` (checked with [`CollectPlan::check`]): consecutive windows,
    /// about [`CHUNK_VALUES`] values each (at least one window). The same block always gives
    /// the same chunks.
    pub fn chunks(&self, w: &Windows) -> Vec<Vec<u8>> {
        let (t, nx, nu) = (self.steps, self.nx, self.nu);
        let per_chunk = (CHUNK_VALUES / ((t + 1) * nx + t * nu)).max(1);
        let count = self.windows.div_ceil(per_chunk);
        (0..count)
            .map(|c| {
                let a = c * per_chunk;
                let b = ((c + 1) * per_chunk).min(self.windows);
                CollectChunk {
                    block: self.block,
                    chunk: c as u32,
                    chunks: count as u32,
                    first: self.first + a as u64,
                    windows: (b - a) as u32,
                    steps: t as u32,
                    nx: nx as u32,
                    nu: nu as u32,
                    x: w.x[a * (t + 1) * nx..b * (t + 1) * nx].to_vec(),
                    u: w.u[a * t * nu..b * t * nu].to_vec(),
                }
                .encode()
            })
            .collect()
    }
}

/// The generator of window `i` of a collection with `seed` (Rust backends): its first draw is
/// the window's reset seed, the next ones its inputs, input by input, step by step. Window `i`
/// depends on nothing else, so any block can be run on its own.
pub fn window_rng(seed: u64, i: u64) -> Rng {
    Rng::derive(seed, i)
}

/// Runs the plan's windows on `backend`, one after the other: window `i` resets with the first
/// draw of [`window_rng`]`(seed, i)` and steps with `u ~ U(low, high)` drawn from it. The
/// default `collect` of every [`SimBackend`]; a planned policy is `unsupported` here (the
/// backend has no planner).
pub fn run_windows<B: SimBackend + ?Sized>(
    backend: &mut B,
    plan: &CollectPlan,
) -> Result<Windows, SimError> {
    let (low, high) = match &plan.inputs {
        PlanInputs::Uniform { low, high } => (low, high),
        PlanInputs::Planned { .. } => {
            return Err(SimError::Unsupported(
                "the planned collect policy needs a simulator that plans its own trajectories \
                 (the Drake Gen3 adapter); this one collects with uniform inputs only"
                    .into(),
            ))
        }
        PlanInputs::Simulator(p) => {
            return Err(SimError::Unsupported(format!(
                "the {} collect policy needs a simulator that runs an expert itself (the Go2 \
                 adapter); this one collects with uniform inputs only",
                p.describe()
            )))
        }
    };
    let (n, t) = (plan.windows, plan.steps);
    let mut w = Windows {
        x: Vec::with_capacity(n * (t + 1) * plan.nx),
        u: Vec::with_capacity(n * t * plan.nu),
    };
    let mut u = vec![0.0; plan.nu];
    for i in 0..n as u64 {
        let mut rng = window_rng(plan.seed, plan.first + i);
        let reset = crate::messages::ResetRequest {
            seed: Some(rng.next_u64()),
            x0: None,
        };
        w.x.extend_from_slice(&backend.reset(&reset)?);
        for _ in 0..t {
            for (v, (lo, hi)) in u.iter_mut().zip(low.iter().zip(high)) {
                *v = rng.uniform(*lo, *hi);
            }
            w.x.extend_from_slice(&backend.step(&u)?);
            w.u.extend_from_slice(&u);
        }
    }
    Ok(w)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::adapter::backend::SystemBackend;
    use crate::messages::InputBound;

    fn request(block: u64, windows: Option<u32>) -> CollectRequest {
        CollectRequest {
            policy: CollectPolicy::default(),
            seed: 7,
            block,
            block_windows: 5,
            windows,
            steps: 4,
        }
    }

    fn pendulum() -> SystemBackend {
        SystemBackend::new(koopman::systems::by_name("damped-pendulum").unwrap())
    }

    #[test]
    fn windows_follow_the_system_and_depend_only_on_their_index() {
        let mut b = pendulum();
        let info = b.info();
        let plan = CollectPlan::new(&info, &request(1, None)).unwrap();
        assert_eq!((plan.first, plan.windows), (5, 5));
        let w = b.collect(&plan).unwrap();
        plan.check(&w).unwrap();
        // Independent computation: the system stepped here from each window's first state.
        let sys = koopman::systems::by_name("damped-pendulum").unwrap();
        let (lo, hi) = sys.input_bounds();
        for i in 0..5 {
            let x = &w.x[i * 10..(i + 1) * 10];
            let u = &w.u[i * 4..(i + 1) * 4];
            let mut r = Rng::derive(7, 5 + i as u64);
            let x0 = sys.sample_initial_state(&mut Rng::new(r.next_u64()));
            assert_eq!(&x[..2], &x0[..]);
            for k in 0..4 {
                assert!(u[k] >= lo[0] && u[k] <= hi[0]);
                let mut next = vec![0.0; 2];
                sys.step(&x[2 * k..2 * k + 2], &u[k..k + 1], &mut next);
                assert_eq!(&x[2 * k + 2..2 * k + 4], &next[..], "window {i} step {k}");
            }
        }
        // A short block of the same collection holds the same first windows.
        let short = CollectPlan::new(&info, &request(1, Some(2))).unwrap();
        let ws = b.collect(&short).unwrap();
        assert_eq!(ws.x, w.x[..20]);
        assert_eq!(ws.u, w.u[..8]);
    }

    #[test]
    fn chunks_cover_the_block_in_order() {
        let mut b = pendulum();
        let info = b.info();
        let req = CollectRequest {
            block_windows: 20_000,
            steps: 15,
            ..request(0, None)
        };
        let plan = CollectPlan::new(&info, &req).unwrap();
        let w = b.collect(&plan).unwrap();
        let chunks: Vec<CollectChunk> = plan
            .chunks(&w)
            .iter()
            .map(|c| CollectChunk::decode(c).unwrap())
            .collect();
        assert!(chunks.len() > 1, "{} chunks", chunks.len());
        let (mut x, mut u, mut next) = (Vec::new(), Vec::new(), 0);
        for (i, c) in chunks.iter().enumerate() {
            assert_eq!((c.chunk as usize, c.chunks as usize), (i, chunks.len()));
            assert_eq!(c.first, next);
            assert!(c.x.len() + c.u.len() <= CHUNK_VALUES);
            next += u64::from(c.windows);
            x.extend_from_slice(&c.x);
            u.extend_from_slice(&c.u);
        }
        assert_eq!((next, x, u), (20_000, w.x, w.u));
    }

    #[test]
    fn bad_requests_are_typed() {
        let info = pendulum().info();
        let code = |r: CollectRequest| CollectPlan::new(&info, &r).unwrap_err().code;
        let r = || request(0, None);
        assert_eq!(
            code(CollectRequest { steps: 0, ..r() }),
            ErrorCode::BadRequest
        );
        assert_eq!(code(request(0, Some(0))), ErrorCode::BadRequest);
        assert_eq!(code(request(0, Some(6))), ErrorCode::BadRequest);
        assert_eq!(code(request(u64::MAX, None)), ErrorCode::BadRequest);
        let huge = CollectRequest {
            block_windows: u32::MAX,
            ..r()
        };
        assert_eq!(code(huge), ErrorCode::TooLarge);
        let policy = |low: InputBound, high: InputBound| CollectRequest {
            policy: CollectPolicy::Uniform {
                low: Some(low),
                high: Some(high),
            },
            ..r()
        };
        use InputBound::{All, Each};
        assert_eq!(
            code(policy(Each(vec![0.0, 1.0]), All(1.0))),
            ErrorCode::Dimension
        );
        assert_eq!(code(policy(All(1.0), All(0.0))), ErrorCode::BadRequest);
        assert_eq!(code(policy(All(f64::NAN), All(0.0))), ErrorCode::BadRequest);
        assert_eq!(
            code(policy(All(0.0), All(f64::INFINITY))),
            ErrorCode::BadRequest
        );
        let ok = CollectPlan::new(&info, &policy(All(-0.5), Each(vec![0.5]))).unwrap();
        assert_eq!(
            ok.inputs,
            PlanInputs::Uniform {
                low: vec![-0.5],
                high: vec![0.5]
            }
        );
        // A simulator without finite bounds needs explicit ones.
        let open = SimInfo {
            u_max: vec![f64::INFINITY],
            ..info.clone()
        };
        assert_eq!(
            CollectPlan::new(&open, &r()).unwrap_err().code,
            ErrorCode::BadRequest
        );
        // A backend that returns too little or a NaN: sim_failure.
        let plan = CollectPlan::new(&info, &r()).unwrap();
        let short = Windows {
            x: vec![0.0; 3],
            u: vec![],
        };
        assert_eq!(plan.check(&short).unwrap_err().code, ErrorCode::SimFailure);
        let mut w = pendulum().collect(&plan).unwrap();
        w.x[3] = f64::NAN;
        assert_eq!(plan.check(&w).unwrap_err().code, ErrorCode::SimFailure);
    }

    #[test]
    fn a_planned_policy_is_checked_and_unsupported_without_a_planner() {
        let mut b = pendulum();
        let info = b.info();
        let planned = |k: Option<u32>| CollectRequest {
            policy: CollectPolicy::Planned {
                windows_per_plan: k,
                dither: None,
            },
            ..request(0, None)
        };
        let zero = CollectPlan::new(&info, &planned(Some(0))).unwrap_err();
        assert_eq!(zero.code, ErrorCode::BadRequest);
        assert!(
            zero.message.contains("windows_per_plan"),
            "{}",
            zero.message
        );
        let dithered = |d: f64| CollectRequest {
            policy: CollectPolicy::Planned {
                windows_per_plan: Some(20),
                dither: Some(d),
            },
            ..request(0, None)
        };
        for bad in [-0.1, f64::NAN, f64::INFINITY] {
            let e = CollectPlan::new(&info, &dithered(bad)).unwrap_err();
            assert_eq!(e.code, ErrorCode::BadRequest);
            assert!(e.message.contains("dither"), "{}", e.message);
        }
        let d = CollectPlan::new(&info, &dithered(0.2)).unwrap();
        assert_eq!(d.policy(), dithered(0.2).policy);
        let plan = CollectPlan::new(&info, &planned(Some(20))).unwrap();
        // What a Python backend is handed: the policy as asked.
        assert_eq!(plan.policy(), planned(Some(20)).policy);
        let err = b.collect(&plan).unwrap_err();
        assert!(matches!(err, SimError::Unsupported(_)), "{err:?}");
        assert_eq!(err.reply().code, ErrorCode::Unsupported);
        // Bounds play no part: a simulator without finite bounds accepts the request too.
        let open = SimInfo {
            u_max: vec![f64::INFINITY],
            ..info
        };
        assert!(CollectPlan::new(&open, &planned(None)).is_ok());
    }
}
