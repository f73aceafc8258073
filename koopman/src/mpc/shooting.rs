//! Random-shooting MPC for one-step models `x⁺ = f(x, u)` (the NNDM baseline of the paper):
//! sample input sequences uniformly within the bounds, roll out, apply the best first input.

use rayon::prelude::*;

use crate::error::{ensure_finite, Error, Result};
use crate::rng::Rng;
use crate::systems::System;

/// A model that predicts the next state from the state and the input.
pub trait OneStepModel: Send + Sync {
    /// State dimension.
    fn nx(&self) -> usize;
    /// Input dimension.
    fn nu(&self) -> usize;
    /// Writes `x⁺ = f(x, u)` into `next`.
    fn predict(&self, x: &[f64], u: &[f64], next: &mut [f64]);

    /// Predicts `rows` transitions at once: `xs` (rows × nx), `us` (rows × nu) and `next`
    /// (rows × nx) are row-major. The default calls [`OneStepModel::predict`] row by row;
    /// models with a batched forward pass (the NNDM: one GEMM per layer) override it.
    fn predict_rows(&self, xs: &[f64], us: &[f64], next: &mut [f64]) {
        let (nx, nu) = (self.nx(), self.nu());
        for (i, out) in next.chunks_exact_mut(nx).enumerate() {
            self.predict(&xs[i * nx..(i + 1) * nx], &us[i * nu..(i + 1) * nu], out);
        }
    }
}

/// Rollouts per batched prediction in [`RandomShooting::plan`] (and per parallel task).
const ROLLOUT_CHUNK: usize = 128;

/// The true system used as its own one-step model (an oracle upper bound for the baseline).
pub struct SystemAsModel<'s>(pub &'s dyn System);

impl OneStepModel for SystemAsModel<'_> {
    fn nx(&self) -> usize {
        self.0.nx()
    }
    fn nu(&self) -> usize {
        self.0.nu()
    }
    fn predict(&self, x: &[f64], u: &[f64], next: &mut [f64]) {
        self.0.step(x, u, next);
    }
}

/// How far about a feed-forward [`RandomShooting::plan_sequence_about`] samples: each input
/// within ± this fraction of its half-range, `(u_max − u_min)/2`, of the feed-forward.
pub const ABOUT_PLAN_SPREAD: f64 = 0.1;

/// Random-shooting MPC: `samples` sequences of `horizon` inputs, cost
/// `Σ (x_τ − r_τ)ᵀQ(x_τ − r_τ) + Σ (u_τ − u_ff,τ)ᵀR(u_τ − u_ff,τ)` (`u_ff = 0` without a plan;
/// the paper's NNDM baseline has R = 0).
pub struct RandomShooting {
    /// Number of sampled sequences (1000 in the paper).
    pub samples: usize,
    /// Horizon H.
    pub horizon: usize,
    /// Diagonal state weight (nx).
    pub q: Vec<f64>,
    /// Diagonal input weight (nu; zeros: the paper's cost on the states only).
    pub r: Vec<f64>,
    /// Input bounds (nu each).
    pub u_min: Vec<f64>,
    /// Upper input bounds.
    pub u_max: Vec<f64>,
    rng: Rng,
}

impl RandomShooting {
    /// A planner with the given sampling budget, horizon, weights and bounds.
    pub fn new(
        samples: usize,
        horizon: usize,
        q: Vec<f64>,
        u_min: Vec<f64>,
        u_max: Vec<f64>,
        seed: u64,
    ) -> Result<Self> {
        if samples == 0 || horizon == 0 {
            return Err(Error::InvalidArgument(
                "random shooting needs samples ≥ 1 and horizon ≥ 1".into(),
            ));
        }
        if u_min.len() != u_max.len() {
            return Err(Error::dimension("input bounds", u_min.len(), u_max.len()));
        }
        if u_min.iter().chain(&u_max).any(|v| !v.is_finite())
            || u_min.iter().zip(&u_max).any(|(l, h)| l > h)
        {
            return Err(Error::InvalidArgument(
                "random shooting needs finite, non-empty input bounds".into(),
            ));
        }
        Ok(RandomShooting {
            samples,
            horizon,
            q,
            r: vec![0.0; u_min.len()],
            u_min,
            u_max,
            rng: Rng::new(seed),
        })
    }

