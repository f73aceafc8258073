//! MPC `attach`: free-run control of a simulator's state stream — the checks made before
//! attaching (liveliness token, `info`, mode, dimensions, input bounds) and the control thread
//! with its counters ([`AttachStats`]).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use koopman::mpc::{MpcConfig, MpcController};
use serde::{Deserialize, Serialize};
use zenoh::Wait;

use crate::client::Client;
use crate::codec::{CommandMsg, StateMsg};
use crate::error::{Error, ErrorCode, ErrorReply, Result};
use crate::keyexpr::{Role, SimLeaf};
use crate::messages::{InfoReply, SimInfo};

/// Statistics of an attachment (the `attach` reply when detaching). Every state that arrives
/// is counted in `states` and in exactly one of `commands` (answered), `skipped`,
/// `bad_states`, `solve_errors` or `publish_errors`: no failure is silent.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct AttachStats {
    /// State messages received (decodable or not).
    pub states: u64,
    /// Commands published (one per answered state).
    pub commands: u64,
    /// Sequence numbers missing between the decodable states received (states the transport
    /// lost: the same count a recorder of the stream reports).
    pub gaps: u64,
    /// States received but not answered because a newer state was already queued (the MPC
    /// answers only the newest state; these are not gaps).
    #[serde(default)]
    pub skipped: u64,
    /// States that could not be decoded or have the wrong dimension.
    #[serde(default)]
    pub bad_states: u64,
    /// States whose solve failed (no command sent for them).
    #[serde(default)]
    pub solve_errors: u64,
    /// Commands that could not be published.
    #[serde(default)]
    pub publish_errors: u64,
    /// The last of those failures, for a human (`None` if there was none).
    #[serde(default)]
    pub last_error: Option<String>,
    /// State→command latency inside the service: histogram bucket upper bounds in µs.
    pub latency_bounds_us: Vec<u64>,
    /// Counts per bucket (last bucket: everything above the last bound).
    pub latency_counts: Vec<u64>,
    /// Median latency in µs.
    pub latency_median_us: f64,
    /// 99th percentile latency in µs.
    pub latency_p99_us: f64,
}

/// Most simulators an MPC service controls at once (a thread each; PROTOCOL.md, "Limits"):
/// another `attach` is `busy`.
pub const MAX_ATTACHED: usize = 64;

/// A running attachment: its stop flag and its thread (which returns the statistics).
pub(super) struct Attached {
    /// Set to stop the thread.
    pub stop: Arc<AtomicBool>,
    /// The control thread.
    pub thread: std::thread::JoinHandle<AttachStats>,
}

/// Intersects the input bounds of `cfg` with the simulator's (`info.u_min`/`u_max`): absent
/// bounds become the simulator's, given ones are tightened to them. Wrong lengths are a
/// `dimension` error.
pub fn clamp_bounds_to_sim(cfg: &mut MpcConfig, info: &SimInfo) -> Result<()> {
    let nu = info.nu();
    cfg.u_min = Some(tighten(
        "u_min",
        cfg.u_min.as_deref(),
        &info.u_min,
        nu,
        f64::max,
    )?);
    cfg.u_max = Some(tighten(
        "u_max",
        cfg.u_max.as_deref(),
        &info.u_max,
        nu,
        f64::min,
    )?);
    Ok(())
}

/// One side of the input box: the simulator's bounds `sim`, tightened by `given` with `pick`.
fn tighten(
    name: &str,
    given: Option<&[f64]>,
    sim: &[f64],
    nu: usize,
    pick: fn(f64, f64) -> f64,
) -> Result<Vec<f64>> {
    let dim = |what: &str, n: usize| {
        Error::protocol(
            ErrorCode::Dimension,
            format!("{what} {name} has {n} values for {nu} inputs"),
        )
    };
    if sim.len() != nu {
        return Err(dim("the simulator's", sim.len()));
    }
    match given {
        None => Ok(sim.to_vec()),
        Some(g) if g.len() != nu => Err(dim("the configured", g.len())),
        Some(g) => Ok(g.iter().zip(sim).map(|(&a, &b)| pick(a, b)).collect()),
    }
}

