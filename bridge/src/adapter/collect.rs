//! The simulator side of `collect` that needs no simulator: a request checked against the
//! simulator's info ([`CollectPlan`]), what a backend returns for it checked, and the result cut
//! into reply chunks (the windows themselves are run by [`SimBackend::collect`], by default
//! [`run_windows`]).
//!
//! [`SimBackend::collect`]: super::SimBackend::collect
//! [`run_windows`]: super::run_windows

use crate::codec::{CollectChunk, MAX_VECTOR_LEN};
use crate::error::{ErrorCode, ErrorReply};
use crate::messages::{CollectPolicy, CollectRequest, SimInfo};

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
        /// The box `(low, high)` (`nx` values each) every window's initial state is drawn
        /// from (`reset(x0)`); `None` = a seeded reset.
        x0: Option<(Vec<f64>, Vec<f64>)>,
    },
    /// Windows of trajectories the simulator plans itself ([`CollectPolicy::Planned`]): only a
    /// backend with a planner runs them; [`run_windows`](super::run_windows) answers
    /// `unsupported`.
    Planned {
        /// Windows per plan (≥ 1; `None` = the simulator's default).
        windows_per_plan: Option<u32>,
        /// Exploration amplitude on the planned commands (finite, ≥ 0; `None` = none).
        dither: Option<f64>,
    },
    /// A policy the simulator runs itself with its own settings ([`CollectPolicy::Expert`],
    /// [`CollectPolicy::ExpertNoise`]): passed on as it is; [`run_windows`](super::run_windows)
    /// answers `unsupported`.
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
    pub(super) nx: usize,
    pub(super) nu: usize,
}

fn refuse(code: ErrorCode, msg: impl Into<String>) -> ErrorReply {
    ErrorReply::new(code, format!("collect request: {}", msg.into()))
}

/// The initial-state box of a uniform policy checked: `nx` values each side (`dimension`),
/// finite, `low ≤ high` (`bad_request`).
fn x0_box(lo: &[f64], hi: &[f64], nx: usize) -> Result<(Vec<f64>, Vec<f64>), ErrorReply> {
    if lo.len() != nx || hi.len() != nx {
        return Err(refuse(
            ErrorCode::Dimension,
            format!(
                "uniform policy: x0_low and x0_high must have {nx} values (one per state), got {} and {}",
                lo.len(),
                hi.len()
            ),
        ));
    }
    if let Some(i) = (0..nx).find(|&i| !(lo[i].is_finite() && hi[i].is_finite() && lo[i] <= hi[i]))
    {
        return Err(refuse(
            ErrorCode::BadRequest,
            format!(
                "uniform policy: the initial-state box at state {i} is [{}, {}] (must be finite with x0_low <= x0_high)",
                lo[i], hi[i]
            ),
        ));
    }
    Ok((lo.to_vec(), hi.to_vec()))
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
        let (low, high, x0_low, x0_high) = match &req.policy {
            CollectPolicy::Uniform {
                low,
                high,
                x0_low,
                x0_high,
            } => (low, high, x0_low, x0_high),
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
        let x0 = match (x0_low, x0_high) {
            (None, None) => None,
            (Some(lo), Some(hi)) => Some(x0_box(lo, hi, nx)?),
            _ => {
                return Err(refuse(
                    ErrorCode::BadRequest,
                    "uniform policy: x0_low and x0_high go together (the initial-state box's two corners)",
                ))
            }
        };
        Ok(CollectPlan {
            seed: req.seed,
            block: req.block,
            first,
            windows: n,
            steps: t,
            inputs: PlanInputs::Uniform { low, high, x0 },
            nx,
            nu,
        })
    }

    /// The policy with its bounds made explicit (what a backend of another language reads).
    pub fn policy(&self) -> CollectPolicy {
        use crate::messages::InputBound::Each;
        match &self.inputs {
            PlanInputs::Uniform { low, high, x0 } => CollectPolicy::Uniform {
                low: Some(Each(low.clone())),
                high: Some(Each(high.clone())),
                x0_low: x0.as_ref().map(|b| b.0.clone()),
                x0_high: x0.as_ref().map(|b| b.1.clone()),
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
