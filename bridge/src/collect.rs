//! Data collection: windows of `T` steps from one or several simulators stepped concurrently
//! in lockstep, or run by the simulators themselves ([`blocks`], the `collect` request), turned
//! into `koopman::data::Dataset`s (bit-for-bit repeatable for a seed).

pub mod blocks;

use koopman::data::{DataRegion, Dataset, DatasetMeta, Pairing};
use koopman::rng::Rng;

use crate::client::{step_all, Liveliness, SimClient};
use crate::error::{Error, ErrorCode, Result};
use crate::messages::{CollectPolicy, InputBound, ResetRequest, SimInfo};
use crate::scenario::Policy;

/// Which split a set of windows is for (keeps the seeds of the three splits independent).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Split {
    /// Training windows.
    Train = 0,
    /// Validation windows.
    Val = 1,
    /// Test windows.
    Test = 2,
}

/// The seed of window `i` of simulator `j` in `split` (reset seed; the input stream uses it too).
pub fn window_seed(seed: u64, split: Split, sim: usize, i: usize) -> u64 {
    let mut r = Rng::derive(
        seed,
        ((split as u64) << 56) ^ ((sim as u64) << 40) ^ i as u64,
    );
    r.next_u64()
}

/// The `collect` seed of simulator `j` for `split` under a scenario's data `seed` (keeps the
/// splits and simulators independent when they run their windows themselves).
pub fn adapter_seed(seed: u64, split: Split, sim: usize) -> u64 {
    let mut r = Rng::derive(
        seed ^ 0xADA9_7E55_C011_EC70,
        ((split as u64) << 56) ^ sim as u64,
    );
    r.next_u64()
}

/// What to collect.
#[derive(Clone, Debug)]
pub struct CollectJob<'a> {
    /// Input policy.
    pub policy: &'a Policy,
    /// Windows per simulator.
    pub windows: usize,
    /// Transitions per window.
    pub steps: usize,
    /// Data seed.
    pub seed: u64,
    /// Which split (keeps the splits' seeds independent).
    pub split: Split,
    /// The box `(low, high)` (`nx` values each) every window's initial state is drawn from,
    /// uniformly and deterministically from the window's seed, and sent as `reset(x0)`;
    /// `None` = the simulator's own seeded reset. With `Policy::Adapter` (uniform inputs) it
    /// travels in the `collect` request and the simulator draws it.
    pub x0_box: Option<&'a (Vec<f64>, Vec<f64>)>,
}

/// The initial state of window `i` of simulator `j` drawn uniformly in `x0_box` (component by
/// component, in order) from the window's seed ([`window_seed`]); independent of the input
/// stream, so a box changes the initial states and nothing else.
pub fn window_x0(ws: u64, x0_box: &(Vec<f64>, Vec<f64>)) -> Vec<f64> {
    let mut r = Rng::new(ws ^ 0x0B0C_5EED_u64);
    x0_box
        .0
        .iter()
        .zip(&x0_box.1)
        .map(|(&lo, &hi)| r.uniform(lo, hi))
        .collect()
}

/// Checks an initial-state box against the simulator `info` describes (its id `sim`): `nx`
/// values each side, finite, `low ≤ high`. `keys` name the scenario keys the two sides came
/// from (`["x0_low", "x0_high"]`, or `x0_center` twice). The error names the key, the simulator
/// and its states.
pub fn check_x0_box(
    x0_box: &(Vec<f64>, Vec<f64>),
    keys: [&str; 2],
    sim: &str,
    info: &SimInfo,
) -> std::result::Result<(), String> {
    let (lo, hi) = x0_box;
    let nx = info.nx();
    if let Some((key, n)) = [(keys[0], lo.len()), (keys[1], hi.len())]
        .into_iter()
        .find(|&(_, n)| n != nx)
    {
        return Err(format!(
            "{key} has {n} values, simulator '{sim}' has {nx} states ({})",
            info.state_names.join(", ")
        ));
    }
    if let Some(i) = (0..nx).find(|&i| !(lo[i].is_finite() && hi[i].is_finite())) {
        return Err(format!(
            "the initial-state box of simulator '{sim}' is not finite at state {i} ({}): [{}, {}]",
            info.state_names.get(i).map_or("?", String::as_str),
            lo[i],
            hi[i]
        ));
    }
    if let Some(i) = (0..nx).find(|&i| lo[i] > hi[i]) {
        return Err(format!(
            "the initial-state box of simulator '{sim}' is empty at state {i} ({}): low {} > high {}",
            info.state_names.get(i).map_or("?", String::as_str),
            lo[i],
            hi[i]
        ));
    }
    Ok(())
}

