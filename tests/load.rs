//! Load (issue 13 §3): ten simulators free-running at 1 kHz in one session, every stream
//! recorded by the recorder service and watched by a second subscriber here: sequence gaps, late
//! steps and per-simulator rates. Ignored (a minute of real time):
//!
//! `cargo test --release --test load -- --ignored --nocapture`
//!
//! `KB_LOAD_SECONDS` (default 60) sets the duration, `KB_LOAD_SEGMENT_SECONDS` (default: the
//! whole run) cuts the recordings into segments (each checked, then deleted: the soak of
//! `scripts/soak.sh` runs 30 minutes in 1-minute segments), `KB_LOAD_REPORT` names a JSON file
//! for the figures.

mod common;

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use bridge::client::SimClient;
use bridge::codec::StateMsg;
use bridge::keyexpr::{Role, SimLeaf};
use bridge::orchestrator::SERVICES_ID;
use bridge::services::recorder::{record_start, record_stop, RecordSummary};
use bridge::zenoh::Wait;
use koopman::data::Dataset;

/// Simulators in the session.
const SIMS: usize = 10;
/// Their free-run rate (steps per second).
const RATE_HZ: u32 = 1000;

/// What the test's own subscriber saw of one stream.
#[derive(Default, Clone, Copy)]
struct Seen {
    states: u64,
    gaps: u64,
    out_of_order: u64,
    last_seq: Option<u64>,
}

impl Seen {
    fn take(&mut self, seq: u64) {
        self.states += 1;
        match self.last_seq {
            Some(l) if seq <= l => self.out_of_order += 1,
            Some(l) => {
                self.gaps += seq - l - 1;
                self.last_seq = Some(seq);
            }
            None => self.last_seq = Some(seq),
        }
    }
}

/// The totals of one simulator over every segment.
#[derive(Default, Debug, Clone, serde::Serialize)]
struct PerSim {
    id: String,
    recorded_states: u64,
    recorder_gaps: u64,
    recorder_out_of_order: u64,
    windows: usize,
    observer_states: u64,
    observer_gaps: u64,
    observer_out_of_order: u64,
    published: u64,
    overruns: u64,
    max_lateness_us: u64,
    rate_hz: f64,
}

