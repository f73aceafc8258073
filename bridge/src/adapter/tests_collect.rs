//! Tests of `collect` on the simulator side: requests checked into a [`CollectPlan`], windows run
//! by the default [`SimBackend::collect`] ([`super::run_windows`]) and cut into reply chunks.

use koopman::rng::Rng;

use super::backend::{SimBackend, SimError, SystemBackend};
use super::collect::{CollectPlan, PlanInputs, Windows, CHUNK_VALUES};
use crate::codec::CollectChunk;
use crate::error::ErrorCode;
use crate::messages::{CollectPolicy, CollectRequest, InputBound, SimInfo};

fn request(block: u64, windows: Option<u32>) -> CollectRequest {
    CollectRequest {
        policy: CollectPolicy::default(),
        seed: 7,
        block,
        block_windows: 5,
        windows,
        steps: 4,
    }
}

fn pendulum() -> SystemBackend {
    SystemBackend::new(koopman::systems::by_name("damped-pendulum").unwrap())
}

#[test]
fn windows_follow_the_system_and_depend_only_on_their_index() {
    let mut b = pendulum();
    let info = b.info();
    let plan = CollectPlan::new(&info, &request(1, None)).unwrap();
    assert_eq!((plan.first, plan.windows), (5, 5));
    let w = b.collect(&plan).unwrap();
    plan.check(&w).unwrap();
    // Independent computation: the system stepped here from each window's first state.
    let sys = koopman::systems::by_name("damped-pendulum").unwrap();
    let (lo, hi) = sys.input_bounds();
    for i in 0..5 {
        let x = &w.x[i * 10..(i + 1) * 10];
        let u = &w.u[i * 4..(i + 1) * 4];
        let mut r = Rng::derive(7, 5 + i as u64);
        let x0 = sys.sample_initial_state(&mut Rng::new(r.next_u64()));
        assert_eq!(&x[..2], &x0[..]);
        for k in 0..4 {
            assert!(u[k] >= lo[0] && u[k] <= hi[0]);
            let mut next = vec![0.0; 2];
            sys.step(&x[2 * k..2 * k + 2], &u[k..k + 1], &mut next);
            assert_eq!(&x[2 * k + 2..2 * k + 4], &next[..], "window {i} step {k}");
        }
    }
    // A short block of the same collection holds the same first windows.
    let short = CollectPlan::new(&info, &request(1, Some(2))).unwrap();
    let ws = b.collect(&short).unwrap();
    assert_eq!(ws.x, w.x[..20]);
    assert_eq!(ws.u, w.u[..8]);
}

#[test]
fn chunks_cover_the_block_in_order() {
    let mut b = pendulum();
    let info = b.info();
    let req = CollectRequest {
        block_windows: 20_000,
        steps: 15,
        ..request(0, None)
    };
    let plan = CollectPlan::new(&info, &req).unwrap();
    let w = b.collect(&plan).unwrap();
    let chunks: Vec<CollectChunk> = plan
        .chunks(&w)
        .iter()
        .map(|c| CollectChunk::decode(c).unwrap())
        .collect();
    assert!(chunks.len() > 1, "{} chunks", chunks.len());
    let (mut x, mut u, mut next) = (Vec::new(), Vec::new(), 0);
    for (i, c) in chunks.iter().enumerate() {
        assert_eq!((c.chunk as usize, c.chunks as usize), (i, chunks.len()));
        assert_eq!(c.first, next);
        assert!(c.x.len() + c.u.len() <= CHUNK_VALUES);
        next += u64::from(c.windows);
        x.extend_from_slice(&c.x);
        u.extend_from_slice(&c.u);
    }
    assert_eq!((next, x, u), (20_000, w.x, w.u));
}

#[test]
fn bad_requests_are_typed() {
    let info = pendulum().info();
    let code = |r: CollectRequest| CollectPlan::new(&info, &r).unwrap_err().code;
    let r = || request(0, None);
    assert_eq!(
        code(CollectRequest { steps: 0, ..r() }),
        ErrorCode::BadRequest
    );
    assert_eq!(code(request(0, Some(0))), ErrorCode::BadRequest);
    assert_eq!(code(request(0, Some(6))), ErrorCode::BadRequest);
    assert_eq!(code(request(u64::MAX, None)), ErrorCode::BadRequest);
    let huge = CollectRequest {
        block_windows: u32::MAX,
        ..r()
    };
    assert_eq!(code(huge), ErrorCode::TooLarge);
    let policy = |low: InputBound, high: InputBound| CollectRequest {
        policy: CollectPolicy::Uniform {
            low: Some(low),
            high: Some(high),
            x0_low: None,
            x0_high: None,
        },
        ..r()
    };
    use InputBound::{All, Each};
    assert_eq!(
        code(policy(Each(vec![0.0, 1.0]), All(1.0))),
        ErrorCode::Dimension
    );
    assert_eq!(code(policy(All(1.0), All(0.0))), ErrorCode::BadRequest);
    assert_eq!(code(policy(All(f64::NAN), All(0.0))), ErrorCode::BadRequest);
    assert_eq!(
        code(policy(All(0.0), All(f64::INFINITY))),
        ErrorCode::BadRequest
    );
    let ok = CollectPlan::new(&info, &policy(All(-0.5), Each(vec![0.5]))).unwrap();
    assert_eq!(
        ok.inputs,
        PlanInputs::Uniform {
            low: vec![-0.5],
            high: vec![0.5],
            x0: None
        }
    );
    // A simulator without finite bounds needs explicit ones.
    let open = SimInfo {
        u_max: vec![f64::INFINITY],
        ..info.clone()
    };
    assert_eq!(
        CollectPlan::new(&open, &r()).unwrap_err().code,
        ErrorCode::BadRequest
    );
    // A backend that returns too little or a NaN: sim_failure.
    let plan = CollectPlan::new(&info, &r()).unwrap();
    let short = Windows {
        x: vec![0.0; 3],
        u: vec![],
    };
    assert_eq!(plan.check(&short).unwrap_err().code, ErrorCode::SimFailure);
    let mut w = pendulum().collect(&plan).unwrap();
    w.x[3] = f64::NAN;
    assert_eq!(plan.check(&w).unwrap_err().code, ErrorCode::SimFailure);
}

