//! The client side of `collect`: block `b` of a collection of windows that a simulator runs in
//! its own process ([`collect_block`]; deterministic by seed, so a collection resumes at any
//! block), whole collections block by block ([`collect_blocks`]) and the datasets of several
//! simulators collected at once ([`collect_datasets`]).

use std::sync::mpsc;
use std::time::Duration;

use koopman::data::Dataset;

use crate::client::{Client, Liveliness, PendingQuery, SimClient};
use crate::codec::CollectChunk;
use crate::error::{Error, ErrorCode, Result};
use crate::keyexpr::{Role, SimLeaf};
use crate::messages::{CollectPolicy, CollectRequest};

/// How long one block may take by default (a block runs on the simulator before any reply).
pub const BLOCK_TIMEOUT: Duration = Duration::from_secs(600);

/// One block's windows as received: `x` `[windows, steps + 1, nx]`, `u` `[windows, steps, nu]`.
#[derive(Clone, Debug, PartialEq)]
pub struct Block {
    /// The block index.
    pub block: u64,
    /// The collection index of its first window.
    pub first: u64,
    /// Windows.
    pub windows: usize,
    /// Transitions per window.
    pub steps: usize,
    /// State dimension.
    pub nx: usize,
    /// Input dimension.
    pub nu: usize,
    /// States.
    pub x: Vec<f64>,
    /// Inputs.
    pub u: Vec<f64>,
}

fn mismatch(who: &str, msg: String) -> Error {
    Error::protocol(
        ErrorCode::BadRequest,
        format!("{who}: collect reply: {msg}"),
    )
}

/// Sends the `collect` query of `req` to simulator `sim` without waiting.
pub fn start_block(
    client: &Client,
    sim: &str,
    req: &CollectRequest,
    timeout: Duration,
) -> Result<PendingQuery> {
    let key = client.keys.sim(sim, SimLeaf::Collect)?;
    let body = serde_json::to_vec(req).map_err(|e| Error::Config(e.to_string()))?;
    client.start(&key, body, timeout, &format!("simulator '{sim}'"))
}

/// Waits for the chunks of a block started with [`start_block`] and puts them together,
/// checking that they are exactly the requested windows (no chunk missing or twice, every one
/// of the same shape). With `live`, a simulator that loses its liveliness token ends the wait.
pub fn finish_block(
    pending: PendingQuery,
    sim: &str,
    req: &CollectRequest,
    live: Option<&Liveliness>,
) -> Result<Block> {
    let who = format!("simulator '{sim}'");
    let mut parts: Vec<Option<CollectChunk>> = Vec::new();
    let mut left = usize::MAX;
    pending.wait_many(live.map(|l| (l, Role::Sim, sim)), |bytes| {
        let c = CollectChunk::decode(&bytes)?;
        if c.block != req.block || c.steps != req.steps {
            return Err(mismatch(
                &who,
                format!(
                    "chunk of block {} with {} steps for block {} of {} steps",
                    c.block, c.steps, req.block, req.steps
                ),
            ));
        }
        if parts.is_empty() {
            // Every chunk holds at least one window: more chunks than windows is a lie.
            if c.chunks > req.window_count() {
                return Err(mismatch(
                    &who,
                    format!("{} chunks for {} windows", c.chunks, req.window_count()),
                ));
            }
            parts.resize(c.chunks as usize, None);
            left = parts.len();
        }
        let count = parts.len();
        match parts.get_mut(c.chunk as usize) {
            Some(slot @ None) if c.chunks as usize == count => {
                *slot = Some(c);
                left -= 1;
                Ok(left == 0)
            }
            _ => Err(mismatch(
                &who,
                format!(
                    "chunk {} of {} (again, or another count than {})",
                    c.chunk, c.chunks, count
                ),
            )),
        }
    })?;
    let chunks: Vec<CollectChunk> = parts.into_iter().flatten().collect();
    let (nx, nu) = (chunks[0].nx as usize, chunks[0].nu as usize);
    let first = req
        .first_window()
        .ok_or_else(|| Error::Config("collect request: block index overflows".into()))?;
    let mut out = Block {
        block: req.block,
        first,
        windows: 0,
        steps: req.steps as usize,
        nx,
        nu,
        x: Vec::new(),
        u: Vec::new(),
    };
    for c in chunks {
        if c.first != first + out.windows as u64 || (c.nx as usize, c.nu as usize) != (nx, nu) {
            return Err(mismatch(
                &who,
                format!(
                    "chunk {} starts at window {} (nx {}, nu {}), expected {} (nx {nx}, nu {nu})",
                    c.chunk,
                    c.first,
                    c.nx,
                    c.nu,
                    first + out.windows as u64
                ),
            ));
        }
        out.windows += c.windows as usize;
        out.x.extend_from_slice(&c.x);
        out.u.extend_from_slice(&c.u);
    }
    if out.windows != req.window_count() as usize {
        return Err(mismatch(
            &who,
            format!(
                "{} windows, {} were asked for",
                out.windows,
                req.window_count()
            ),
        ));
    }
    Ok(out)
}

