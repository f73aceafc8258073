//! Lockstep over Zenoh between separate processes: step query/reply against a local computation,
//! idempotent retries answered from cache, typed errors for bad payloads, repeatability.

mod common;

use std::time::Duration;

use bridge::client::{step_all, SimClient};
use bridge::codec::{StepReply, StepRequest};
use bridge::collect::{collect, window_seed, CollectJob, Split};
use bridge::error::{Error, ErrorCode};
use bridge::keyexpr::SimLeaf;
use bridge::messages::ResetRequest;
use bridge::scenario::Policy;

fn remote_code(r: bridge::Result<Vec<u8>>) -> ErrorCode {
    match r {
        Err(Error::Remote { reply, .. }) => reply.code,
        other => panic!("expected a typed error reply, got {other:?}"),
    }
}

#[test]
fn steps_match_a_local_integration_and_retries_hit_the_cache() {
    let (c, _opts, _s) = common::cluster("lockstep", &[("pend", "damped-pendulum")], &[]);
    let mut sim = SimClient::connect(&c.client, "pend", common::READY).unwrap();
    assert_eq!(sim.info.sim.nx(), 2);
    assert_eq!(sim.info.protocol_version, bridge::codec::PROTOCOL_VERSION);
    let x0 = sim
        .reset(&ResetRequest {
            seed: None,
            x0: Some(vec![0.3, -0.2]),
            perturbation: None,
        })
        .unwrap();
    assert_eq!((x0.k, x0.x.clone()), (0, vec![0.3, -0.2]));

    // Independent computation: the same system stepped in this process.
    let sys = koopman::systems::by_name("damped-pendulum").unwrap();
    let mut x = vec![0.3, -0.2];
    for k in 0..20 {
        let u = [((k as f64) * 0.7).sin() * 5.0];
        let r = sim.step(&u, Some(&c.live)).unwrap();
        let mut next = vec![0.0; 2];
        sys.step(&x, &u, &mut next);
        assert_eq!(r.x, next, "state after step {k} differs from a local step");
        assert_eq!(r.k, k + 1);
        assert!((r.t - (k + 1) as f64 * sys.dt()).abs() < 1e-12);
        x = next;
    }

    // A duplicated request for the last step (same k, same u) is answered from the cache.
    let key = c.client.keys.sim("pend", SimLeaf::Step).unwrap();
    let u_last = [((19f64) * 0.7).sin() * 5.0];
    let dup = StepRequest {
        k: 19,
        u: u_last.to_vec(),
    }
    .encode();
    let again = c
        .client
        .query(&key, dup, Duration::from_secs(20), "pend")
        .unwrap();
    let again = StepReply::decode(&again).unwrap();
    assert_eq!((again.k, again.x.clone()), (20, x.clone()));
    let info = sim.refresh_info().unwrap().clone();
    assert_eq!(
        info.stats.steps, 20,
        "a duplicated request stepped the simulator again"
    );
    assert_eq!(info.stats.cache_hits, 1);
    assert_eq!(info.k, 20);
    // Same k with another input: conflict. A k from the future: out_of_order.
    let q = |b: Vec<u8>| c.client.query(&key, b, Duration::from_secs(20), "pend");
    assert_eq!(
        remote_code(q(StepRequest {
            k: 19,
            u: vec![0.0]
        }
        .encode())),
        ErrorCode::Conflict
    );
    assert_eq!(
        remote_code(q(StepRequest {
            k: 25,
            u: vec![0.0]
        }
        .encode())),
        ErrorCode::OutOfOrder
    );
    // Malformed and oversized payloads: typed errors, and the adapter keeps serving.
    assert_eq!(remote_code(q(b"garbage".to_vec())), ErrorCode::BadRequest);
    let mut v = StepRequest {
        k: 20,
        u: vec![0.0],
    }
    .encode();
    v[2] = 7;
    assert_eq!(remote_code(q(v)), ErrorCode::VersionMismatch);
    assert_eq!(
        remote_code(q(StepRequest {
            k: 20,
            u: vec![0.0, 1.0]
        }
        .encode())),
        ErrorCode::Dimension
    );
    assert_eq!(
        remote_code(q(StepRequest {
            k: 20,
            u: vec![f64::NAN]
        }
        .encode())),
        ErrorCode::BadRequest
    );
    assert_eq!(remote_code(q(vec![0u8; 2 << 20])), ErrorCode::TooLarge);
    let reset_key = c.client.keys.sim("pend", SimLeaf::Reset).unwrap();
    let rq = |b: &[u8]| {
        c.client
            .query(&reset_key, b.to_vec(), Duration::from_secs(20), "pend")
    };
    assert_eq!(remote_code(rq(b"{not json")), ErrorCode::BadRequest);
    assert_eq!(remote_code(rq(br#"{"x0":[1.0]}"#)), ErrorCode::Dimension);
    assert_eq!(remote_code(rq(br#"{"bogus":1}"#)), ErrorCode::BadRequest);
    let r = sim.step(&[1.0], Some(&c.live)).unwrap();
    assert_eq!(r.k, 21);
}

#[test]
fn collection_is_bit_for_bit_repeatable_and_equals_local_stepping() {
    let (c, _opts, _s) = common::cluster(
        "repeat",
        &[("a", "damped-pendulum"), ("b", "double-pendulum")],
        &[],
    );
    let mut sims = vec![
        SimClient::connect(&c.client, "a", common::READY).unwrap(),
        SimClient::connect(&c.client, "b", common::READY).unwrap(),
    ];
    let job = CollectJob {
        policy: &Policy::uniform(),
        windows: 6,
        steps: 5,
        seed: 42,
        split: Split::Train,
        x0_box: None,
    };
    let run = |sims: &mut [SimClient]| collect(sims, &job, Some(&c.live), &mut |_, _| {}).unwrap();
    let first = run(&mut sims);
    let second = run(&mut sims);
    assert_eq!(
        first, second,
        "two lockstep collections with the same seed differ"
    );
    assert_eq!(first[1].nx, 4);
    assert_eq!(first[1].nu, 2);
    // Local recomputation of window 3 of simulator b from its seed and inputs.
    let sys = koopman::systems::by_name("double-pendulum").unwrap();
    let d = &first[1];
    let mut rng = koopman::rng::Rng::new(window_seed(42, Split::Train, 1, 3));
    let mut x = sys.sample_initial_state(&mut rng);
    assert_eq!(d.state(3, 0), &x[..]);
    for t in 0..5 {
        let u = d.input(3, t);
        let (lo, hi) = sys.input_bounds();
        assert!(u
            .iter()
            .zip(lo.iter().zip(&hi))
            .all(|(v, (l, h))| v >= l && v < h));
        let mut next = vec![0.0; 4];
        sys.step(&x, u, &mut next);
        assert_eq!(d.state(3, t + 1), &next[..]);
        x = next;
    }
    // Concurrent stepping of both simulators in one macro step.
    let r = step_all(&mut sims, &[vec![0.0], vec![0.0, 0.0]], Some(&c.live)).unwrap();
    assert_eq!(r.len(), 2);
}