#[test]
fn a_planned_policy_is_checked_and_unsupported_without_a_planner() {
    let mut b = pendulum();
    let info = b.info();
    let planned = |k: Option<u32>| CollectRequest {
        policy: CollectPolicy::Planned {
            windows_per_plan: k,
            dither: None,
        },
        ..request(0, None)
    };
    let zero = CollectPlan::new(&info, &planned(Some(0))).unwrap_err();
    assert_eq!(zero.code, ErrorCode::BadRequest);
    assert!(
        zero.message.contains("windows_per_plan"),
        "{}",
        zero.message
    );
    let dithered = |d: f64| CollectRequest {
        policy: CollectPolicy::Planned {
            windows_per_plan: Some(20),
            dither: Some(d),
        },
        ..request(0, None)
    };
    for bad in [-0.1, f64::NAN, f64::INFINITY] {
        let e = CollectPlan::new(&info, &dithered(bad)).unwrap_err();
        assert_eq!(e.code, ErrorCode::BadRequest);
        assert!(e.message.contains("dither"), "{}", e.message);
    }
    let d = CollectPlan::new(&info, &dithered(0.2)).unwrap();
    assert_eq!(d.policy(), dithered(0.2).policy);
    let plan = CollectPlan::new(&info, &planned(Some(20))).unwrap();
    // What a Python backend is handed: the policy as asked.
    assert_eq!(plan.policy(), planned(Some(20)).policy);
    let err = b.collect(&plan).unwrap_err();
    assert!(matches!(err, SimError::Unsupported(_)), "{err:?}");
    assert_eq!(err.reply().code, ErrorCode::Unsupported);
    // Bounds play no part: a simulator without finite bounds accepts the request too.
    let open = SimInfo {
        u_max: vec![f64::INFINITY],
        ..info
    };
    assert!(CollectPlan::new(&open, &planned(None)).is_ok());
}

#[test]
fn an_initial_state_box_resets_every_window_inside_it() {
    let mut b = pendulum();
    let info = b.info();
    let boxed = |lo: Vec<f64>, hi: Vec<f64>| CollectRequest {
        policy: CollectPolicy::Uniform {
            low: Some(InputBound::All(-0.5)),
            high: Some(InputBound::All(0.5)),
            x0_low: Some(lo),
            x0_high: Some(hi),
        },
        ..request(0, None)
    };
    let plan = CollectPlan::new(&info, &boxed(vec![0.1, -0.2], vec![0.3, 0.0])).unwrap();
    // The box travels on to a backend of another language.
    assert!(matches!(
        plan.policy(),
        CollectPolicy::Uniform { x0_low: Some(ref l), .. } if l == &[0.1, -0.2]
    ));
    let w = b.collect(&plan).unwrap();
    plan.check(&w).unwrap();
    let sys = koopman::systems::by_name("damped-pendulum").unwrap();
    for i in 0..5 {
        // Independent computation: the window's stream — reset seed, x0, then the inputs.
        let mut r = Rng::derive(7, i as u64);
        r.next_u64();
        let x0 = [r.uniform(0.1, 0.3), r.uniform(-0.2, 0.0)];
        let x = &w.x[i * 10..(i + 1) * 10];
        assert_eq!(&x[..2], &x0[..], "window {i}");
        let u0 = r.uniform(-0.5, 0.5);
        assert_eq!(w.u[i * 4], u0);
        let mut next = vec![0.0; 2];
        sys.step(&x0, &[u0], &mut next);
        assert_eq!(&x[2..4], &next[..]);
    }
    let code = |r: CollectRequest| CollectPlan::new(&info, &r).unwrap_err().code;
    assert_eq!(code(boxed(vec![0.0], vec![1.0])), ErrorCode::Dimension);
    assert_eq!(
        code(boxed(vec![0.0, 1.0], vec![1.0, 0.5])),
        ErrorCode::BadRequest
    );
    let half = CollectRequest {
        policy: CollectPolicy::Uniform {
            low: None,
            high: None,
            x0_low: Some(vec![0.0, 0.0]),
            x0_high: None,
        },
        ..request(0, None)
    };
    assert_eq!(code(half), ErrorCode::BadRequest);
}