/// The error of a simulator that cannot reset to a given state, with what to do about it.
fn x0_unsupported(sim: &str, e: Error) -> Error {
    match e {
        Error::Remote { reply, .. } if reply.code == ErrorCode::Unsupported => {
            Error::Config(format!(
                "simulator '{sim}' cannot reset to a given state (reset(x0) answered unsupported: \
                 {}); drop the x0 box (x0_low/x0_high or x0_center/x0_radius) from [collect] and \
                 its [[sims]] entry so that its own seeded reset draws the initial states",
                reply.message
            ))
        }
        e => e,
    }
}

/// One simulator's own data region, over the job's ([`collect_regions`]): a scenario's
/// `[[sims]]` `x0_low`/`x0_high` (or `x0_center`/`x0_radius`) and `u_low`/`u_high`. `None`
/// fields fall back to the job's box and the policy's bounds.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SimRegion {
    /// The initial-state box `(low, high)`, `nx` values each.
    pub x0_box: Option<(Vec<f64>, Vec<f64>)>,
    /// Lower input bounds of the uniform policy.
    pub low: Option<InputBound>,
    /// Upper input bounds of the uniform policy.
    pub high: Option<InputBound>,
    /// Its own inputs for `Policy::Adapter`, in place of the policy's `inputs` (a scenario's
    /// `[[sims]]` `collect_inputs`); the box and bounds above then apply to these.
    pub inputs: Option<CollectPolicy>,
}

impl SimRegion {
    /// Whether it sets no initial-state box and no input bounds (its `inputs` aside).
    pub fn is_empty(&self) -> bool {
        self.x0_box.is_none() && self.low.is_none() && self.high.is_none()
    }
}