fn env_secs(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Every transition of the recorded dataset `path` equals a local step of the damped pendulum
/// with the recorded input; returns its number of windows.
fn check_recording(path: &std::path::Path) -> usize {
    let d = Dataset::load_npz(path).unwrap();
    let sys = koopman::systems::by_name("damped-pendulum").unwrap();
    let mut next = vec![0.0; d.nx];
    for i in 0..d.n {
        for t in 0..d.steps {
            sys.step(d.state(i, t), d.input(i, t), &mut next);
            assert_eq!(
                d.state(i, t + 1),
                &next[..],
                "{}: window {i} step {t}",
                path.display()
            );
        }
    }
    d.n
}

#[test]
#[ignore = "a minute of real time; cargo test --release --test load -- --ignored --nocapture"]
fn ten_simulators_at_1khz_are_recorded_without_gaps() {
    let seconds = env_secs("KB_LOAD_SECONDS", 60);
    let segment = env_secs("KB_LOAD_SEGMENT_SECONDS", seconds).clamp(1, seconds);
    let (c, opts, session) = common::cluster("load", &[], &["recorder"]);
    let ids: Vec<String> = (0..SIMS).map(|i| format!("load{i}")).collect();
    let rate = RATE_HZ.to_string();
    let _sims: Vec<_> = ids
        .iter()
        .enumerate()
        .map(|(i, id)| {
            let seed = i.to_string();
            let args = [
                "sim",
                "--env",
                "damped-pendulum",
                "--id",
                id,
                "--session",
                &session,
                "--free-run",
                "--rate",
                &rate,
                "--seed",
                &seed,
            ];
            common::spawn(&c, &opts, id, &args)
        })
        .collect();
    let who: Vec<(Role, String)> = ids.iter().map(|i| (Role::Sim, i.clone())).collect();
    c.live.wait_for(&who, common::READY).unwrap();

    // A second observer of every stream, independent of the recorder.
    let seen: Arc<Mutex<HashMap<String, Seen>>> = Arc::default();
    let _subs: Vec<_> = ids
        .iter()
        .map(|id| {
            let (seen, id2) = (seen.clone(), id.clone());
            c.client
                .session
                .declare_subscriber(c.client.keys.sim(id, SimLeaf::State).unwrap())
                .callback(move |s| {
                    if let Ok(m) = StateMsg::decode(&s.payload().to_bytes()) {
                        bridge::services::lock(&seen)
                            .entry(id2.clone())
                            .or_default()
                            .take(m.seq);
                    }
                })
                .wait()
                .unwrap()
        })
        .collect();

    let data = opts.out_dir.join("state/data");
    let mut totals: Vec<PerSim> = ids
        .iter()
        .map(|id| PerSim {
            id: id.clone(),
            ..Default::default()
        })
        .collect();
    let t0 = Instant::now();
    let mut n_segment = 0;
    while t0.elapsed() < Duration::from_secs(seconds) {
        for id in &ids {
            record_start(
                &c.client,
                SERVICES_ID,
                id,
                Some(15),
                None,
                Duration::from_secs(30),
            )
            .unwrap();
        }
        let left = Duration::from_secs(seconds).saturating_sub(t0.elapsed());
        std::thread::sleep(left.min(Duration::from_secs(segment)));
        for (id, tot) in ids.iter().zip(totals.iter_mut()) {
            let name = format!("{id}-s{n_segment}");
            let s: RecordSummary =
                record_stop(&c.client, SERVICES_ID, id, &name, Duration::from_secs(60)).unwrap();
            let file = data.join(format!("{name}.npz"));
            assert_eq!(check_recording(&file), s.windows, "{name}");
            std::fs::remove_file(&file).unwrap();
            tot.recorded_states += s.states;
            tot.recorder_gaps += s.gaps;
            tot.recorder_out_of_order += s.out_of_order;
            tot.windows += s.windows;
        }
        n_segment += 1;
        eprintln!(
            "segment {n_segment} done at {:.0} s",
            t0.elapsed().as_secs_f64()
        );
    }
    let wall = t0.elapsed().as_secs_f64();

    for tot in totals.iter_mut() {
        let mut sim = SimClient::connect(&c.client, &tot.id, common::READY).unwrap();
        let info = sim.refresh_info().unwrap();
        let st = &info.stats;
        tot.published = st.published;
        tot.overruns = st.overruns;
        tot.max_lateness_us = st.max_lateness_us;
        tot.rate_hz = st.real_time_factor / info.sim.dt;
        let o = bridge::services::lock(&seen)
            .get(&tot.id)
            .copied()
            .unwrap_or_default();
        tot.observer_states = o.states;
        tot.observer_gaps = o.gaps;
        tot.observer_out_of_order = o.out_of_order;
    }
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    eprintln!(
        "{SIMS} simulators at {RATE_HZ} Hz for {wall:.1} s in {n_segment} segment(s); load {}",
        load.trim()
    );
    eprintln!(
        "sim     recorded  gaps ooo  observed gaps ooo  published overruns max-late-us rate-Hz"
    );
    for t in &totals {
        eprintln!(
            "{:7} {:8} {:5} {:3} {:9} {:4} {:3} {:10} {:8} {:11} {:7.1}",
            t.id,
            t.recorded_states,
            t.recorder_gaps,
            t.recorder_out_of_order,
            t.observer_states,
            t.observer_gaps,
            t.observer_out_of_order,
            t.published,
            t.overruns,
            t.max_lateness_us,
            t.rate_hz
        );
    }
    if let Ok(p) = std::env::var("KB_LOAD_REPORT") {
        let r = serde_json::json!({
            "sims": SIMS, "rate_hz": RATE_HZ, "seconds": wall, "segments": n_segment,
            "loadavg_end": load.trim(), "per_sim": totals,
        });
        std::fs::write(p, serde_json::to_vec_pretty(&r).unwrap()).unwrap();
    }
    let expected = (wall * RATE_HZ as f64 * 0.5) as u64;
    for t in &totals {
        assert_eq!(
            (t.recorder_gaps, t.recorder_out_of_order),
            (0, 0),
            "{}: the recorder saw gaps or reordering",
            t.id
        );
        assert_eq!(
            (t.observer_gaps, t.observer_out_of_order),
            (0, 0),
            "{}: the second subscriber saw gaps or reordering",
            t.id
        );
        assert!(
            t.recorded_states > expected,
            "{}: only {} states recorded in {wall:.0} s",
            t.id,
            t.recorded_states
        );
    }
}
