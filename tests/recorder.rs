//! The recorder over Zenoh: a free-running simulator's stream becomes a dataset whose every
//! transition equals a local step of the same system with the recorded input, without gaps.

mod common;

use std::time::Duration;

use bridge::orchestrator::SERVICES_ID;
use bridge::services::recorder::RecordSummary;

#[test]
fn a_free_run_stream_is_recorded_into_exact_windows() {
    let (c, opts, session) = common::cluster("recorder", &[], &["recorder"]);
    let key = c.client.keys.recorder(SERVICES_ID).unwrap();
    let q = |body: serde_json::Value| {
        c.client.query(
            &key,
            serde_json::to_vec(&body).unwrap(),
            Duration::from_secs(30),
            "recorder",
        )
    };
    q(serde_json::json!({"action": "start", "sim": "fr", "window_steps": 15})).unwrap();
    let steps = 300;
    let _sim =
        common::spawn_free_run_pendulum(&c, &opts, &session, "fr", 400, steps, &["--seed", "4"]);
    // The adapter keeps its token while serving; it returns (and exits) after its steps.
    common::wait_until_sim_finished(&c, "fr");
    // Its info is needed for the dataset: restart a lockstep one with the same id to answer it.
    let _info = common::spawn(
        &c,
        &opts,
        "fr-info",
        &[
            "sim",
            "--env",
            "damped-pendulum",
            "--id",
            "fr",
            "--session",
            &session,
        ],
    );
    bridge::client::SimClient::connect(&c.client, "fr", common::READY).unwrap();
    let b = q(serde_json::json!({"action": "stop", "sim": "fr", "name": "rec1"})).unwrap();
    let s: RecordSummary = serde_json::from_slice(&b).unwrap();
    assert_eq!(s.states, steps + 1);
    assert_eq!((s.gaps, s.out_of_order), (0, 0));
    assert_eq!(s.windows, 20);
    let bytes = c
        .client
        .query(
            &c.client.keys.data("rec1").unwrap(),
            vec![],
            Duration::from_secs(30),
            "recorder",
        )
        .unwrap();
    let p = opts.out_dir.join("rec1.npz");
    std::fs::write(&p, bytes).unwrap();
    let d = koopman::data::Dataset::load_npz(&p).unwrap();
    assert_eq!((d.n, d.steps, d.nx, d.nu), (20, 15, 2, 1));
    let sys = koopman::systems::by_name("damped-pendulum").unwrap();
    for i in 0..d.n {
        for t in 0..d.steps {
            let mut next = vec![0.0; 2];
            sys.step(d.state(i, t), d.input(i, t), &mut next);
            assert_eq!(d.state(i, t + 1), &next[..], "window {i} step {t}");
        }
    }
    let mut x0 = vec![0.0; 2];
    x0.copy_from_slice(d.state(0, 0));
    let mut rng = koopman::rng::Rng::new(4);
    assert_eq!(x0, sys.sample_initial_state(&mut rng));
}
