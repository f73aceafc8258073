//! A multi-host fault (issue 13 §3) in network namespaces the test makes itself: a router and
//! two hosts on veth links with loopback-range addresses — host A runs a free-running simulator,
//! host B the recorder and an observer — and A's link is cut mid-recording (`ip link set down`:
//! the simulator host's end by default, so nothing is reset and only the Zenoh lease notices;
//! `KB_NETNS_CUT=router` cuts the router's end instead). The cut is detected (the simulator's
//! liveliness token disappears at B), the simulator reconnects when the link returns, the lost
//! states are reported as sequence gaps, and what was recorded is complete and exact. Skipped,
//! saying why, where namespaces cannot be made (not root).

mod common;

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use bridge::client::{Client, Liveliness};
use bridge::codec::StateMsg;
use bridge::keyexpr::{fresh_session_id, Keys, Role, SimLeaf};
use bridge::services::recorder::{record_start, record_stop, RecordSummary};
use bridge::session::{open_session, Mode, ZenohOptions};
use bridge::zenoh::Wait;
use common::netns::Net;

/// The Zenoh lease of every process here (the default is 10 s): a cut link is noticed after it.
const LEASE_MS: u64 = 2000;

fn unix_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_millis() as u64
}

/// Waits until `f` holds; panics with `what` after `limit`.
fn wait_until(what: &str, limit: Duration, mut f: impl FnMut() -> bool) {
    let t = Instant::now();
    while !f() {
        assert!(t.elapsed() < limit, "{what}: not within {limit:?}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// What the observer saw of the stream: states, gaps between consecutive ones, reorderings.
#[derive(Default, Clone, Copy, serde::Serialize, serde::Deserialize)]
struct Seen {
    states: u64,
    gaps: u64,
    out_of_order: u64,
    last_seq: Option<u64>,
}

/// The observer's process on host B (started by the test below): records simulator `far`
/// through recorder `main` and watches the stream and the simulator's token; writes
/// `started`, `detected` and `result.json` into its folder. `KB_NETNS_OBSERVER` = `session
/// endpoint zenoh-config folder`; without it, nothing.
#[test]
#[ignore = "the observer's process, started by a_link_cut_mid_recording_is_detected_and_nothing_recorded_is_lost"]
fn helper_observer() {
    let Ok(spec) = std::env::var("KB_NETNS_OBSERVER") else {
        return;
    };
    let f: Vec<&str> = spec.split_whitespace().collect();
    let dir = Path::new(f[3]);
    let z = ZenohOptions {
        connect: vec![f[1].to_string()],
        listen: Vec::new(),
        mode: Some(Mode::Client),
        zenoh_config: Some(f[2].into()),
    };
    let session = (0..300)
        .find_map(|_| {
            open_session(&z)
                .map_err(|_| std::thread::sleep(Duration::from_millis(200)))
                .ok()
        })
        .expect("could not reach the router");
    let client = Client::new(session, Keys::new(f[0]).unwrap());
    let live = Liveliness::new(&client).unwrap();
    live.wait_for(
        &[(Role::Sim, "far".into()), (Role::Recorder, "main".into())],
        common::READY,
    )
    .unwrap();
    record_start(
        &client,
        "main",
        "far",
        Some(10),
        None,
        Duration::from_secs(30),
    )
    .unwrap();
    let seen = Arc::new(Mutex::new(Seen::default()));
    let s2 = seen.clone();
    let _sub = client
        .session
        .declare_subscriber(client.keys.sim("far", SimLeaf::State).unwrap())
        .callback(move |s| {
            if let Ok(m) = StateMsg::decode(&s.payload().to_bytes()) {
                let mut v = bridge::services::lock(&s2);
                v.states += 1;
                match v.last_seq {
                    Some(l) if m.seq <= l => v.out_of_order += 1,
                    Some(l) => v.gaps += m.seq - l - 1,
                    None => {}
                }
                if v.last_seq.is_none_or(|l| m.seq > l) {
                    v.last_seq = Some(m.seq);
                }
            }
        })
        .wait()
        .unwrap();
    let now = || *bridge::services::lock(&seen);
    wait_until("200 states", common::READY, || now().states >= 200);
    std::fs::write(dir.join("started"), b"").unwrap();
    wait_until("the cut noticed", Duration::from_secs(60), || {
        live.is_gone(Role::Sim, "far")
    });
    let detected_ms = unix_ms();
    let at_cut = now();
    std::fs::write(dir.join("detected"), detected_ms.to_string()).unwrap();
    wait_until("the simulator back", common::READY, || {
        live.is_alive(Role::Sim, "far")
    });
    let back_ms = unix_ms();
    wait_until("200 states after the cut", common::READY, || {
        now().states >= at_cut.states + 200
    });
    let summary = record_stop(&client, "main", "far", "cut", Duration::from_secs(60)).unwrap();
    let r = serde_json::json!({"detected_ms": detected_ms, "back_ms": back_ms,
        "before_cut": at_cut, "observer": now(), "summary": summary});
    bridge::fsutil::write_atomic(&dir.join("result.json"), &serde_json::to_vec(&r).unwrap())
        .unwrap();
}

#[test]
fn a_link_cut_mid_recording_is_detected_and_nothing_recorded_is_lost() {
    let mut net = match Net::new("cut") {
        Ok(n) => n,
        Err(why) => {
            eprintln!("skipped: network namespaces cannot be made here ({why})");
            return;
        }
    };
    let (r, a, b) = (
        net.ns("r").unwrap(),
        net.ns("a").unwrap(),
        net.ns("b").unwrap(),
    );
    let (r_to_a, a_to_r) = net.link(&r, "127.100.1.2", &a, "127.100.1.1").unwrap();
    net.link(&r, "127.100.2.2", &b, "127.100.2.1").unwrap();
    let dir = common::scratch("netns-cut");
    let cfg = dir.join("zenoh.json5");
    std::fs::write(
        &cfg,
        format!(
            "{{ scouting: {{ multicast: {{ enabled: false }} }}, \
             transport: {{ link: {{ tx: {{ lease: {LEASE_MS}, keep_alive: 4 }} }} }} }}"
        ),
    )
    .unwrap();
    let cfg_s = cfg.display().to_string();
    let session = fresh_session_id();
    let exe = common::exe();
    let log = |n: &str| dir.join(format!("{n}.log"));
    let client_of = |ep: &'static str| {
        [
            "--mode",
            "client",
            "--connect",
            ep,
            "--zenoh-config",
            &cfg_s,
        ]
    };
    let mut procs = vec![net.spawn_router(&r, &exe, &cfg_s, &log("router"))];
    let sim_args = [
        "sim",
        "--env",
        "damped-pendulum",
        "--id",
        "far",
        "--session",
        &session,
        "--free-run",
        "--rate",
        "200",
        "--seed",
        "3",
        "--stdin-lifeline",
    ];
    procs.push(net.spawn(
        &a,
        "simulator",
        &exe,
        &[&sim_args[..], &client_of("tcp/127.100.1.2:7447")].concat(),
        &[],
        &log("sim"),
    ));
    let (state, store) = (
        dir.join("state").display().to_string(),
        dir.join("models").display().to_string(),
    );
    let rec_args = [
        "serve",
        "recorder",
        "--session",
        &session,
        "--id",
        "main",
        "--state-dir",
        &state,
        "--store",
        &store,
        "--stdin-lifeline",
    ];
    procs.push(net.spawn(
        &b,
        "recorder",
        &exe,
        &[&rec_args[..], &client_of("tcp/127.100.2.2:7447")].concat(),
        &[],
        &log("recorder"),
    ));
    let spec = format!("{session} tcp/127.100.2.2:7447 {cfg_s} {}", dir.display());
    let me = std::env::current_exe().unwrap();
    procs.push(net.spawn(
        &b,
        "observer",
        &me,
        &[
            "--exact",
            "helper_observer",
            "--ignored",
            "--nocapture",
            "--test-threads",
            "1",
        ],
        &[("KB_NETNS_OBSERVER", &spec)],
        &log("observer"),
    ));
    let mut alive = |what: &str| {
        for p in procs.iter_mut() {
            if let Some(m) = p.exited() {
                panic!("{what}: {m}");
            }
        }
    };
    let t = Instant::now();
    while !dir.join("started").exists() {
        alive("before the cut");
        assert!(t.elapsed() < common::READY, "the recording never started");
        std::thread::sleep(Duration::from_millis(20));
    }

    // Which end goes down: the simulator host's (default; the router's interface stays up, only
    // the lease notices) or the router's (`KB_NETNS_CUT=router`: the router's writes fail at once).
    let (ns, dev) = match std::env::var("KB_NETNS_CUT").as_deref() {
        Ok("router") => (&r, &r_to_a),
        _ => (&a, &a_to_r),
    };
    let cut_ms = unix_ms();
    net.set_link(ns, dev, false);
    let t = Instant::now();
    let detected_ms: u64 = loop {
        if let Ok(s) = std::fs::read_to_string(dir.join("detected")) {
            break s.trim().parse().unwrap();
        }
        alive("during the cut");
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "the cut was never noticed"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    let detection = detected_ms.saturating_sub(cut_ms);
    let restored_ms = unix_ms();
    net.set_link(ns, dev, true);
    let t = Instant::now();
    let result: serde_json::Value = loop {
        if let Ok(b) = std::fs::read(dir.join("result.json")) {
            break serde_json::from_slice(&b).unwrap();
        }
        alive("after the cut");
        assert!(
            t.elapsed() < Duration::from_secs(120),
            "no result after the link returned"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    let back = result["back_ms"]
        .as_u64()
        .unwrap()
        .saturating_sub(restored_ms);
    let summary: RecordSummary = serde_json::from_value(result["summary"].clone()).unwrap();
    let before: Seen = serde_json::from_value(result["before_cut"].clone()).unwrap();
    let seen: Seen = serde_json::from_value(result["observer"].clone()).unwrap();
    eprintln!(
        "link cut: noticed after {detection} ms (lease {LEASE_MS} ms); simulator back {back} ms \
         after the link; recorder: {summary:?}; observer before the cut: {} states, {} gaps; \
         in all: {} states, {} gaps",
        before.states, before.gaps, seen.states, seen.gaps
    );
    assert!(
        detection <= 2 * LEASE_MS + 1000,
        "the cut took {detection} ms to notice (lease {LEASE_MS} ms)"
    );
    // Nothing recorded before the cut was lost; the loss during it is reported, not hidden.
    assert_eq!((before.gaps, before.out_of_order), (0, 0));
    assert_eq!(summary.out_of_order, 0);
    assert!(summary.gaps > 0, "the cut must show as a gap: {summary:?}");
    assert_eq!(
        summary.gaps, seen.gaps,
        "recorder and observer disagree on the loss"
    );

    // The dataset parses and every transition in it is exact (no window spans the gap).
    let d = koopman::data::Dataset::load_npz(&dir.join("state/data/cut.npz")).unwrap();
    assert_eq!(d.n, summary.windows);
    assert!(
        d.n as u64 >= (before.states - 1) / 10 - 1,
        "{} windows",
        d.n
    );
    let sys = koopman::systems::by_name("damped-pendulum").unwrap();
    let mut next = vec![0.0; d.nx];
    for i in 0..d.n {
        for t in 0..d.steps {
            sys.step(d.state(i, t), d.input(i, t), &mut next);
            assert_eq!(d.state(i, t + 1), &next[..], "window {i} step {t}");
        }
    }
    drop(procs);
}
