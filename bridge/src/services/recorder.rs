//! The recorder: turns a free-running simulator's `state` stream into a dataset file (windows of
//! T transitions, exact input pairing from the state messages) and an MCAP file of the whole
//! stream (states, inputs, reference; [`super::recording_mcap`]), detecting gaps by sequence
//! number, and serves recorded datasets at `…/data/{name}`.

use std::collections::HashMap;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use koopman::data::{Dataset, DatasetMeta, Pairing};
use serde::{Deserialize, Serialize};
use zenoh::{Session, Wait};

use super::recording_mcap::{check_reference, mcap_bytes, McapRecording};
use super::{key_tail, parse_json, query_json, serve_queries, to_json, Inbox};
use crate::codec::StateMsg;
use crate::error::{Error, ErrorCode, ErrorReply, Result};
use crate::keyexpr::{validate_chunk, Keys, Role, SimLeaf};
use crate::messages::InfoReply;

/// `…/recorder/{id}/record` request.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordRequest {
    /// `start` or `stop`.
    pub action: String,
    /// Simulator id.
    pub sim: String,
    /// Dataset name (`[a-z0-9_-]`), required for `stop`.
    #[serde(default)]
    pub name: String,
    /// Transitions per window (default 15).
    #[serde(default)]
    pub window_steps: Option<usize>,
    /// `start` only: the reference the simulator is driven towards, for the MCAP file's
    /// `reference` channel: `nx` values, or rows of `nx` (row `k` at step `k`, the last one
    /// repeated past the end). Checked at `stop` against the simulator's `nx`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference: Option<Vec<f64>>,
}

/// `stop` reply: what was recorded.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RecordSummary {
    /// Dataset name.
    pub name: String,
    /// States received.
    pub states: u64,
    /// Sequence numbers missing from the stream.
    pub gaps: u64,
    /// States that arrived with a sequence number lower than an earlier one.
    pub out_of_order: u64,
    /// Windows written.
    pub windows: usize,
    /// The MCAP file written beside the dataset (`{name}.mcap`, every received state), if any
    /// state was received.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mcap: Option<String>,
    /// States received but not kept because the recordings held [`MAX_RECORDED_BYTES`]
    /// (absent when none).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub dropped: u64,
}

fn is_zero(n: &u64) -> bool {
    *n == 0
}

/// Most recordings a recorder runs at once (PROTOCOL.md, "Limits"): another `start` is `busy`.
pub const MAX_RECORDINGS: usize = 64;
/// Most state data all running recordings of a recorder keep together (512 MiB, counted as
/// [`state_cost`]): a state past it is dropped and counted in [`RecordSummary::dropped`].
pub const MAX_RECORDED_BYTES: usize = 512 << 20;

/// What keeping state `m` costs against [`MAX_RECORDED_BYTES`]: its values and a fixed
/// overhead for the message and its vectors.
pub fn state_cost(m: &StateMsg) -> usize {
    96 + 8 * (m.x.len() + m.u.len())
}

/// Asks recorder `id` to start recording simulator `sim`'s state stream in windows of
/// `window_steps` transitions (None: 15). `reference` (`nx` values, or rows of `nx` with row
/// `k` at step `k`) is what the simulator is driven towards, written to the MCAP file's
/// `reference` channel; `None`: no reference channel.
pub fn record_start(
    client: &crate::client::Client,
    id: &str,
    sim: &str,
    window_steps: Option<usize>,
    reference: Option<Vec<f64>>,
    timeout: Duration,
) -> Result<()> {
    let req = RecordRequest {
        action: "start".into(),
        sim: sim.into(),
        name: String::new(),
        window_steps,
        reference,
    };
    let key = client.keys.recorder(id)?;
    let _: serde_json::Value =
        query_json(client, &key, &req, timeout, &format!("recorder '{id}'"))?;
    Ok(())
}

/// Asks recorder `id` to stop recording `sim` and write the windows as dataset `name` (served
/// at `…/data/{name}`); returns what was recorded.
pub fn record_stop(
    client: &crate::client::Client,
    id: &str,
    sim: &str,
    name: &str,
    timeout: Duration,
) -> Result<RecordSummary> {
    let req = RecordRequest {
        action: "stop".into(),
        sim: sim.into(),
        name: name.into(),
        window_steps: None,
        reference: None,
    };
    let key = client.keys.recorder(id)?;
    query_json(client, &key, &req, timeout, &format!("recorder '{id}'"))
}