fn reply(code: ErrorCode, m: String) -> ErrorReply {
    ErrorReply::new(code, m)
}

/// Checks that simulator `sim` is there (its liveliness token), free-running, and of the
/// dimensions of `reference`; builds its controller with `build(cfg)` from `cfg` with the input
/// bounds intersected with the simulator's; then starts the control thread.
pub(super) fn start(
    client: &Client,
    sim: &str,
    reference: &[f64],
    mut cfg: MpcConfig,
    build: impl FnOnce(&MpcConfig) -> Result<MpcController<'static>>,
) -> std::result::Result<Attached, ErrorReply> {
    let (session, keys) = (&client.session, &client.keys);
    let err = |e: Error| e.to_reply();
    let alive = session
        .liveliness()
        .get(keys.alive(Role::Sim, sim).map_err(err)?)
        .timeout(Duration::from_secs(2))
        .wait()
        .map_err(|e| err(Error::zenoh(e)))?;
    if !alive.recv().is_ok_and(|r| r.result().is_ok()) {
        return Err(reply(
            ErrorCode::NotFound,
            format!("simulator '{sim}' is not in this session (no liveliness token)"),
        ));
    }
    // Subscribe before asking for `info`: an adapter that waits for a subscriber before it
    // starts (`--wait-subscriber`) answers queries only once it runs.
    let (tx, rx) = std::sync::mpsc::channel::<(Instant, Vec<u8>)>();
    let sub = session
        .declare_subscriber(keys.sim(sim, SimLeaf::State).map_err(err)?)
        .callback(move |s| {
            let _ = tx.send((Instant::now(), s.payload().to_bytes().into_owned()));
        })
        .wait()
        .map_err(|e| err(Error::zenoh(e)))?;
    let who = format!("simulator '{sim}'");
    let b = client
        .query(
            &keys.sim(sim, SimLeaf::Info).map_err(err)?,
            Vec::new(),
            Duration::from_secs(5),
            &who,
        )
        .map_err(err)?;
    let info: InfoReply = serde_json::from_slice(&b)
        .map_err(|e| reply(ErrorCode::BadRequest, format!("{who}: info reply: {e}")))?;
    if info.mode != "free-run" {
        return Err(reply(
            ErrorCode::Busy,
            format!(
                "{who} is in {} mode; attach needs a free-running simulator",
                info.mode
            ),
        ));
    }
    let (nx, nu) = (info.sim.nx(), info.sim.nu());
    if reference.len() != nx && reference.len() != cfg.horizon * nx {
        return Err(reply(
            ErrorCode::Dimension,
            format!(
                "reference has {} values; {who} has {nx} states (give {nx}, or {} for horizon {})",
                reference.len(),
                cfg.horizon * nx,
                cfg.horizon
            ),
        ));
    }
    clamp_bounds_to_sim(&mut cfg, &info.sim).map_err(err)?;
    let controller = build(&cfg).map_err(err)?;
    if controller.nx() != nx || controller.nu() != nu {
        return Err(reply(
            ErrorCode::Dimension,
            format!(
                "the model has nx = {}, nu = {}; {who} has nx = {nx}, nu = {nu}",
                controller.nx(),
                controller.nu()
            ),
        ));
    }
    let publisher = session
        .declare_publisher(keys.sim(sim, SimLeaf::Command).map_err(err)?)
        .wait()
        .map_err(|e| err(Error::zenoh(e)))?;
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    let reference = reference.to_vec();
    let thread = std::thread::spawn(move || {
        let _sub = sub;
        let put = |bytes: Vec<u8>| publisher.put(bytes).wait().map_err(|e| e.to_string());
        control_loop(&rx, controller, &reference, &flag, put)
    });
    Ok(Attached { stop, thread })
}

const LATENCY_BOUNDS_US: [u64; 12] = [
    50, 100, 200, 500, 1000, 2000, 5000, 10_000, 20_000, 50_000, 100_000, 1_000_000,
];

