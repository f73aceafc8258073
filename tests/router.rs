//! A run through a node in router mode: the simulator and this test are Zenoh clients of a
//! `koopbridge` process started with `--mode router`; nothing connects peer to peer.

mod common;

use std::time::Duration;

use bridge::client::{Client, Liveliness, SimClient};
use bridge::keyexpr::{fresh_session_id, Keys};
use bridge::messages::ResetRequest;
use bridge::procs::ChildProc;
use bridge::session::{free_loopback_endpoint, open_session, Mode, ZenohOptions};

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
    // Connecting as a client retries until the router listens.
    let z = ZenohOptions {
        connect: vec![ep.clone()],
        mode: Some(Mode::Client),
        ..Default::default()
    };
    let mut session_handle = None;
    for _ in 0..100 {
        match open_session(&z) {
            Ok(s) => {
                session_handle = Some(s);
                break;
            }
            Err(_) => std::thread::sleep(Duration::from_millis(200)),
        }
    }
    let client = Client::new(
        session_handle.expect("could not reach the router"),
        Keys::new(&session).unwrap(),
    );
    let live = Liveliness::new(&client).unwrap();
    // The router is up (we reached it): now the simulator, also a client.
    let _sim = ChildProc::spawn(
        "sim",
        &common::exe(),
        &s(&[
            "sim",
            "--env",
            "damped-pendulum",
            "--id",
            "viarouter",
            "--session",
            &session,
            "--mode",
            "client",
            "--connect",
            &ep,
            "--stdin-lifeline",
        ]),
        &dir.join("sim.log"),
    )
    .unwrap();
    live.wait_for(
        &[(bridge::keyexpr::Role::Sim, "viarouter".into())],
        common::READY,
    )
    .unwrap();
    let mut sim = SimClient::connect(&client, "viarouter", common::READY).unwrap();
    sim.reset(&ResetRequest {
        seed: Some(9),
        x0: None,
    })
    .unwrap();
    for k in 0..10 {
        assert_eq!(sim.step(&[1.0], Some(&live)).unwrap().k, k + 1);
    }
}
