//! What an adapter serves: the [`SimBackend`] trait (plain synchronous calls), its error type,
//! the in-process `collect` every backend has by default ([`run_windows`]) and [`SystemBackend`]
//! for the built-in reference systems.

use koopman::rng::Rng;

use crate::codec::StepStatus;
use crate::error::{ErrorCode, ErrorReply};
use crate::messages::{ResetRequest, SimInfo};

use super::collect::{CollectPlan, PlanInputs, Windows};

/// A simulator as the adapter sees it: plain synchronous calls, one at a time, on one thread.
pub trait SimBackend {
    /// What the simulator is (called once when serving starts).
    fn info(&self) -> SimInfo;
    /// Resets and returns the first state `x_0` (`nx` values).
    fn reset(&mut self, req: &ResetRequest) -> std::result::Result<Vec<f64>, SimError>;
    /// Applies `u` (`nu` values, held over one `dt`) and returns the next state.
    fn step(&mut self, u: &[f64]) -> std::result::Result<Vec<f64>, SimError>;
    /// [`Self::step`] and what the simulator says about that step (an episode end, a clipped
    /// input), sent in the lockstep step reply (PROTOCOL.md §4, `0x09`). Default: `step` with
    /// an empty status; a backend with something to report overrides it.
    fn step_reporting(
        &mut self,
        u: &[f64],
    ) -> std::result::Result<(Vec<f64>, StepStatus), SimError> {
        Ok((self.step(u)?, StepStatus::EMPTY))
    }
    /// Runs the windows of a checked `collect` request in-process and returns them (the
    /// adapter checks their sizes and values). Default: [`run_windows`], reset and step one
    /// window after the other; a backend with a faster path (or its own generator, as the
    /// Python simulators have) overrides it. The simulator's state afterwards is arbitrary.
    fn collect(&mut self, plan: &CollectPlan) -> std::result::Result<Windows, SimError> {
        run_windows(self, plan)
    }
}

/// A failure reported by a backend.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SimError {
    /// The request was wrong (bad initial state, input out of range the simulator refuses, ...).
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// The request is not supported by this simulator (e.g. an explicit `x0`).
    #[error("unsupported: {0}")]
    Unsupported(String),
    /// The simulator failed (diverged, crashed, ...).
    #[error("simulator failure: {0}")]
    Failed(String),
}

impl SimError {
    /// The error reply sent for this failure (`bad_request`, `unsupported`, `sim_failure`).
    pub fn reply(&self) -> ErrorReply {
        let code = match self {
            SimError::InvalidInput(_) => ErrorCode::BadRequest,
            SimError::Unsupported(_) => ErrorCode::Unsupported,
            SimError::Failed(_) => ErrorCode::SimFailure,
        };
        ErrorReply::new(code, self.to_string())
    }
}

/// The generator of window `i` of a collection with `seed` (Rust backends): its first draw is
/// the window's reset seed, the next ones its inputs, input by input, step by step. Window `i`
/// depends on nothing else, so any block can be run on its own.
pub fn window_rng(seed: u64, i: u64) -> Rng {
    Rng::derive(seed, i)
}

/// Runs the plan's windows on `backend`, one after the other: window `i` resets with the first
/// draw of [`window_rng`]`(seed, i)` (or, with an initial-state box, to `x0 ~ U(x0_low,
/// x0_high)` drawn next from it) and steps with `u ~ U(low, high)` drawn from it. The
/// default `collect` of every [`SimBackend`]; a planned policy is `unsupported` here (the
/// backend has no planner).
pub fn run_windows<B: SimBackend + ?Sized>(
    backend: &mut B,
    plan: &CollectPlan,
) -> Result<Windows, SimError> {
    let (low, high, x0_box) = match &plan.inputs {
        PlanInputs::Uniform { low, high, x0 } => (low, high, x0),
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
        let seed = rng.next_u64();
        // With a box: x0 drawn from the window's stream after its reset seed, component by
        // component, then the inputs.
        let reset = match x0_box {
            Some((lo, hi)) => ResetRequest {
                seed: None,
                x0: Some(
                    lo.iter()
                        .zip(hi)
                        .map(|(l, h)| rng.uniform(*l, *h))
                        .collect(),
                ),
                perturbation: None,
            },
            None => ResetRequest {
                seed: Some(seed),
                x0: None,
                perturbation: None,
            },
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

/// A [`SimBackend`] for any built-in reference system of `koopman::systems`.
pub struct SystemBackend {
    system: Box<dyn koopman::systems::System>,
    x: Vec<f64>,
}

impl SystemBackend {
    /// Wraps a system.
    pub fn new(system: Box<dyn koopman::systems::System>) -> Self {
        let nx = system.nx();
        SystemBackend {
            system,
            x: vec![0.0; nx],
        }
    }
}

impl SimBackend for SystemBackend {
    fn info(&self) -> SimInfo {
        SimInfo::from_system(self.system.as_ref())
    }

    fn reset(&mut self, req: &ResetRequest) -> std::result::Result<Vec<f64>, SimError> {
        if req.perturbation.is_some() {
            return Err(SimError::Unsupported(format!(
                "the built-in system '{}' takes no perturbation (the legged adapters do)",
                self.system.name()
            )));
        }
        self.x = match (&req.x0, req.seed) {
            (Some(x0), _) => x0.clone(),
            (None, seed) => {
                let mut rng = koopman::rng::Rng::new(seed.unwrap_or(0));
                self.system.sample_initial_state(&mut rng)
            }
        };
        Ok(self.x.clone())
    }

    fn step(&mut self, u: &[f64]) -> std::result::Result<Vec<f64>, SimError> {
        let mut next = vec![0.0; self.x.len()];
        self.system.step(&self.x, u, &mut next);
        if !next.iter().all(|v| v.is_finite()) {
            return Err(SimError::Failed("the state became non-finite".into()));
        }
        self.x = next;
        Ok(self.x.clone())
    }
}