/// The received states of one recording.
#[derive(Default)]
struct Recording {
    states: Vec<StateMsg>,
    bad: u64,
    /// What `states` cost against the recorder's budget ([`state_cost`]).
    bytes: usize,
    /// States dropped because the budget was spent.
    dropped: u64,
}

/// Keeps state `m` in `rec` if the recorder's budget `spent` (what every running recording
/// keeps) has room for it under [`MAX_RECORDED_BYTES`]; otherwise counts it as dropped.
fn keep(rec: &mut Recording, m: StateMsg, spent: &AtomicUsize) {
    let c = state_cost(&m);
    if spent.fetch_add(c, Ordering::Relaxed) + c > MAX_RECORDED_BYTES {
        spent.fetch_sub(c, Ordering::Relaxed);
        rec.dropped += 1;
    } else {
        rec.bytes += c;
        rec.states.push(m);
    }
}

/// Turns a sequence of state messages into windows of `steps` transitions. Windows never span
/// a sequence gap or a reset (k not increasing by one). Returns (x, u, windows, gaps, out_of_order).
pub fn windows_from_stream(
    states: &[StateMsg],
    steps: usize,
    nx: usize,
    nu: usize,
) -> (Vec<f64>, Vec<f64>, usize, u64, u64) {
    let (mut x, mut u) = (Vec::new(), Vec::new());
    let (mut n, mut gaps, mut ooo) = (0usize, 0u64, 0u64);
    let mut run: Vec<&StateMsg> = Vec::new();
    let mut last_seq: Option<u64> = None;
    for s in states {
        if let Some(l) = last_seq {
            if s.seq <= l {
                ooo += 1;
                continue;
            }
            if s.seq > l + 1 {
                gaps += s.seq - l - 1;
                run.clear();
            }
        }
        last_seq = Some(s.seq);
        let continues = run
            .last()
            .is_some_and(|p| s.k == p.k + 1 && s.u.len() == nu);
        if !continues {
            run.clear();
        }
        if s.x.len() != nx {
            run.clear();
            continue;
        }
        run.push(s);
        if run.len() == steps + 1 {
            for (i, r) in run.iter().enumerate() {
                x.extend_from_slice(&r.x);
                if i > 0 {
                    u.extend_from_slice(&r.u);
                }
            }
            n += 1;
            let last = run[steps];
            run.clear();
            run.push(last);
        }
    }
    (x, u, n, gaps, ooo)
}

#[derive(Clone, Copy)]
enum Op {
    Record,
    Data,
}

/// A recording in progress: its states, the subscription, the window length, the
/// simulator's `info` (read at `start`, while the simulator is surely there) and the reference.
struct Active {
    rec: Arc<Mutex<Recording>>,
    sub: zenoh::pubsub::Subscriber<()>,
    steps: usize,
    info: Option<InfoReply>,
    reference: Option<Vec<f64>>,
}

/// The `info` of simulator `sim`; one that does not answer is `not_found` (its dimensions,
/// which a recording needs, are unknown).
fn sim_info(
    client: &crate::client::Client,
    keys: &Keys,
    sim: &str,
) -> std::result::Result<InfoReply, ErrorReply> {
    let key = keys.sim(sim, SimLeaf::Info).map_err(|e| e.to_reply())?;
    let who = format!("simulator '{sim}'");
    let b = client
        .query(&key, Vec::new(), Duration::from_secs(10), &who)
        .map_err(|e| match e {
            Error::Remote { reply, .. } => reply,
            _ => ErrorReply::new(
                ErrorCode::NotFound,
                format!(
                    "{who} does not answer info: its dimensions are unknown \
                     (start recording while it runs)"
                ),
            ),
        })?;
    parse_json("info", &b)
}