/// Answers the newest queued state with a command until `stop` is set; counts everything.
fn control_loop(
    rx: &std::sync::mpsc::Receiver<(Instant, Vec<u8>)>,
    mut c: MpcController<'static>,
    reference: &[f64],
    stop: &AtomicBool,
    put: impl Fn(Vec<u8>) -> std::result::Result<(), String>,
) -> AttachStats {
    let (nx, nu) = (c.nx(), c.nu());
    let mut stats = AttachStats {
        latency_bounds_us: LATENCY_BOUNDS_US.to_vec(),
        latency_counts: vec![0; LATENCY_BOUNDS_US.len() + 1],
        ..Default::default()
    };
    let mut lat = Vec::new();
    let mut last_seq: Option<u64> = None;
    let mut seq = 0u64;
    while !stop.load(Ordering::Relaxed) {
        let Ok(first) = rx.recv_timeout(Duration::from_millis(100)) else {
            continue;
        };
        // Every queued state is counted; only the newest decodable one is answered.
        let mut newest: Option<(Instant, StateMsg)> = None;
        for (arrived, bytes) in std::iter::once(first).chain(rx.try_iter()) {
            stats.states += 1;
            let s = match StateMsg::decode(&bytes) {
                Ok(s) if s.x.len() == nx => s,
                Ok(s) => {
                    stats.bad_states += 1;
                    stats.last_error = Some(format!("state with {} values, nx = {nx}", s.x.len()));
                    continue;
                }
                Err(e) => {
                    stats.bad_states += 1;
                    stats.last_error = Some(format!("undecodable state: {e}"));
                    continue;
                }
            };
            if let Some(l) = last_seq {
                if s.seq > l + 1 {
                    stats.gaps += s.seq - l - 1;
                }
            }
            last_seq = Some(s.seq);
            if newest.replace((arrived, s)).is_some() {
                stats.skipped += 1;
            }
        }
        let Some((arrived, s)) = newest else {
            continue;
        };
        let sol = match c.solve(&s.x, reference) {
            Ok(sol) => sol,
            Err(e) => {
                stats.solve_errors += 1;
                stats.last_error = Some(format!("solve at k = {}: {e}", s.k));
                continue;
            }
        };
        let cmd = CommandMsg {
            seq,
            k: s.k,
            u: sol.u[..nu].to_vec(),
        };
        seq += 1;
        match put(cmd.encode()) {
            Ok(()) => stats.commands += 1,
            Err(e) => {
                stats.publish_errors += 1;
                stats.last_error = Some(format!("publish at k = {}: {e}", s.k));
                continue;
            }
        }
        let us = arrived.elapsed().as_micros() as u64;
        lat.push(us as f64);
        let b = LATENCY_BOUNDS_US
            .iter()
            .position(|&x| us <= x)
            .unwrap_or(LATENCY_BOUNDS_US.len());
        stats.latency_counts[b] += 1;
    }
    lat.sort_by(|a, b| a.total_cmp(b));
    if !lat.is_empty() {
        stats.latency_median_us = lat[lat.len() / 2];
        stats.latency_p99_us = lat[((lat.len() as f64 * 0.99) as usize).min(lat.len() - 1)];
    }
    stats
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounds_are_the_simulators_tightened_by_the_configured_ones() {
        let sys = koopman::systems::by_name("double-pendulum").unwrap();
        let info = SimInfo::from_system(sys.as_ref()); // ±6 on two inputs
        let mut cfg = MpcConfig::default();
        clamp_bounds_to_sim(&mut cfg, &info).unwrap();
        assert_eq!(cfg.u_min, Some(vec![-6.0, -6.0]));
        assert_eq!(cfg.u_max, Some(vec![6.0, 6.0]));
        let mut cfg = MpcConfig {
            u_min: Some(vec![-10.0, -2.0]),
            u_max: Some(vec![1.0, 60.0]),
            ..Default::default()
        };
        clamp_bounds_to_sim(&mut cfg, &info).unwrap();
        assert_eq!(cfg.u_min, Some(vec![-6.0, -2.0]));
        assert_eq!(cfg.u_max, Some(vec![1.0, 6.0]));
        let mut bad = MpcConfig {
            u_max: Some(vec![1.0]),
            ..Default::default()
        };
        let e = clamp_bounds_to_sim(&mut bad, &info).unwrap_err();
        assert_eq!(e.to_reply().code, ErrorCode::Dimension);
    }
}
