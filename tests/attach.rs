//! MPC `attach` over Zenoh: the MPC service controls a free-running simulator from its state
//! stream, answers every state with a command, and reports the state→command latency histogram.

mod common;

use std::time::Duration;

use bridge::orchestrator::{Cluster, SERVICES_ID};
use bridge::services::mpc::AttachStats;
use koopman::model::arch::Arch;
use koopman::model::koopman::KoopmanModel;

#[test]
fn attached_mpc_answers_every_state_of_a_free_running_simulator() {
    let (opts, session) = common::options("attach");
    KoopmanModel::init(Arch::new(2, 1, &[32], 4).unwrap(), 3)
        .unwrap()
        .save(&opts.out_dir.join("models/m"))
        .unwrap();
    let c = Cluster::start(&opts, &session, &[], &["mpc"]).unwrap();
    let base = |leaf: &str| c.client.keys.under(&["mpc", SERVICES_ID, leaf]);
    let q = |leaf: &str, v: serde_json::Value| {
        c.client.query(
            &base(leaf),
            serde_json::to_vec(&v).unwrap(),
            Duration::from_secs(60),
            "mpc",
        )
    };
    let cfg = koopman::mpc::MpcConfig::with_bounds(vec![-8.0], vec![8.0]);
    q("configure", serde_json::json!({"model": "m", "mpc": cfg})).unwrap();
    q(
        "attach",
        serde_json::json!({"sim": "fr", "model": "m", "reference": [0.0, 0.0]}),
    )
    .unwrap();
    // Attaching twice is refused with `busy`.
    let again = q(
        "attach",
        serde_json::json!({"sim": "fr", "model": "m", "reference": [0.0, 0.0]}),
    );
    assert!(
        matches!(again, Err(bridge::Error::Remote { ref reply, .. }) if reply.code == bridge::ErrorCode::Busy)
    );
    let steps = 400;
    let sim = common::spawn_free_run_pendulum(&c, &opts, &session, "fr", 100, steps, &[]);
    common::wait_until_sim_finished(&c, "fr");
    std::thread::sleep(Duration::from_millis(300));
    let b = q("attach", serde_json::json!({"sim": "fr", "detach": true})).unwrap();
    let s: AttachStats = serde_json::from_slice(&b).unwrap();
    assert_eq!(s.gaps, 0);
    assert_eq!(s.states, steps + 1, "the MPC missed states");
    assert_eq!(s.commands, s.states);
    assert_eq!(s.latency_counts.iter().sum::<u64>(), s.commands);
    assert!(s.latency_median_us > 0.0 && s.latency_median_us <= s.latency_p99_us);
    // The adapter's own counters (printed as its last line): commands arrived and were applied.
    let log = std::fs::read_to_string(&sim.log).unwrap();
    let stats: serde_json::Value = log
        .lines()
        .rev()
        .find_map(|l| serde_json::from_str(l).ok())
        .unwrap();
    assert_eq!(stats["steps"], steps);
    let missing =
        stats["missing_commands"].as_u64().unwrap() + stats["late_commands"].as_u64().unwrap();
    assert!(
        missing < steps / 4,
        "too many late/missing commands at 100 Hz: {stats}"
    );
}
