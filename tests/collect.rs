//! The `collect` request between separate processes over real Zenoh: a `koopbridge sim` runs
//! blocks of windows in its own process; the same request gives the same bytes, a collection
//! resumes at any block, the windows are the system's own transitions, bad requests get typed
//! errors while the adapter keeps serving; and `koopbridge run` collects through it with
//! `policy = { kind = "adapter" }`.

mod common;

use std::time::Duration;

use bridge::adapter::collect::CollectPlan;
use bridge::adapter::{run_windows, window_rng, SimBackend, SystemBackend};
use bridge::client::SimClient;
use bridge::collect::blocks::{collect_block, collect_blocks, Block, Collection};
use bridge::collect::{adapter_seed, Split};
use bridge::error::{Error, ErrorCode};
use bridge::keyexpr::SimLeaf;
use bridge::messages::{CollectPolicy, CollectRequest, InputBound, ResetRequest};
use koopman::rng::Rng;

const T: Duration = Duration::from_secs(60);

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn same(a: &Block, b: &Block) -> bool {
    (a.block, a.first, a.windows) == (b.block, b.first, b.windows)
        && bits(&a.x) == bits(&b.x)
        && bits(&a.u) == bits(&b.u)
}

fn job(seed: u64) -> Collection {
    Collection {
        policy: CollectPolicy::default(),
        seed,
        windows: 100,
        block_windows: 40,
        steps: 15,
    }
}

fn all_blocks(c: &bridge::client::Client, job: &Collection, from: u64) -> Vec<Block> {
    let mut out = Vec::new();
    collect_blocks(c, "pend", job, from, T, None, &mut |b| {
        out.push(b);
        Ok(())
    })
    .unwrap();
    out
}

#[test]
fn blocks_repeat_bit_for_bit_resume_and_follow_the_system() {
    let (c, _opts, _s) = common::cluster("collect", &[("pend", "damped-pendulum")], &[]);
    let sim = SimClient::connect(&c.client, "pend", common::READY).unwrap();
    let a = all_blocks(&c.client, &job(9), 0);
    let b = all_blocks(&c.client, &job(9), 0);
    assert_eq!(a.len(), 3);
    assert_eq!(a[2].windows, 20, "the last block is short");
    assert!(
        a.iter().zip(&b).all(|(a, b)| same(a, b)),
        "same seed, other bytes"
    );
    // Resume at block 2, and one block asked for alone: the same windows.
    let resumed = all_blocks(&c.client, &job(9), 2);
    assert_eq!(resumed.len(), 1);
    assert!(same(&resumed[0], &a[2]));
    let alone = collect_block(&c.client, "pend", &job(9).request(1), T, Some(&c.live)).unwrap();
    assert!(same(&alone, &a[1]));
    // Another seed: other windows.
    let other = all_blocks(&c.client, &job(10), 0);
    assert_ne!(bits(&other[0].x), bits(&a[0].x));

    // Independent computation: each window's first state is the system's draw for the reset
    // seed of window i, and each transition is the system stepped here.
    let sys = koopman::systems::by_name("damped-pendulum").unwrap();
    let (lo, hi) = sys.input_bounds();
    for blk in &a {
        for w in 0..blk.windows {
            let i = blk.first + w as u64;
            let x = &blk.x[w * 16 * 2..(w + 1) * 16 * 2];
            let u = &blk.u[w * 15..(w + 1) * 15];
            let x0 = sys.sample_initial_state(&mut Rng::new(window_rng(9, i).next_u64()));
            assert_eq!(&x[..2], &x0[..], "window {i}: first state");
            for k in 0..15 {
                assert!(u[k] >= lo[0] && u[k] <= hi[0]);
                let mut next = vec![0.0; 2];
                sys.step(&x[2 * k..2 * k + 2], &u[k..k + 1], &mut next);
                assert_eq!(
                    bits(&x[2 * k + 2..2 * k + 4]),
                    bits(&next),
                    "window {i} step {k}"
                );
            }
        }
    }

    // A block of several chunks travels whole (5,000 windows: two chunks of about 1 MiB).
    let big = CollectRequest {
        block_windows: 5000,
        ..job(9).request(0)
    };
    let blk = collect_block(&c.client, "pend", &big, T, Some(&c.live)).unwrap();
    assert_eq!((blk.windows, blk.x.len()), (5000, 5000 * 32));
    assert_eq!(bits(&blk.x[..40 * 32]), bits(&a[0].x));

    // The lockstep state is gone after a collect: a step needs a reset first.
    let step_key = c.client.keys.sim("pend", SimLeaf::Step).unwrap();
    let step = bridge::codec::StepRequest { k: 0, u: vec![0.0] }.encode();
    match c.client.query(&step_key, step, T, "pend") {
        Err(Error::Remote { reply, .. }) => assert_eq!(reply.code, ErrorCode::OutOfOrder),
        other => panic!("expected out_of_order, got {other:?}"),
    }
    let mut sim = sim;
    sim.reset(&ResetRequest::default()).unwrap();
    sim.step(&[0.5], Some(&c.live)).unwrap();
    let stats = sim.refresh_info().unwrap().stats.clone();
    assert_eq!(stats.collected_windows, 2 * 100 + 20 + 40 + 100 + 5000);
}

