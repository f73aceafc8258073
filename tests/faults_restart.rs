//! Faults, continued (issue 13 §3): the router between two client-mode peers killed with
//! SIGKILL is noticed within 1 s and the peers reconnect to a new one; a scenario whose
//! orchestrator is killed continues when run again into the same folder.

mod common;

use std::path::Path;
use std::time::{Duration, Instant};

use bridge::client::{Client, Liveliness, SimClient};
use bridge::error::Error;
use bridge::keyexpr::{fresh_session_id, Keys, Role};
use bridge::messages::ResetRequest;
use bridge::procs::ChildProc;
use bridge::session::free_loopback_endpoint;
use common::faults::{first_error, local_states, nothing_half_written, DETECT};

#[test]
fn a_killed_router_between_client_peers_is_detected_within_1s_and_they_reconnect() {
    let dir = common::scratch("fault-router");
    let session = fresh_session_id();
    let ep = free_loopback_endpoint().unwrap();
    let router = |n: u32| {
        ChildProc::spawn(
            "router",
            &common::exe(),
            &["router", "--listen", &ep, "--stdin-lifeline"].map(String::from),
            &dir.join(format!("router-{n}.log")),
        )
        .unwrap()
    };
    let mut r1 = router(1);
    let client = Client::new(common::connect_client(&ep), Keys::new(&session).unwrap());
    let live = Liveliness::new(&client).unwrap();
    let _sim = common::spawn_client_sim(&dir, "far", &session, &ep);
    live.wait_for(&[(Role::Sim, "far".into())], common::READY)
        .unwrap();
    let mut sim = SimClient::connect(&client, "far", common::READY).unwrap();
    sim.reset(&ResetRequest {
        seed: None,
        x0: Some(vec![0.2, 0.0]),
        perturbation: None,
    })
    .unwrap();
    let expect = local_states(&[0.2, 0.0], &[0.3; 6]);
    for x in &expect[1..4] {
        assert_eq!(&sim.step(&[0.3], Some(&live)).unwrap().x, x);
    }
    common::sigkill(r1.id());
    let killed = Instant::now();
    let (err, took) = first_error(killed, Duration::from_secs(10), || {
        sim.step(&[0.3], Some(&live))
    });
    eprintln!("router killed: the step failed after {took:?}: {err}");
    assert!(
        matches!(&err, Error::Gone(w) if w.contains("'far'"))
            || matches!(&err, Error::Timeout { who, .. } if who.contains("'far'")),
        "{err}"
    );
    assert!(took < DETECT, "took {took:?} to notice the lost router");
    r1.kill();

    // The router again on the same endpoint: both clients reconnect on their own, and the
    // simulator kept its state (k = 3), so the run continues where it stopped.
    let _r2 = router(2);
    let back = Instant::now();
    live.wait_for(&[(Role::Sim, "far".into())], Duration::from_secs(60))
        .unwrap();
    let mut sim = SimClient::connect(&client, "far", common::READY).unwrap();
    eprintln!(
        "router restarted: the simulator was back after {:?}",
        back.elapsed()
    );
    assert_eq!(sim.k, 3);
    for x in &expect[4..] {
        assert_eq!(&sim.step(&[0.3], Some(&live)).unwrap().x, x);
    }
}

/// A tiny collect + train scenario whose training lasts seconds (killed in the middle).
/// 20,000 iterations (~7 s on 2 quiet cores): long enough that the kill lands mid-training on a
/// loaded machine too (with 1,500, ~0.5 s, a CI run finished the training before the kill: the
/// finished job's checkpoint is removed and the rerun rightly trains afresh).
const SCENARIO: &str = r#"
name = "killed"
[[sims]]
id = "pend"
env = "damped-pendulum"
[collect]
policy = { kind = "uniform" }
train_windows = 120
val_windows = 20
test_windows = 20
steps = 15
seed = 5
[train]
config = { iterations = 20000, hidden = [32, 32], n_mult = 4, batch = 64, validate_every = 100 }
[control]
x0 = [-1.0, 0.1]
reference = [0.0, 0.0]
steps = 5
"#;

#[test]
fn a_scenario_whose_orchestrator_is_killed_continues_when_run_again() {
    let dir = common::scratch("fault-run");
    let sc = dir.join("killed.toml");
    std::fs::write(&sc, SCENARIO).unwrap();
    let out = dir.join("out");
    let args = ["run", sc.to_str().unwrap(), "--out", out.to_str().unwrap()];
    let mut run = std::process::Command::new(common::exe())
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let jobs = out.join("state/trainer/jobs");
    let deadline = Instant::now() + common::READY;
    while !std::fs::read_dir(&jobs).is_ok_and(|d| {
        d.flatten()
            .any(|e| e.path().extension().is_some_and(|x| x == "ckpt"))
    }) {
        assert!(run.try_wait().unwrap().is_none(), "the run ended early");
        assert!(Instant::now() < deadline, "training never checkpointed");
        std::thread::sleep(Duration::from_millis(5));
    }
    let children = common::children_of(run.id());
    assert_eq!(children.len(), 2, "a simulator and the services");
    common::sigkill(run.id());
    run.wait().unwrap();
    // Its children follow it (their lifeline closed); what it left is whole.
    let t = Instant::now();
    while children.iter().any(|&p| common::running(p)) {
        assert!(
            t.elapsed() < Duration::from_secs(10),
            "the children outlived the run"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    nothing_half_written(&out);
    let collected: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("data/collect.json")).unwrap()).unwrap();
    for f in collected["report"]["files"].as_array().unwrap() {
        koopman::data::Dataset::load_npz(Path::new(f.as_str().unwrap())).unwrap();
    }
    assert!(!out.join("report.json").exists());

    // The same command again: collection reused, the job resumed, the run completes.
    let o = std::process::Command::new(common::exe())
        .args(args)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "the rerun failed:\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(r["collect"]["reused"], true, "{r}");
    assert!(
        r["train"][0]["metrics"]["resumed_from"].as_u64().unwrap() >= 100,
        "{r}"
    );
    assert_eq!(r["control"]["x"].as_array().unwrap().len(), 6);
    nothing_half_written(&out);
}