    /// The same planner with input weight `r` (nu finite values ≥ 0).
    pub fn with_input_weight(mut self, r: Vec<f64>) -> Result<Self> {
        if r.len() != self.u_min.len() {
            return Err(Error::dimension(
                "input weight r",
                self.u_min.len(),
                r.len(),
            ));
        }
        if r.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
            return Err(Error::InvalidArgument(format!(
                "random shooting: the input weight r needs finite values ≥ 0, got {r:?}"
            )));
        }
        self.r = r;
        Ok(self)
    }

    /// The best first input for state `x` and stacked reference `r` (horizon·nx values).
    /// Returns the input and the best sequence's cost.
    pub fn plan(
        &mut self,
        model: &dyn OneStepModel,
        x: &[f64],
        r: &[f64],
    ) -> Result<(Vec<f64>, f64)> {
        let nu = model.nu();
        let (mut seq, cost) = self.plan_sequence(model, x, r)?;
        seq.truncate(nu);
        Ok((seq, cost))
    }

    /// Like [`RandomShooting::plan`], but returns the whole best sequence (horizon·nu values,
    /// step-major) and its cost.
    pub fn plan_sequence(
        &mut self,
        model: &dyn OneStepModel,
        x: &[f64],
        r: &[f64],
    ) -> Result<(Vec<f64>, f64)> {
        self.check(model, x, r)?;
        let nu = model.nu();
        // Draw every sequence first (deterministic), then roll out in parallel.
        let seqs: Vec<Vec<f64>> = (0..self.samples)
            .map(|_| {
                (0..self.horizon * nu)
                    .map(|k| self.rng.uniform(self.u_min[k % nu], self.u_max[k % nu]))
                    .collect()
            })
            .collect();
        self.best(model, x, r, seqs, None)
    }

    /// Random shooting about a plan: the sequences are the feed-forward `ff` (horizon·nu values,
    /// step-major) itself and `samples − 1` draws of `ff` + δ, one δ ~ U(± [`ABOUT_PLAN_SPREAD`]
    /// of each input's half-range) held over the horizon (a correction held, not noise drawn
    /// afresh at every step, which averages out over the horizon and corrects nothing), clipped
    /// to the bounds; the cost weighs `u − ff` by R. Returns the best sequence and its cost:
    /// never worse, by the model, than the feed-forward.
    pub fn plan_sequence_about(
        &mut self,
        model: &dyn OneStepModel,
        x: &[f64],
        r: &[f64],
        ff: &[f64],
    ) -> Result<(Vec<f64>, f64)> {
        self.check(model, x, r)?;
        let nu = model.nu();
        if ff.len() != self.horizon * nu {
            return Err(Error::dimension(
                "feed-forward",
                self.horizon * nu,
                ff.len(),
            ));
        }
        ensure_finite("feed-forward", ff)?;
        let clip = |k: usize, v: f64| v.clamp(self.u_min[k % nu], self.u_max[k % nu]);
        let ff: Vec<f64> = ff.iter().enumerate().map(|(k, &v)| clip(k, v)).collect();
        let half: Vec<f64> = (0..nu)
            .map(|i| ABOUT_PLAN_SPREAD * (self.u_max[i] - self.u_min[i]) / 2.0)
            .collect();
        let mut seqs = vec![ff.clone()];
        for _ in 1..self.samples {
            let delta: Vec<f64> = half.iter().map(|&w| self.rng.uniform(-w, w)).collect();
            let seq = (0..self.horizon * nu)
                .map(|k| clip(k, ff[k] + delta[k % nu]))
                .collect();
            seqs.push(seq);
        }
        self.best(model, x, r, seqs, Some(&ff))
    }

    /// Checks the sizes of a solve's state and stacked reference, and the state's values.
    fn check(&self, model: &dyn OneStepModel, x: &[f64], r: &[f64]) -> Result<()> {
        let (nx, nu) = (model.nx(), model.nu());
        if x.len() != nx {
            return Err(Error::dimension("state", nx, x.len()));
        }
        if r.len() != self.horizon * nx {
            return Err(Error::dimension(
                "stacked reference",
                self.horizon * nx,
                r.len(),
            ));
        }
        if self.q.len() != nx || self.u_min.len() != nu {
            return Err(Error::dimension(
                "shooting weights/bounds",
                nx,
                self.q.len(),
            ));
        }
        ensure_finite("state", x)
    }

    /// The sequence of `seqs` with the least cost from `x` against the stacked `r` (inputs
    /// weighed about `ff`, or about zero), and that cost.
    fn best(
        &self,
        model: &dyn OneStepModel,
        x: &[f64],
        r: &[f64],
        seqs: Vec<Vec<f64>>,
        ff: Option<&[f64]>,
    ) -> Result<(Vec<f64>, f64)> {
        let (nx, nu) = (model.nx(), model.nu());
        let (horizon, q, rw) = (self.horizon, &self.q, &self.r);
        let weighs_inputs = rw.iter().any(|&w| w != 0.0);
        let input_cost = |seq: &[f64]| -> f64 {
            if !weighs_inputs {
                return 0.0;
            }
            seq.iter()
                .enumerate()
                .map(|(k, &u)| rw[k % nu] * (u - ff.map_or(0.0, |f| f[k])).powi(2))
                .sum()
        };
        // Roll out chunks of sequences in parallel, each chunk one batched prediction per step.
        let costs: Vec<f64> = seqs
            .par_chunks(ROLLOUT_CHUNK)
            .flat_map_iter(|chunk| {
                let rows = chunk.len();
                let mut cur: Vec<f64> = x.repeat(rows);
                let mut next = vec![0.0; rows * nx];
                let mut inputs = vec![0.0; rows * nu];
                let mut cost: Vec<f64> = chunk.iter().map(|seq| input_cost(seq)).collect();
                for t in 0..horizon {
                    for (dst, seq) in inputs.chunks_exact_mut(nu.max(1)).zip(chunk) {
                        dst.copy_from_slice(&seq[t * nu..(t + 1) * nu]);
                    }
                    model.predict_rows(&cur, &inputs, &mut next);
                    for (c, xn) in cost.iter_mut().zip(next.chunks_exact(nx)) {
                        for i in 0..nx {
                            *c += q[i] * (xn[i] - r[t * nx + i]).powi(2);
                        }
                    }
                    std::mem::swap(&mut cur, &mut next);
                }
                cost.into_iter()
                    .map(|c| if c.is_nan() { f64::INFINITY } else { c })
            })
            .collect();
        let (i_best, &c_best) = costs
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.total_cmp(b.1))
            .expect("samples ≥ 1");
        if !c_best.is_finite() {
            return Err(Error::Numerical(
                "random shooting: every rollout diverged".into(),
            ));
        }
        let mut seqs = seqs;
        Ok((seqs.swap_remove(i_best), c_best))
    }
}