#[test]
fn bad_requests_get_typed_errors_and_the_adapter_keeps_serving() {
    let (c, _opts, _s) = common::cluster("collect-bad", &[("pend", "damped-pendulum")], &[]);
    SimClient::connect(&c.client, "pend", common::READY).unwrap();
    let key = c.client.keys.sim("pend", SimLeaf::Collect).unwrap();
    let raw = |body: &str| -> ErrorCode {
        match c.client.query(&key, body.as_bytes().to_vec(), T, "pend") {
            Err(Error::Remote { reply, .. }) => reply.code,
            other => panic!("expected an error reply to {body}, got {other:?}"),
        }
    };
    let ok = r#""seed": 1, "block": 0, "block_windows": 4, "steps": 3"#;
    assert_eq!(raw(""), ErrorCode::BadRequest);
    assert_eq!(
        raw(&format!(r#"{{{ok}, "policy": {{"kind": "gaussian"}}}}"#)),
        ErrorCode::BadRequest
    );
    assert_eq!(
        raw(&format!(
            r#"{{{ok}, "policy": {{"kind": "uniform", "low": NaN}}}}"#
        )),
        ErrorCode::BadRequest
    );
    assert_eq!(
        raw(&format!(r#"{{{ok}, "extra": 1}}"#)),
        ErrorCode::BadRequest
    );
    assert_eq!(
        raw(&format!(
            r#"{{{ok}, "policy": {{"kind": "planned", "windows_per_plan": 0}}}}"#
        )),
        ErrorCode::BadRequest
    );
    assert_eq!(
        raw(&format!(r#"{{{ok}, "policy": {{"kind": "planned"}}}}"#)),
        ErrorCode::Unsupported
    );
    let code = |req: CollectRequest| match collect_block(&c.client, "pend", &req, T, None) {
        Err(Error::Remote { reply, .. }) => reply.code,
        other => panic!("expected an error reply, got {other:?}"),
    };
    let base = job(1).request(0);
    let uniform = |low: InputBound, high: InputBound| CollectRequest {
        policy: CollectPolicy::Uniform {
            low: Some(low),
            high: Some(high),
            x0_low: None,
            x0_high: None,
        },
        ..base.clone()
    };
    assert_eq!(
        code(uniform(InputBound::All(1.0), InputBound::All(-1.0))),
        ErrorCode::BadRequest
    );
    assert_eq!(
        code(uniform(
            InputBound::Each(vec![0.0, 0.0]),
            InputBound::All(1.0)
        )),
        ErrorCode::Dimension
    );
    // A planned policy: known on the wire, but the built-in systems have no planner.
    let planned = CollectRequest {
        policy: CollectPolicy::Planned {
            windows_per_plan: Some(5),
            dither: None,
        },
        ..base.clone()
    };
    assert_eq!(code(planned), ErrorCode::Unsupported);
    let too_many = CollectRequest {
        block_windows: 4_000_000,
        ..base.clone()
    };
    assert_eq!(code(too_many), ErrorCode::TooLarge);
    assert_eq!(
        code(CollectRequest {
            steps: 0,
            ..base.clone()
        }),
        ErrorCode::BadRequest
    );
    // Still serving: a good request after all of them, inside a narrower box.
    let narrow = uniform(InputBound::All(-0.25), InputBound::All(0.25));
    let b = collect_block(&c.client, "pend", &narrow, T, Some(&c.live)).unwrap();
    assert!(b.u.iter().all(|u| u.abs() <= 0.25));
    assert_eq!(b.windows, 40);
}

#[test]
fn a_scenario_collects_through_the_adapters() {
    let dir = common::scratch("collect-run");
    let sc = dir.join("adapter.toml");
    std::fs::write(
        &sc,
        r#"
name = "adapter-collect"
[[sims]]
id = "pend"
env = "damped-pendulum"
[[sims]]
id = "dbl"
env = "double-pendulum"
[collect]
policy = { kind = "adapter", block = 7 }
train_windows = 30
val_windows = 5
test_windows = 0
steps = 15
seed = 3
"#,
    )
    .unwrap();
    let out = dir.join("out");
    common::run_scenario(&sc, &out, &[]);
    // The files hold what each system gives in this process for the seeds of its split.
    for (j, (id, env)) in [("pend", "damped-pendulum"), ("dbl", "double-pendulum")]
        .iter()
        .enumerate()
    {
        for (split, name, n) in [(Split::Train, "train", 30u32), (Split::Val, "val", 5)] {
            let ds = koopman::data::Dataset::load_npz(&out.join(format!("data/{id}/{name}.npz")))
                .unwrap();
            let mut b = SystemBackend::new(koopman::systems::by_name(env).unwrap());
            let req = CollectRequest {
                policy: CollectPolicy::default(),
                seed: adapter_seed(3, split, j),
                block: 0,
                block_windows: n,
                windows: None,
                steps: 15,
            };
            let plan = CollectPlan::new(&b.info(), &req).unwrap();
            let w = run_windows(&mut b, &plan).unwrap();
            assert_eq!(ds.n, n as usize);
            assert_eq!(bits(&ds.x), bits(&w.x), "{id} {name}: x");
            assert_eq!(bits(&ds.u), bits(&w.u), "{id} {name}: u");
        }
    }
    assert!(!out.join("data/pend/test.npz").exists());
}
