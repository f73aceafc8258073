//! Presence over liveliness tokens: a simulator killed mid-run is named within a second and the
//! orchestrator does not hang; a peer that joins late is found and stepped.

mod common;

use std::time::{Duration, Instant};

use bridge::client::SimClient;
use bridge::error::Error;
use bridge::keyexpr::Role;
use bridge::messages::ResetRequest;

#[test]
fn a_killed_simulator_is_named_within_one_second() {
    let (mut c, _opts, _s) = common::cluster(
        "killed",
        &[("victim", "damped-pendulum"), ("other", "polynomial")],
        &[],
    );
    let mut sim = SimClient::connect(&c.client, "victim", common::READY).unwrap();
    sim.timeout = Duration::from_secs(30);
    sim.reset(&ResetRequest::default()).unwrap();
    for _ in 0..5 {
        sim.step(&[0.0], Some(&c.live)).unwrap();
    }
    let victim = c
        .children
        .iter_mut()
        .find(|ch| ch.name.contains("victim"))
        .unwrap();
    victim.kill();
    let killed_at = Instant::now();
    let err = loop {
        match sim.step(&[0.0], Some(&c.live)) {
            Ok(_) => assert!(
                killed_at.elapsed() < Duration::from_secs(5),
                "the dead simulator kept answering"
            ),
            Err(e) => break e,
        }
    };
    let took = killed_at.elapsed();
    match &err {
        Error::Gone(who) => assert!(who.contains("victim"), "{err}"),
        other => panic!("expected Gone naming the simulator, got {other}"),
    }
    assert!(
        took < Duration::from_secs(1),
        "took {took:?} (> 1 s) to notice the dead simulator"
    );
    assert!(c.live.is_gone(Role::Sim, "victim"));
    assert!(c.live.is_alive(Role::Sim, "other"));
}

#[test]
fn a_late_joining_peer_is_found_and_stepped() {
    let (c, opts, session) = common::cluster("late", &[("early", "damped-pendulum")], &[]);
    SimClient::connect(&c.client, "early", common::READY).unwrap();
    std::thread::sleep(Duration::from_millis(500));
    let _late = common::spawn(
        &c,
        &opts,
        "late",
        &[
            "sim",
            "--env",
            "polynomial",
            "--id",
            "late",
            "--session",
            &session,
        ],
    );
    c.live
        .wait_for(&[(Role::Sim, "late".into())], common::READY)
        .unwrap();
    let mut sim = SimClient::connect(&c.client, "late", common::READY).unwrap();
    assert_eq!(sim.info.sim.env, "polynomial");
    sim.reset(&ResetRequest {
        seed: Some(3),
        x0: None,
        perturbation: None,
    })
    .unwrap();
    let r = sim.step(&[], Some(&c.live)).unwrap();
    assert_eq!(r.k, 1);
}
