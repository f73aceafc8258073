//! Free-run over Zenoh: the state stream arrives complete and in order, commands are applied
//! (zero-order hold, reported back in the state messages), and the adapter's counters add up.

mod common;

use std::time::{Duration, Instant};

use bridge::codec::{CommandMsg, StateMsg};
use bridge::keyexpr::SimLeaf;
use bridge::orchestrator::Cluster;
use bridge::zenoh::pubsub::{Publisher, Subscriber};
use bridge::zenoh::Wait;
use std::sync::mpsc::Receiver;

#[test]
fn state_stream_is_ordered_without_gaps_and_commands_are_applied() {
    let (c, opts, session) = common::cluster("freerun", &[], &[]);
    let (_sub, rx, publisher) = state_feed_and_commands(&c, "fr");
    let steps = 1500u64;
    let child = common::spawn_free_run_pendulum(&c, &opts, &session, "fr", 500, steps, &[]);
    let mut states: Vec<StateMsg> = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(120);
    let mut seq = 0;
    while Instant::now() < deadline {
        let Ok(b) = rx.recv_timeout(Duration::from_millis(500)) else {
            continue;
        };
        let s = StateMsg::decode(&b).unwrap();
        let k = s.k;
        // Answer every state with u = k / 1000 (so the applied input tells which command it was).
        let cmd = CommandMsg {
            seq,
            k,
            u: vec![k as f64 / 1000.0],
        };
        seq += 1;
        publisher.put(cmd.encode()).wait().unwrap();
        states.push(s);
        if k >= steps {
            break;
        }
    }
    assert!(!states.is_empty(), "no state received");
    assert_eq!(states.last().unwrap().k, steps, "stream ended early");
    // The adapter waited for our subscriber: nothing was lost at the start either.
    assert_eq!(
        (states[0].seq, states[0].k),
        (0, 0),
        "the start of the stream was missed"
    );
    // Ordering and completeness from the first received state on.
    for w in states.windows(2) {
        assert_eq!(
            w[1].seq,
            w[0].seq + 1,
            "sequence gap or reordering at seq {}",
            w[0].seq
        );
        assert_eq!(w[1].k, w[0].k + 1);
        assert!((w[1].t - w[1].k as f64 * 0.02).abs() < 1e-9);
    }
    // Zero-order hold: every applied input is one of ours (k'/1000 for a k' ≤ k−1) or zero
    // before our first command arrived; and most commands arrive in time at 500 Hz.
    let mut answered_in_time = 0;
    for s in &states[1..] {
        let u = s.u[0];
        let kk = (u * 1000.0).round() as i64;
        assert!(
            (u * 1000.0 - kk as f64).abs() < 1e-9 && kk < s.k as i64,
            "state k={} was driven by u={u}",
            s.k
        );
        if kk == s.k as i64 - 1 {
            answered_in_time += 1;
        }
    }
    assert!(
        answered_in_time * 2 > states.len(),
        "only {answered_in_time} of {} commands in time",
        states.len()
    );
    drop(child);
}

/// A free-running adapter never applies a command outside its input bounds (±8 for the damped
/// pendulum): a command of ±61 is applied as ±8, reported so in the state stream, and counted in
/// `info.stats.clipped_commands`.
#[test]
fn commands_outside_the_bounds_are_clipped_and_counted() {
    let (c, opts, session) = common::cluster("freerun-clip", &[], &[]);
    let (_sub, rx, publisher) = state_feed_and_commands(&c, "clip");
    let steps = 2000u64;
    let child = common::spawn_free_run_pendulum(&c, &opts, &session, "clip", 200, steps, &[]);
    let (mut sent, mut driven) = (0u64, 0u64);
    let deadline = Instant::now() + Duration::from_secs(120);
    let info = loop {
        assert!(Instant::now() < deadline, "too few states");
        let Ok(b) = rx.recv_timeout(Duration::from_millis(500)) else {
            continue;
        };
        let s = StateMsg::decode(&b).unwrap();
        assert!(
            s.u.iter().all(|u| u.abs() <= 8.0),
            "state k={} applied u={:?}",
            s.k,
            s.u
        );
        if s.u.first().is_some_and(|u| u.abs() == 8.0) {
            driven += 1;
        }
        let u = if s.k % 2 == 0 { 61.0 } else { -61.0 };
        let cmd = CommandMsg {
            seq: sent,
            k: s.k,
            u: vec![u],
        };
        publisher.put(cmd.encode()).wait().unwrap();
        sent += 1;
        if s.k == 200 {
            let b = c
                .client
                .query(
                    &c.client.keys.sim("clip", SimLeaf::Info).unwrap(),
                    vec![],
                    Duration::from_secs(30),
                    "simulator clip",
                )
                .unwrap();
            break serde_json::from_slice::<bridge::adapter::InfoReply>(&b).unwrap();
        }
    };
    assert!(
        driven > 100,
        "only {driven} states were driven by a clipped command"
    );
    let clipped = info.stats.clipped_commands;
    // Every command the adapter received was out of bounds (most of those sent arrive at 200 Hz).
    assert!(
        clipped * 2 > sent && clipped <= sent,
        "clipped {clipped}, driven {driven}, sent {sent}"
    );
    drop(child);
}

/// Subscribes to simulator `id`'s state stream (the receiver gets each encoded message) and
/// declares the publisher of its commands.
fn state_feed_and_commands(
    c: &Cluster,
    id: &str,
) -> (Subscriber<()>, Receiver<Vec<u8>>, Publisher<'static>) {
    let (tx, rx) = std::sync::mpsc::channel::<Vec<u8>>();
    let sub = c
        .client
        .session
        .declare_subscriber(c.client.keys.sim(id, SimLeaf::State).unwrap())
        .callback(move |s| {
            let _ = tx.send(s.payload().to_bytes().into_owned());
        })
        .wait()
        .unwrap();
    let publisher = c
        .client
        .session
        .declare_publisher(c.client.keys.sim(id, SimLeaf::Command).unwrap())
        .wait()
        .unwrap();
    (sub, rx, publisher)
}