/// Serves the recorder `id` (recordings written to `data_dir/{name}.npz`) until `stop` is set.
pub fn serve(
    session: &Session,
    keys: &Keys,
    id: &str,
    data_dir: &Path,
    stop: &AtomicBool,
) -> Result<()> {
    std::fs::create_dir_all(data_dir).map_err(|e| Error::Io {
        path: data_dir.to_path_buf(),
        source: e,
    })?;
    let client = crate::client::Client::new(session.clone(), keys.clone());
    let mut inbox = Inbox::new();
    inbox.declare(session, &keys.recorder(id)?, Op::Record)?;
    inbox.declare(session, &keys.under(&["data", "*"]), Op::Data)?;
    let mut active: HashMap<String, Active> = HashMap::new();
    // The state data every running recording keeps, against MAX_RECORDED_BYTES.
    let budget = Arc::new(AtomicUsize::new(0));
    serve_queries(
        session,
        keys,
        Role::Recorder,
        id,
        &inbox,
        stop,
        |op, q, body| match op {
            Op::Data => {
                let name = key_tail(q, "dataset name")?;
                let p = data_dir.join(format!("{name}.npz"));
                std::fs::read(&p).map_err(|_| {
                    ErrorReply::new(ErrorCode::NotFound, format!("no dataset '{name}'"))
                })
            }
            Op::Record => {
                let req: RecordRequest = parse_json("record", &body)?;
                validate_chunk("sim id", &req.sim).map_err(|e| e.to_reply())?;
                match req.action.as_str() {
                    "start" => {
                        if active.contains_key(&req.sim) {
                            return Err(ErrorReply::new(
                                ErrorCode::Busy,
                                format!("already recording '{}'", req.sim),
                            ));
                        }
                        if active.len() >= MAX_RECORDINGS {
                            return Err(ErrorReply::new(
                                ErrorCode::Busy,
                                format!("{MAX_RECORDINGS} recordings are running (the most)"),
                            ));
                        }
                        if let Some(r) = &req.reference {
                            // Whole rows of some nx, finite; against the simulator's nx below
                            // when it answers (else at stop, when the MCAP file is written).
                            check_reference(r, r.len()).map_err(|e| e.to_reply())?;
                        }
                        let rec = Arc::new(Mutex::new(Recording::default()));
                        let (r2, spent) = (rec.clone(), budget.clone());
                        // Subscribed before `info` is asked: a free-running adapter that waits
                        // for a subscriber (`--wait-subscriber`) answers queries only once it
                        // runs.
                        let sub = session
                            .declare_subscriber(
                                keys.sim(&req.sim, SimLeaf::State)
                                    .map_err(|e| e.to_reply())?,
                            )
                            .callback(move |s| {
                                let mut r = super::lock(&r2);
                                match StateMsg::decode(&s.payload().to_bytes()) {
                                    Ok(m) => keep(&mut r, m, &spent),
                                    Err(_) => r.bad += 1,
                                }
                            })
                            .wait()
                            .map_err(|e| Error::zenoh(e).to_reply())?;
                        // The simulator's dimensions are read now if it answers: a
                        // free-running simulator may have finished (and gone) by the time the
                        // recording stops. One that is not there yet is asked again at `stop`.
                        let info = sim_info(&client, keys, &req.sim).ok();
                        if let (Some(r), Some(i)) = (&req.reference, &info) {
                            check_reference(r, i.sim.nx()).map_err(|e| e.to_reply())?;
                        }
                        active.insert(
                            req.sim.clone(),
                            Active {
                                rec,
                                sub,
                                steps: req.window_steps.unwrap_or(15),
                                info,
                                reference: req.reference.clone(),
                            },
                        );
                        to_json(&serde_json::json!({"recording": req.sim}))
                    }
                    "stop" => {
                        validate_chunk("dataset name", &req.name).map_err(|e| e.to_reply())?;
                        let Active {
                            rec,
                            sub,
                            steps,
                            info,
                            reference,
                        } = active.remove(&req.sim).ok_or_else(|| {
                            ErrorReply::new(
                                ErrorCode::NotFound,
                                format!("not recording '{}'", req.sim),
                            )
                        })?;
                        drop(sub);
                        // The states are freed when this arm ends; their budget now.
                        budget.fetch_sub(super::lock(&rec).bytes, Ordering::Relaxed);
                        let info = match info {
                            Some(i) => i,
                            None => sim_info(&client, keys, &req.sim)?,
                        };
                        let rec = super::lock(&rec);
                        let (nx, nu) = (info.sim.nx(), info.sim.nu());
                        let (x, u, n, gaps, ooo) = windows_from_stream(&rec.states, steps, nx, nu);
                        let d = Dataset {
                            n,
                            steps,
                            nx,
                            nu,
                            x,
                            u,
                            meta: DatasetMeta {
                                env: info.sim.env.clone(),
                                dt: info.sim.dt,
                                state_names: info.sim.state_names.clone(),
                                input_names: info.sim.input_names.clone(),
                                pairing: Pairing::Aligned,
                                seed: 0,
                                source: format!("zenoh:sim/{} (free-run recording)", req.sim),
                                policy: "recorded".into(),
                                region: None,
                                window_flags: None,
                            },
                        };
                        if n > 0 {
                            d.save_npz(&data_dir.join(format!("{}.npz", req.name)))
                                .map_err(|e| Error::from(e).to_reply())?;
                        }
                        let mcap = if rec.states.is_empty() {
                            None
                        } else {
                            let file = format!("{}.mcap", req.name);
                            let bytes = mcap_bytes(&McapRecording {
                                sim: &req.sim,
                                info: &info.sim,
                                states: &rec.states,
                                reference: reference.as_deref(),
                            })
                            .map_err(|e| e.to_reply())?;
                            koopman::fsutil::write_atomic(&data_dir.join(&file), &bytes)
                                .map_err(|e| Error::from(e).to_reply())?;
                            Some(file)
                        };
                        to_json(&RecordSummary {
                            name: req.name.clone(),
                            states: rec.states.len() as u64,
                            gaps,
                            out_of_order: ooo,
                            windows: n,
                            mcap,
                            dropped: rec.dropped,
                        })
                    }
                    other => Err(ErrorReply::new(
                        ErrorCode::BadRequest,
                        format!("action '{other}': expected start or stop"),
                    )),
                }
            }
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn st(seq: u64, k: u64, x: f64, u: f64) -> StateMsg {
        StateMsg {
            seq,
            k,
            t: k as f64,
            x: vec![x],
            u: if k == 0 { vec![] } else { vec![u] },
        }
    }

    /// The recordings' budget: a state that would pass [`MAX_RECORDED_BYTES`] is dropped and
    /// counted, one that fits is kept and charged.
    #[test]
    fn states_past_the_budget_are_dropped_and_counted() {
        let c = state_cost(&st(0, 1, 0.0, 0.0));
        assert_eq!(c, 96 + 16);
        let spent = AtomicUsize::new(MAX_RECORDED_BYTES - 2 * c + 1);
        let mut rec = Recording::default();
        keep(&mut rec, st(0, 1, 0.0, 0.0), &spent);
        keep(&mut rec, st(1, 2, 0.0, 0.0), &spent);
        assert_eq!((rec.states.len(), rec.dropped, rec.bytes), (1, 1, c));
        assert_eq!(spent.load(Ordering::Relaxed), MAX_RECORDED_BYTES - c + 1);
    }

    #[test]
    fn windows_skip_gaps_and_pair_inputs_exactly() {
        // seq 0..=4 contiguous (k 0..4), then seq 6 missing 5, then 6..=8.
        let mut s: Vec<StateMsg> = (0..5)
            .map(|i| st(i, i, i as f64, 10.0 + i as f64))
            .collect();
        s.extend((6..9).map(|i| st(i, i, i as f64, 10.0 + i as f64)));
        let (x, u, n, gaps, ooo) = windows_from_stream(&s, 2, 1, 1);
        assert_eq!(gaps, 1);
        assert_eq!(ooo, 0);
        // windows: [0,1,2], [2,3,4], after the gap [6,7,8].
        assert_eq!(n, 3);
        assert_eq!(x, vec![0.0, 1.0, 2.0, 2.0, 3.0, 4.0, 6.0, 7.0, 8.0]);
        // the input of window [0,1,2] is (u that led to 1, u that led to 2).
        assert_eq!(u, vec![11.0, 12.0, 13.0, 14.0, 17.0, 18.0]);
        let mut dup = s.clone();
        dup.insert(3, st(1, 1, 1.0, 11.0));
        let (_, _, _, _, ooo) = windows_from_stream(&dup, 2, 1, 1);
        assert_eq!(ooo, 1);
    }
}
