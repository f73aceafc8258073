//! Runs through a router: the simulator and this test are Zenoh clients of a `koopbridge`
//! process started with `--mode router` or of `koopbridge router`; nothing connects peer to
//! peer. And a `--zenoh-config` file's mode is not overwritten by a `--mode` not given.

mod common;

use std::time::Duration;

use bridge::client::{Client, Liveliness, SimClient};
use bridge::keyexpr::{fresh_session_id, Keys};
use bridge::messages::ResetRequest;
use bridge::procs::ChildProc;
use bridge::session::free_loopback_endpoint;

#[test]
fn lockstep_through_a_router() {
    let dir = common::scratch("router");
    let session = fresh_session_id();
    let ep = free_loopback_endpoint().unwrap();
    let s = |v: &[&str]| v.iter().map(|x| x.to_string()).collect::<Vec<_>>();
    // The router: a model store process in router mode (any koopbridge command can be one).
    let _router = ChildProc::spawn(
        "router",
        &common::exe(),
        &s(&[
            "serve",
            "models",
            "--session",
            &session,
            "--store",
            dir.join("models").to_str().unwrap(),
            "--state-dir",
            dir.join("state").to_str().unwrap(),
            "--mode",
            "router",
            "--listen",
            &ep,
            "--stdin-lifeline",
        ]),
        &dir.join("router.log"),
    )
    .unwrap();
    let client = Client::new(common::connect_client(&ep), Keys::new(&session).unwrap());
    let live = Liveliness::new(&client).unwrap();
    // The router is up (we reached it): now the simulator, also a client.
    let _sim = common::spawn_client_sim(&dir, "viarouter", &session, &ep);
    step_through(&client, &live, "viarouter", 9, 1.0, 10);
}

/// `koopbridge router` is a plain router: a simulator and this test, both Zenoh clients of it,
/// run a lockstep exchange through it.
#[test]
fn the_router_command_carries_a_lockstep_run() {
    let dir = common::scratch("router-cmd");
    let session = fresh_session_id();
    let ep = free_loopback_endpoint().unwrap();
    let s = |v: &[&str]| v.iter().map(|x| x.to_string()).collect::<Vec<_>>();
    let _router = ChildProc::spawn(
        "router",
        &common::exe(),
        &s(&["router", "--listen", &ep, "--stdin-lifeline"]),
        &dir.join("router.log"),
    )
    .unwrap();
    let client = Client::new(common::connect_client(&ep), Keys::new(&session).unwrap());
    let live = Liveliness::new(&client).unwrap();
    let _sim = common::spawn_client_sim(&dir, "r2", &session, &ep);
    step_through(&client, &live, "r2", 3, 0.5, 5);
    // It says where it listens (once its session is open, which may be after it routes).
    let deadline = std::time::Instant::now() + Duration::from_secs(30);
    let log = loop {
        let log = std::fs::read_to_string(dir.join("router.log")).unwrap();
        if log.contains("listening on") || std::time::Instant::now() > deadline {
            break log;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(log.contains(&format!("listening on [\"{ep}\"]")), "{log}");
}

/// A `--zenoh-config` file's `mode` is kept when `--mode` is not given (it used to be
/// overwritten by the flag's default, `peer`): a file that makes the simulator a client of a
/// router that is not there ends it at once with an error, where a peer would have kept running.
#[test]
fn a_config_files_mode_is_not_overwritten_by_an_absent_flag() {
    let dir = common::scratch("zcfg-mode");
    let dead = free_loopback_endpoint().unwrap();
    let cfg = dir.join("client.json5");
    std::fs::write(
        &cfg,
        format!("{{ mode: \"client\", connect: {{ endpoints: [\"{dead}\"] }} }}"),
    )
    .unwrap();
    let mut sim = ChildProc::spawn(
        "sim",
        &common::exe(),
        &[
            "sim",
            "--id",
            "c",
            "--zenoh-config",
            cfg.to_str().unwrap(),
            "--stdin-lifeline",
        ]
        .map(String::from),
        &dir.join("sim.log"),
    )
    .unwrap();
    let deadline = std::time::Instant::now() + Duration::from_secs(60);
    let msg = loop {
        if let Some(m) = sim.exited() {
            break m;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "the simulator kept running: it ignored the file's client mode"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(msg.contains("cannot open session"), "{msg}");
}

/// Waits for simulator `id`, resets it with `seed` and steps it `n` times with input `u`,
/// checking each reply's step counter.
fn step_through(client: &Client, live: &Liveliness, id: &str, seed: u64, u: f64, n: u64) {
    live.wait_for(&[(bridge::keyexpr::Role::Sim, id.into())], common::READY)
        .unwrap();
    let mut sim = SimClient::connect(client, id, common::READY).unwrap();
    sim.reset(&ResetRequest {
        seed: Some(seed),
        x0: None,
        perturbation: None,
    })
    .unwrap();
    for k in 0..n {
        assert_eq!(sim.step(&[u], Some(live)).unwrap().k, k + 1);
    }
}