/// Asks simulator `sim` for one block and waits for it ([`start_block`] + [`finish_block`]).
/// The same request gives the same bytes; a typed error reply (`bad_request`, `dimension`,
/// `too_large`, `sim_failure`, `busy`, `unsupported`) comes back as [`Error::Remote`].
pub fn collect_block(
    client: &Client,
    sim: &str,
    req: &CollectRequest,
    timeout: Duration,
    live: Option<&Liveliness>,
) -> Result<Block> {
    finish_block(start_block(client, sim, req, timeout)?, sim, req, live)
}

/// A whole collection asked of one simulator in blocks.
#[derive(Clone, Debug, PartialEq)]
pub struct Collection {
    /// The input policy.
    pub policy: CollectPolicy,
    /// The collection's seed.
    pub seed: u64,
    /// Windows in all.
    pub windows: u64,
    /// Windows per block (the last block may be short).
    pub block_windows: u32,
    /// Transitions per window.
    pub steps: u32,
}

impl Collection {
    /// How many blocks the collection has.
    pub fn blocks(&self) -> u64 {
        self.windows.div_ceil(u64::from(self.block_windows.max(1)))
    }

    /// The request of block `b`.
    pub fn request(&self, b: u64) -> CollectRequest {
        let bw = u64::from(self.block_windows.max(1));
        let n = bw.min(self.windows.saturating_sub(b * bw)) as u32;
        CollectRequest {
            policy: self.policy.clone(),
            seed: self.seed,
            block: b,
            block_windows: bw as u32,
            windows: (u64::from(n) != bw).then_some(n),
            steps: self.steps,
        }
    }
}

/// Collects blocks `from_block ..` of `job` from simulator `sim`, handing each to `on_block`
/// in order (which may, e.g., write it to disk: a run that stopped resumes at its next block).
/// Two requests are kept in flight, so the simulator starts the next block while the previous
/// one travels. `timeout` applies per block.
pub fn collect_blocks(
    client: &Client,
    sim: &str,
    job: &Collection,
    from_block: u64,
    timeout: Duration,
    live: Option<&Liveliness>,
    on_block: &mut dyn FnMut(Block) -> Result<()>,
) -> Result<()> {
    let end = job.blocks();
    let mut next = from_block;
    let mut in_flight = std::collections::VecDeque::new();
    loop {
        while in_flight.len() < 2 && next < end {
            let req = job.request(next);
            // The second request waits behind the first on the simulator.
            let t = timeout * (in_flight.len() as u32 + 1);
            in_flight.push_back((start_block(client, sim, &req, t)?, req));
            next += 1;
        }
        let Some((pending, req)) = in_flight.pop_front() else {
            return Ok(());
        };
        on_block(finish_block(pending, sim, &req, live)?)?;
    }
}

