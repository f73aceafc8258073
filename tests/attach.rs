//! MPC `attach` over Zenoh: the MPC service controls a free-running simulator from its state
//! stream, answers every state with a command, and reports the state→command latency histogram;
//! it refuses simulators that are not there, lockstep simulators and references of the wrong
//! length with typed errors, never sends a command outside the simulator's input bounds, and
//! counts bad states instead of dropping them silently.

mod common;

use std::sync::{Arc, Mutex};
use std::time::Duration;

use bridge::codec::CommandMsg;
use bridge::keyexpr::{Role, SimLeaf};
use bridge::orchestrator::{Cluster, SERVICES_ID};
use bridge::services::mpc::AttachStats;
use bridge::zenoh::Wait;
use bridge::ErrorCode;
use koopman::model::arch::Arch;
use koopman::model::koopman::KoopmanModel;

fn query(c: &Cluster, leaf: &str, v: serde_json::Value) -> bridge::Result<Vec<u8>> {
    c.client.query(
        &c.client.keys.under(&["mpc", SERVICES_ID, leaf]),
        serde_json::to_vec(&v).unwrap(),
        Duration::from_secs(60),
        "mpc",
    )
}

fn code(r: bridge::Result<Vec<u8>>) -> Option<ErrorCode> {
    match r {
        Err(bridge::Error::Remote { reply, .. }) => Some(reply.code),
        _ => None,
    }
}

fn attach(c: &Cluster, sim: &str, reference: serde_json::Value) -> bridge::Result<Vec<u8>> {
    query(
        c,
        "attach",
        serde_json::json!({"sim": sim, "model": "m", "reference": reference}),
    )
}

fn detach(c: &Cluster, sim: &str) -> AttachStats {
    let b = query(c, "attach", serde_json::json!({"sim": sim, "detach": true})).unwrap();
    serde_json::from_slice(&b).unwrap()
}

fn model() -> KoopmanModel {
    KoopmanModel::init(Arch::new(2, 1, &[32], 4).unwrap(), 3).unwrap()
}

#[test]
fn attached_mpc_answers_every_state_of_a_free_running_simulator() {
    let (opts, session) = common::options("attach");
    model().save(&opts.out_dir.join("models/m")).unwrap();
    let c = Cluster::start(&opts, &session, &[], &["mpc"]).unwrap();
    let cfg = koopman::mpc::MpcConfig::with_bounds(vec![-8.0], vec![8.0]);
    query(
        &c,
        "configure",
        serde_json::json!({"model": "m", "mpc": cfg}),
    )
    .unwrap();
    let steps = 400;
    // The simulator waits for a subscriber of its states (the MPC, once attached).
    let sim = common::spawn_free_run_pendulum(&c, &opts, &session, "fr", 100, steps, &[]);
    c.live
        .wait_for(&[(Role::Sim, "fr".into())], common::READY)
        .unwrap();
    attach(&c, "fr", serde_json::json!([0.0, 0.0])).unwrap();
    // Attaching twice is refused with `busy`.
    let again = attach(&c, "fr", serde_json::json!([0.0, 0.0]));
    assert_eq!(code(again), Some(ErrorCode::Busy));
    common::wait_until_sim_finished(&c, "fr");
    std::thread::sleep(Duration::from_millis(300));
    let s = detach(&c, "fr");
    assert_eq!(s.gaps, 0);
    assert_eq!(s.states, steps + 1, "the MPC missed states");
    assert_eq!(
        (
            s.bad_states,
            s.solve_errors,
            s.publish_errors,
            &s.last_error
        ),
        (0, 0, 0, &None)
    );
    assert_eq!(s.commands + s.skipped, s.states);
    // Only the newest queued state is answered: some are skipped when this process is not
    // scheduled for a period (a loaded machine); the same bound as the adapter's below.
    assert!(
        s.skipped < steps / 4,
        "{} states skipped at 100 Hz",
        s.skipped
    );
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

/// Issue 15: `attach` accepted a simulator that does not exist, a lockstep simulator and a
/// reference of the wrong length, and without `configure` it ignored the simulator's bounds.
#[test]
fn attach_checks_the_simulator_and_keeps_its_bounds() {
    let (opts, session) = common::options("attach-safe");
    let m = model();
    m.save(&opts.out_dir.join("models/m")).unwrap();
    let c = Cluster::start(
        &opts,
        &session,
        &[("ls".into(), "damped-pendulum".into())],
        &["mpc"],
    )
    .unwrap();
    let t = std::time::Instant::now();
    assert_eq!(
        code(attach(&c, "nosuch", serde_json::json!([0.0, 0.0]))),
        Some(ErrorCode::NotFound)
    );
    assert!(t.elapsed() < Duration::from_secs(10), "{:?}", t.elapsed());
    assert_eq!(
        code(attach(&c, "ls", serde_json::json!([0.0, 0.0]))),
        Some(ErrorCode::Busy),
        "a lockstep simulator was attached"
    );
    let steps = 300;
    let _sim = common::spawn_free_run_pendulum(&c, &opts, &session, "fr", 100, steps, &[]);
    c.live
        .wait_for(&[(Role::Sim, "fr".into())], common::READY)
        .unwrap();
    assert_eq!(
        code(attach(&c, "fr", serde_json::json!([0.0, 0.0, 0.0]))),
        Some(ErrorCode::Dimension)
    );
    // Without `configure` the SPEC defaults have no bounds: towards a far reference this
    // untrained model asks for more than the simulator's ±8 (checked locally), and the MPC
    // must not send it.
    let far = serde_json::json!([40.0, 0.0]);
    let mut free = koopman::mpc::MpcController::new(&m, &Default::default()).unwrap();
    let wants = free.solve(&[0.0, 0.0], &[40.0, 0.0]).unwrap().u[0];
    assert!(
        wants.abs() > 8.0,
        "the unbounded plan is within the bounds: {wants}"
    );
    let sent = Arc::new(Mutex::new(Vec::new()));
    let s2 = sent.clone();
    let cmd_key = c.client.keys.sim("fr", SimLeaf::Command).unwrap();
    let _spy = c
        .client
        .session
        .declare_subscriber(&cmd_key)
        .callback(move |s| {
            if let Ok(m) = CommandMsg::decode(&s.payload().to_bytes()) {
                s2.lock().unwrap().push(m.u[0]);
            }
        })
        .wait()
        .unwrap();
    attach(&c, "fr", far).unwrap();
    // States that are not states are counted, not dropped silently.
    let state_key = c.client.keys.sim("fr", SimLeaf::State).unwrap();
    for _ in 0..3 {
        c.client
            .session
            .put(&state_key, vec![1u8, 2, 3])
            .wait()
            .unwrap();
    }
    common::wait_until_sim_finished(&c, "fr");
    std::thread::sleep(Duration::from_millis(300));
    let s = detach(&c, "fr");
    assert_eq!(s.bad_states, 3, "{s:?}");
    assert!(
        s.last_error
            .as_deref()
            .unwrap_or("")
            .contains("undecodable"),
        "{s:?}"
    );
    assert_eq!(
        s.commands + s.skipped + s.bad_states + s.solve_errors + s.publish_errors,
        s.states
    );
    let u = sent.lock().unwrap().clone();
    assert!(
        u.len() as u64 >= s.commands / 2,
        "{} commands seen of {}",
        u.len(),
        s.commands
    );
    let max = u.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    assert!(
        max <= 8.0 + 1e-9,
        "a command of {max} was sent to a ±8 simulator"
    );
}