/// Collects `job.windows` windows of `job.steps` transitions from every simulator in `sims`
/// concurrently; returns one dataset per simulator. `progress(done, total)` is called after each
/// window (after each block with `Policy::Adapter`, whose windows the simulators run
/// themselves: [`blocks::collect_datasets`] with [`adapter_seed`]).
pub fn collect(
    sims: &mut [SimClient],
    job: &CollectJob<'_>,
    live: Option<&Liveliness>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Vec<Dataset>> {
    collect_regions(sims, job, &[], live, progress)
}

/// [`collect`] with a data region per simulator: `regions[j]` (absent or empty = the job's)
/// overrides the job's initial-state box and the uniform policy's input bounds for `sims[j]`,
/// and with `Policy::Adapter` its `inputs` replace the policy's for `sims[j]`. With
/// `Policy::Adapter` the box and bounds travel in the `collect` request's uniform policy
/// (PROTOCOL.md, "Collect"); a planned or expert policy takes neither (`Error::Config`). Every
/// dataset with a box or bounds records them in its metadata (`region`).
pub fn collect_regions(
    sims: &mut [SimClient],
    job: &CollectJob<'_>,
    regions: &[SimRegion],
    live: Option<&Liveliness>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Vec<Dataset>> {
    let CollectJob {
        policy,
        windows,
        steps,
        seed,
        split,
        x0_box,
    } = *job;
    let none = SimRegion::default();
    let region = |j: usize| regions.get(j).unwrap_or(&none);
    let box_of = |j: usize| region(j).x0_box.as_ref().or(x0_box);
    if let Policy::Adapter { inputs, block } = policy {
        let mut policies = Vec::with_capacity(sims.len());
        let mut boxes = Vec::with_capacity(sims.len());
        for (j, s) in sims.iter().enumerate() {
            let (r, xb) = (region(j), box_of(j));
            let p = match r.inputs.as_ref().unwrap_or(inputs) {
                CollectPolicy::Uniform {
                    low,
                    high,
                    x0_low,
                    x0_high,
                } => {
                    let (low, high) = (
                        r.low.clone().or(low.clone()),
                        r.high.clone().or(high.clone()),
                    );
                    let xb = xb.cloned().or(match (x0_low, x0_high) {
                        (Some(l), Some(h)) => Some((l.clone(), h.clone())),
                        _ => None,
                    });
                    let info = &s.info.sim;
                    let b = uniform_bounds(&low, &high, info)
                        .map_err(|m| Error::Config(format!("simulator '{}': {m}", s.id)))?;
                    if let Some(xb) = &xb {
                        check_x0_box(xb, ["x0_low", "x0_high"], &s.id, info)
                            .map_err(Error::Config)?;
                    }
                    let explicit = xb.is_some() || low.is_some() || high.is_some();
                    boxes.push(explicit.then(|| DataRegion {
                        x0_low: xb.as_ref().map(|b| b.0.clone()),
                        x0_high: xb.as_ref().map(|b| b.1.clone()),
                        u_low: Some(b.0.clone()),
                        u_high: Some(b.1.clone()),
                    }));
                    CollectPolicy::Uniform {
                        low,
                        high,
                        x0_low: xb.as_ref().map(|b| b.0.clone()),
                        x0_high: xb.as_ref().map(|b| b.1.clone()),
                    }
                }
                p => {
                    if xb.is_some() || r.low.is_some() || r.high.is_some() {
                        return Err(Error::Config(format!(
                            "simulator '{}': an initial-state box or input bounds need uniform \
                             inputs; the {} policy draws its own windows",
                            s.id,
                            p.describe()
                        )));
                    }
                    boxes.push(None);
                    p.clone()
                }
            };
            policies.push(p);
        }
        let seeds: Vec<u64> = (0..sims.len())
            .map(|j| adapter_seed(seed, split, j))
            .collect();
        let mut out = blocks::collect_datasets(
            sims, &policies, &seeds, windows, steps, *block, live, progress,
        )?;
        for (ds, b) in out.iter_mut().zip(boxes) {
            if b.is_some() {
                ds.meta.region = b;
            }
        }
        return Ok(out);
    }
    let mut out: Vec<Dataset> = Vec::with_capacity(sims.len());
    // Per simulator, the uniform policy's bounds (`nu` values each).
    let mut bounds: Vec<(Vec<f64>, Vec<f64>)> = Vec::with_capacity(sims.len());
    for (j, s) in sims.iter().enumerate() {
        let info = &s.info.sim;
        let r = region(j);
        if let Some(p) = &r.inputs {
            return Err(Error::Config(format!(
                "simulator '{}': its own collect inputs ({}) replace an adapter policy's; the \
                 lockstep {} policy chooses the inputs here",
                s.id,
                p.describe(),
                if matches!(policy, Policy::Scripted { .. }) {
                    "scripted"
                } else {
                    "uniform"
                }
            )));
        }
        if let Policy::Scripted { inputs } = policy {
            if r.low.is_some() || r.high.is_some() {
                return Err(Error::Config(format!(
                    "simulator '{}': input bounds (u_low/u_high) need a uniform policy, not a \
                     scripted one",
                    s.id
                )));
            }
            if let Some(bad) = inputs.iter().find(|u| u.len() != info.nu()) {
                return Err(Error::Config(format!(
                    "scripted input {bad:?} has {} values, simulator '{}' has {} inputs",
                    bad.len(),
                    s.id,
                    info.nu()
                )));
            }
        }
        let b = match policy {
            Policy::Uniform { low, high } => uniform_bounds(
                &r.low.clone().or(low.clone()),
                &r.high.clone().or(high.clone()),
                info,
            )
            .map_err(|m| Error::Config(format!("simulator '{}': {m}", s.id)))?,
            _ => (Vec::new(), Vec::new()),
        };
        let kind = match policy {
            Policy::Uniform { .. } => format!("uniform low={:?} high={:?}", b.0, b.1),
            Policy::Scripted { .. } => "scripted".into(),
            Policy::Adapter { .. } => "adapter".into(),
        };
        let source = format!("zenoh:sim/{}", s.id);
        let mut ds = empty_dataset(info, windows, steps, seed, source, &kind);
        let uniform = matches!(policy, Policy::Uniform { .. });
        if let Some(xb) = box_of(j) {
            check_x0_box(xb, ["x0_low", "x0_high"], &s.id, info).map_err(Error::Config)?;
        }
        if box_of(j).is_some() || (uniform && !r.is_empty()) {
            ds.meta.region = Some(DataRegion {
                x0_low: box_of(j).map(|b| b.0.clone()),
                x0_high: box_of(j).map(|b| b.1.clone()),
                u_low: uniform.then(|| b.0.clone()),
                u_high: uniform.then(|| b.1.clone()),
            });
        }
        out.push(ds);
        bounds.push(b);
    }
    // Per simulator, the windows it flagged (terminated, truncated, clipped), counted once each.
    let mut flagged = vec![koopman::data::WindowFlags::default(); sims.len()];
    for i in 0..windows {
        let mut window_status = vec![crate::codec::StepStatus::EMPTY; sims.len()];
        let mut rngs = Vec::with_capacity(sims.len());
        for (j, s) in sims.iter_mut().enumerate() {
            let ws = window_seed(seed, split, j, i);
            let first = match box_of(j) {
                Some(xb) => s
                    .reset_watched(
                        &ResetRequest {
                            seed: None,
                            x0: Some(window_x0(ws, xb)),
                            perturbation: None,
                        },
                        live,
                    )
                    .map_err(|e| x0_unsupported(&s.id, e))?,
                None => s.reset_watched(
                    &ResetRequest {
                        seed: Some(ws),
                        x0: None,
                        perturbation: None,
                    },
                    live,
                )?,
            };
            out[j].x.extend_from_slice(&first.x);
            rngs.push(Rng::new(ws ^ 0x5EED_u64));
        }
        for t in 0..steps {
            let inputs: Vec<Vec<f64>> = bounds
                .iter()
                .zip(rngs.iter_mut())
                .map(|((lo, hi), r)| match policy {
                    Policy::Uniform { .. } => lo
                        .iter()
                        .zip(hi)
                        .map(|(&lo, &hi)| r.uniform(lo, hi))
                        .collect(),
                    Policy::Scripted { inputs } => inputs[(i * steps + t) % inputs.len()].clone(),
                    Policy::Adapter { .. } => unreachable!("collected by the simulators above"),
                })
                .collect();
            let replies = step_all(sims, &inputs, live)?;
            for (j, (r, u)) in replies.iter().zip(&inputs).enumerate() {
                out[j].x.extend_from_slice(&r.x);
                out[j].u.extend_from_slice(u);
                window_status[j] = window_status[j].union(r.status);
            }
        }
        for (f, st) in flagged.iter_mut().zip(&window_status) {
            f.terminated += usize::from(st.terminated());
            f.truncated += usize::from(st.truncated());
            f.clipped += usize::from(st.clipped());
        }
        progress(i + 1, windows);
    }
    for (d, f) in out.iter_mut().zip(flagged) {
        d.meta.window_flags = Some(f);
    }
    Ok(out)
}

/// The bounds (`nu` values each) of the lockstep uniform policy on the simulator `info`
/// describes: `low`/`high` as given (one value for every input, or `nu`), else the simulator's
/// `u_min`/`u_max`. The error says what does not fit: a length other than 1 or `nu`, a
/// non-finite bound (an unbounded simulator needs `low` and `high`), `low > high`, or a bound
/// outside the simulator's (it cannot take more).
pub fn uniform_bounds(
    low: &Option<InputBound>,
    high: &Option<InputBound>,
    info: &SimInfo,
) -> std::result::Result<(Vec<f64>, Vec<f64>), String> {
    let nu = info.nu();
    let resolve = |b: &Option<InputBound>, default: &[f64], what: &str| match b {
        Some(b) => b.resolve(nu).ok_or_else(|| {
            format!("collect.policy: `{what}` must have 1 or {nu} values (one per input)")
        }),
        None => Ok(default.to_vec()),
    };
    let lo = resolve(low, &info.u_min, "low")?;
    let hi = resolve(high, &info.u_max, "high")?;
    for i in 0..nu {
        let name = info.input_names.get(i).map_or("?", String::as_str);
        let (l, h) = (lo[i], hi[i]);
        if !(l.is_finite() && h.is_finite()) {
            return Err(format!(
                "collect.policy: input {i} ({name}) has no finite bounds [{l}, {h}]; set `low` and \
                 `high` in the uniform policy"
            ));
        }
        if l > h {
            return Err(format!(
                "collect.policy: input {i} ({name}) has low {l} > high {h}"
            ));
        }
        if l < info.u_min[i] || h > info.u_max[i] {
            return Err(format!(
                "collect.policy: input {i} ({name}) bounds [{l}, {h}] exceed the simulator's \
                 [{}, {}]",
                info.u_min[i], info.u_max[i]
            ));
        }
    }
    Ok((lo, hi))
}

/// An empty aligned dataset for `windows` windows of `steps` transitions of the simulator `info`
/// describes, with room for them reserved, and its metadata.
pub(crate) fn empty_dataset(
    info: &crate::messages::SimInfo,
    windows: usize,
    steps: usize,
    seed: u64,
    source: String,
    policy: &str,
) -> Dataset {
    Dataset {
        n: windows,
        steps,
        nx: info.nx(),
        nu: info.nu(),
        x: Vec::with_capacity(windows * (steps + 1) * info.nx()),
        u: Vec::with_capacity(windows * steps * info.nu()),
        meta: DatasetMeta {
            env: info.env.clone(),
            dt: info.dt,
            state_names: info.state_names.clone(),
            input_names: info.input_names.clone(),
            pairing: Pairing::Aligned,
            seed,
            source,
            policy: policy.into(),
            region: None,
            window_flags: None,
        },
    }
}