/// Collects `windows` windows of `steps` transitions from every simulator in `sims` at once
/// (one thread each), each running them itself in blocks of `block` windows; simulator `j`
/// uses policy `policies[j]` and seed `seeds[j]`. Returns one dataset per simulator (aligned pairing);
/// `progress(done, total)` gets the windows of the slowest simulator so far.
#[allow(clippy::too_many_arguments)]
pub fn collect_datasets(
    sims: &[SimClient],
    policies: &[CollectPolicy],
    seeds: &[u64],
    windows: usize,
    steps: usize,
    block: u32,
    live: Option<&Liveliness>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Vec<Dataset>> {
    if seeds.len() != sims.len() || policies.len() != sims.len() {
        return Err(Error::Config(format!(
            "{} simulators but {} seeds and {} policies",
            sims.len(),
            seeds.len(),
            policies.len()
        )));
    }
    let steps32 =
        u32::try_from(steps).map_err(|_| Error::Config(format!("{steps} steps per window")))?;
    let (tx, rx) = mpsc::channel::<(usize, usize)>();
    std::thread::scope(|scope| {
        let handles: Vec<_> = sims
            .iter()
            .zip(seeds)
            .zip(policies)
            .enumerate()
            .map(|(j, ((s, &seed), policy))| {
                let tx = tx.clone();
                let job = Collection {
                    policy: policy.clone(),
                    seed,
                    windows: windows as u64,
                    block_windows: block,
                    steps: steps32,
                };
                scope.spawn(move || -> Result<Dataset> {
                    let info = &s.info.sim;
                    let mut ds = empty_dataset(s, windows, steps, seed, policy);
                    collect_blocks(s.client(), &s.id, &job, 0, BLOCK_TIMEOUT, live, &mut |b| {
                        if (b.nx, b.nu) != (info.nx(), info.nu()) {
                            return Err(Error::protocol(
                                ErrorCode::Dimension,
                                format!(
                                    "simulator '{}' sent windows with nx {} and nu {}, its info says {} and {}",
                                    s.id,
                                    b.nx,
                                    b.nu,
                                    info.nx(),
                                    info.nu()
                                ),
                            ));
                        }
                        ds.x.extend_from_slice(&b.x);
                        ds.u.extend_from_slice(&b.u);
                        let _ = tx.send((j, b.windows));
                        Ok(())
                    })?;
                    Ok(ds)
                })
            })
            .collect();
        drop(tx);
        let mut done = vec![0usize; sims.len()];
        for (j, n) in rx {
            done[j] += n;
            progress(done.iter().copied().min().unwrap_or(0), windows);
        }
        handles
            .into_iter()
            .map(|h| {
                h.join()
                    .unwrap_or_else(|_| Err(Error::Config("a collect thread panicked".into())))
            })
            .collect()
    })
}

/// The dataset of simulator `s`, empty; its `policy` names the collect policy and, for a planned
/// one, how the simulator plans (the string its info's `extra.planned_collect` gives, if any:
/// goals, seeds, solver).
fn empty_dataset(
    s: &SimClient,
    windows: usize,
    steps: usize,
    seed: u64,
    policy: &CollectPolicy,
) -> Dataset {
    let mut name = policy.describe();
    if matches!(policy, CollectPolicy::Planned { .. }) {
        if let Some(how) = s
            .info
            .sim
            .extra
            .get("planned_collect")
            .and_then(|v| v.as_str())
        {
            name = format!("{name}; {how}");
        }
    }
    super::empty_dataset(
        &s.info.sim,
        windows,
        steps,
        seed,
        format!("zenoh:sim/{}/collect", s.id),
        &name,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_collection_is_cut_into_blocks_with_a_short_last_one() {
        let job = Collection {
            policy: CollectPolicy::default(),
            seed: 1,
            windows: 1050,
            block_windows: 500,
            steps: 15,
        };
        assert_eq!(job.blocks(), 3);
        let r: Vec<CollectRequest> = (0..3).map(|b| job.request(b)).collect();
        assert_eq!(r[0].windows, None);
        assert_eq!(r[1].first_window(), Some(500));
        assert_eq!((r[2].first_window(), r[2].window_count()), (Some(1000), 50));
        let exact = Collection {
            windows: 1000,
            ..job
        };
        assert_eq!((exact.blocks(), exact.request(1).windows), (2, None));
    }
}
