//! The MPC service and the model store over Zenoh, in separate processes: a remote solve equals
//! a local solve of the same model, bad requests get typed errors and the service keeps serving,
//! and a model fetched from the store is byte-identical.

mod common;

use std::time::Duration;

use bridge::codec::{SolveReply, SolveRequest};
use bridge::error::{Error, ErrorCode};
use bridge::orchestrator::SERVICES_ID;
use koopman::model::arch::Arch;
use koopman::model::koopman::KoopmanModel;
use koopman::mpc::{MpcConfig, MpcController};

fn code(r: bridge::Result<Vec<u8>>) -> ErrorCode {
    match r {
        Err(Error::Remote { reply, .. }) => reply.code,
        other => panic!("expected a typed error reply, got {other:?}"),
    }
}

#[test]
fn remote_solve_equals_local_solve_and_errors_are_typed() {
    let (opts, session) = common::options("mpc");
    // The store is created before the services start; they serve it from `out_dir/models`.
    let model = KoopmanModel::init(Arch::new(2, 1, &[32, 32], 4).unwrap(), 7).unwrap();
    model.save(&opts.out_dir.join("models").join("m1")).unwrap();
    let c = bridge::orchestrator::Cluster::start(&opts, &session, &[], &["mpc", "models"]).unwrap();
    let cfg = MpcConfig::with_bounds(vec![-2.0], vec![2.0]);
    let configure = c.client.keys.under(&["mpc", SERVICES_ID, "configure"]);
    let body = serde_json::to_vec(&serde_json::json!({"model": "m1", "mpc": cfg})).unwrap();
    let r: serde_json::Value = serde_json::from_slice(
        &c.client
            .query(&configure, body, Duration::from_secs(60), "mpc")
            .unwrap(),
    )
    .unwrap();
    assert_eq!(r["horizon"], 15);
    let key = c.client.keys.mpc_solve(SERVICES_ID).unwrap();
    let mut local = MpcController::new(&model, &cfg).unwrap();
    for (i, x) in [[0.5, -0.3], [-2.0, 1.0], [3.0, 0.0]].iter().enumerate() {
        let req = SolveRequest {
            model: "m1".into(),
            x: x.to_vec(),
            reference: vec![0.0, 0.0],
            feedforward: Vec::new(),
        };
        let b = c
            .client
            .query(&key, req.encode(), Duration::from_secs(30), "mpc")
            .unwrap();
        let remote = SolveReply::decode(&b).unwrap();
        let mine = local.solve(x, &[0.0, 0.0]).unwrap();
        assert_eq!(remote.u.len(), 15);
        for (a, b) in remote.u.iter().zip(&mine.u) {
            assert!((a - b).abs() < 1e-9, "solve {i}: remote {a} vs local {b}");
        }
        assert!(remote
            .u
            .iter()
            .all(|u| (-2.0 - 1e-9..=2.0 + 1e-9).contains(u)));
    }
    // Error-state tracking of a plan: the feed-forward travels with the request and the remote
    // plan is the local `solve_about_plan`'s.
    let u_ff: Vec<f64> = (0..15).map(|i| 0.1 * (i as f64 * 0.4).sin()).collect();
    for x in [[0.5, -0.3], [-1.0, 0.8]] {
        let req = SolveRequest {
            model: "m1".into(),
            x: x.to_vec(),
            reference: vec![0.4, -0.2],
            feedforward: u_ff.clone(),
        };
        let b = c
            .client
            .query(&key, req.encode(), Duration::from_secs(30), "mpc")
            .unwrap();
        let remote = SolveReply::decode(&b).unwrap();
        let mine = local.solve_about_plan(&x, &[0.4, -0.2], &u_ff).unwrap();
        let plain = local.solve(&x, &[0.4, -0.2]).unwrap();
        let gap = |p: &[f64]| {
            remote
                .u
                .iter()
                .zip(p)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max)
        };
        assert!(
            gap(&mine.u) < 1e-9,
            "error-state: remote vs local {}",
            gap(&mine.u)
        );
        assert!(
            gap(&plain.u) > 1e-6,
            "the feed-forward must change the plan"
        );
    }
    let q = |b: Vec<u8>| c.client.query(&key, b, Duration::from_secs(30), "mpc");
    let short_ff = SolveRequest {
        model: "m1".into(),
        x: vec![0.0; 2],
        reference: vec![0.0; 2],
        feedforward: vec![0.0; 14],
    };
    assert_eq!(code(q(short_ff.encode())), ErrorCode::BadRequest);
    assert_eq!(code(q(b"\x00\x01".to_vec())), ErrorCode::BadRequest);
    assert_eq!(code(q(vec![7u8; 3 << 20])), ErrorCode::TooLarge);
    let wrong_dim = SolveRequest {
        model: "m1".into(),
        x: vec![0.0; 3],
        reference: vec![0.0, 0.0],
        feedforward: Vec::new(),
    };
    assert_eq!(code(q(wrong_dim.encode())), ErrorCode::Dimension);
    let missing = SolveRequest {
        model: "nope".into(),
        x: vec![0.0; 2],
        reference: vec![0.0; 2],
        feedforward: Vec::new(),
    };
    assert!(matches!(q(missing.encode()), Err(Error::Remote { .. })));
    // Still serving.
    let ok = SolveRequest {
        model: String::new(),
        x: vec![0.1, 0.1],
        reference: vec![0.0, 0.0],
        feedforward: Vec::new(),
    };
    assert!(SolveReply::decode(&q(ok.encode()).unwrap()).is_ok());

    // Model store: the archive unpacks to the same files.
    let dst = opts.out_dir.join("fetched");
    let dir =
        bridge::services::models::fetch(&c.client, "m1", &dst, Duration::from_secs(30)).unwrap();
    for f in ["config.json", "model.safetensors"] {
        assert_eq!(
            std::fs::read(dir.join(f)).unwrap(),
            std::fs::read(opts.out_dir.join("models/m1").join(f)).unwrap()
        );
    }
    assert_eq!(
        code(c.client.query(
            &c.client.keys.model("absent").unwrap(),
            vec![],
            Duration::from_secs(30),
            "models"
        )),
        ErrorCode::NotFound
    );
}

/// Three models' closed loops solved at once from three threads (each model has its own solver
/// thread in the service): every reply is its own model's plan, equal to a local controller fed
/// the same sequence of states, and a model configured again mid-way plans with its new
/// settings from the next solve on while the others go on.
#[test]
fn several_models_are_solved_side_by_side_each_with_its_own_plan() {
    let (opts, session) = common::options("mpc-many");
    let dims = [(2usize, 1usize, 3u64), (4, 2, 5), (3, 1, 9)];
    for (i, &(nx, nu, seed)) in dims.iter().enumerate() {
        let m = KoopmanModel::init(Arch::new(nx, nu, &[16, 16], 2).unwrap(), seed).unwrap();
        m.save(&opts.out_dir.join("models").join(format!("m{i}")))
            .unwrap();
    }
    let c = bridge::orchestrator::Cluster::start(&opts, &session, &[], &["mpc", "models"]).unwrap();
    let configure_key = c.client.keys.under(&["mpc", SERVICES_ID, "configure"]);
    let configure = |model: &str, cfg: &MpcConfig| {
        let body = serde_json::to_vec(&serde_json::json!({"model": model, "mpc": cfg})).unwrap();
        c.client
            .query(&configure_key, body, Duration::from_secs(60), "mpc")
            .unwrap();
    };
    let cfgs: Vec<MpcConfig> = dims
        .iter()
        .map(|&(_, nu, _)| MpcConfig::with_bounds(vec![-1.0; nu], vec![1.0; nu]))
        .collect();
    for (i, cfg) in cfgs.iter().enumerate() {
        configure(&format!("m{i}"), cfg);
    }
    let key = c.client.keys.mpc_solve(SERVICES_ID).unwrap();
    let solves = 40;
    std::thread::scope(|s| {
        for (i, &(nx, nu, seed)) in dims.iter().enumerate() {
            let (key, client, cfg) = (&key, &c.client, &cfgs[i]);
            let configure = &configure;
            s.spawn(move || {
                let model =
                    KoopmanModel::init(Arch::new(nx, nu, &[16, 16], 2).unwrap(), seed).unwrap();
                let mut local = MpcController::new(&model, cfg).unwrap();
                let mut rng = koopman::rng::Rng::new(100 + seed);
                for k in 0..solves {
                    if i == 0 && k == solves / 2 {
                        // Model m0 again, with a shorter horizon: later plans have 5 steps.
                        let short = MpcConfig {
                            horizon: 5,
                            ..cfg.clone()
                        };
                        configure("m0", &short);
                        local = MpcController::new(&model, &short).unwrap();
                    }
                    let x: Vec<f64> = (0..nx).map(|_| rng.uniform(-1.0, 1.0)).collect();
                    let req = SolveRequest {
                        model: format!("m{i}"),
                        x: x.clone(),
                        reference: vec![0.0; nx],
                        feedforward: Vec::new(),
                    };
                    let b = client
                        .query(key, req.encode(), Duration::from_secs(30), "mpc")
                        .unwrap();
                    let remote = SolveReply::decode(&b).unwrap();
                    let mine = local.solve(&x, &vec![0.0; nx]).unwrap();
                    assert_eq!(remote.u.len(), mine.u.len(), "m{i}, solve {k}");
                    for (a, b) in remote.u.iter().zip(&mine.u) {
                        assert!((a - b).abs() < 1e-9, "m{i}, solve {k}: remote {a} vs {b}");
                    }
                }
            });
        }
    });
}

/// An NNDM in the store gets random-shooting MPC (the paper's NNDM baseline) through the same
/// `configure`/`solve` as a lifted model: the remote plan is the best of the 1000 sequences
/// drawn from the controller's seed, found here a second way (the draws repeated with the same
/// generator, every rollout stepped one transition at a time instead of batched), a
/// reconfigure starts the draws again, and what random shooting cannot do gets typed errors.
#[test]
fn an_nndm_is_planned_by_random_shooting_through_the_service() {
    use koopman::model::nndm::{NndmArch, NndmModel};
    use koopman::mpc::controllers::{SHOOTING_SAMPLES, SHOOTING_SEED};
    let (opts, session) = common::options("mpc-nndm");
    let model = NndmModel::init(NndmArch::new(2, 1, &[16, 16]).unwrap(), 3).unwrap();
    model
        .save(&opts.out_dir.join("models").join("nn1"))
        .unwrap();
    let c = bridge::orchestrator::Cluster::start(&opts, &session, &[], &["mpc", "models"]).unwrap();
    let configure_key = c.client.keys.under(&["mpc", SERVICES_ID, "configure"]);
    let configure = |mpc: serde_json::Value| {
        let body = serde_json::to_vec(&serde_json::json!({"model": "nn1", "mpc": mpc})).unwrap();
        c.client
            .query(&configure_key, body, Duration::from_secs(60), "mpc")
    };
    let (h, q, lo, hi) = (5usize, [1.0, 0.1], -0.5, 0.5);
    let good = serde_json::json!({"horizon": h, "q": q, "u_min": [lo], "u_max": [hi]});
    let r: serde_json::Value = serde_json::from_slice(&configure(good.clone()).unwrap()).unwrap();
    assert_eq!(
        (r["nx"].clone(), r["horizon"].clone()),
        (2.into(), 5.into())
    );

    // The independent computation: the same draws, rolled out one step at a time.
    let (x, target) = ([0.3, -0.2], [0.0, 0.1]);
    let mut rng = koopman::rng::Rng::new(SHOOTING_SEED);
    let mut best = (f64::INFINITY, Vec::new());
    for _ in 0..SHOOTING_SAMPLES {
        let seq: Vec<f64> = (0..h).map(|_| rng.uniform(lo, hi)).collect();
        let (mut s, mut cost) = (x.to_vec(), 0.0);
        for u in &seq {
            s = model.step(&s, &[*u]).unwrap();
            cost += (0..2)
                .map(|i| q[i] * (s[i] - target[i]).powi(2))
                .sum::<f64>();
        }
        if cost < best.0 {
            best = (cost, seq);
        }
    }
    let key = c.client.keys.mpc_solve(SERVICES_ID).unwrap();
    let solve = |reference: Vec<f64>, feedforward: Vec<f64>| {
        let req = SolveRequest {
            model: "nn1".into(),
            x: x.to_vec(),
            reference,
            feedforward,
        };
        c.client
            .query(&key, req.encode(), Duration::from_secs(30), "mpc")
    };
    let first = SolveReply::decode(&solve(target.to_vec(), vec![]).unwrap()).unwrap();
    assert_eq!(first.u.len(), h);
    for (a, b) in first.u.iter().zip(&best.1) {
        assert!(
            (a - b).abs() < 1e-12,
            "remote {:?} vs independent {:?}",
            first.u,
            best.1
        );
    }
    // The next solve draws new sequences; a reconfigure starts from the seed again, and the
    // stacked reference (the target held over H steps) plans the same as the single state.
    let second = SolveReply::decode(&solve(target.to_vec(), vec![]).unwrap()).unwrap();
    assert_ne!(second.u, first.u);
    configure(good.clone()).unwrap();
    let stacked = SolveReply::decode(&solve(target.repeat(h), vec![]).unwrap()).unwrap();
    assert_eq!(stacked.u, first.u);

    // About a plan (a feed-forward): the feed-forward itself and ff + δ, one δ ~ U(±10 % of
    // the half-range) held over the horizon, towards the model's own rollout of the plan from
    // the plan's state, R on u − ff; the same draws computed here.
    let with_r =
        serde_json::json!({"horizon": h, "q": q, "r": [0.5], "u_min": [lo], "u_max": [hi]});
    configure(with_r).unwrap();
    let (plan_x, ff) = ([0.25, -0.1], [0.1, -0.2, 0.3, 0.45, 0.0]);
    let mut plan = Vec::new();
    let mut s = plan_x.to_vec();
    for u in ff {
        s = model.step(&s, &[u]).unwrap();
        plan.push(s.clone());
    }
    let mut rng = koopman::rng::Rng::new(SHOOTING_SEED);
    let w = koopman::mpc::shooting::ABOUT_PLAN_SPREAD * (hi - lo) / 2.0;
    let mut best = (f64::INFINITY, Vec::new());
    for i in 0..SHOOTING_SAMPLES {
        let d = if i == 0 { 0.0 } else { rng.uniform(-w, w) };
        let seq: Vec<f64> = ff.iter().map(|u| (u + d).clamp(lo, hi)).collect();
        let (mut s, mut cost) = (x.to_vec(), 0.0);
        for (k, u) in seq.iter().enumerate() {
            s = model.step(&s, &[*u]).unwrap();
            cost += (0..2)
                .map(|i| q[i] * (s[i] - plan[k][i]).powi(2))
                .sum::<f64>()
                + 0.5 * (u - ff[k]).powi(2);
        }
        if cost < best.0 {
            best = (cost, seq);
        }
    }
    let about = SolveReply::decode(&solve(plan_x.to_vec(), ff.to_vec()).unwrap()).unwrap();
    for (a, b) in about.u.iter().zip(&best.1) {
        assert!(
            (a - b).abs() < 1e-12,
            "remote {:?} vs independent {:?}",
            about.u,
            best.1
        );
    }
    configure(good.clone()).unwrap();

    // What random shooting cannot do: typed errors, and the service keeps serving.
    assert_eq!(
        code(solve(target.to_vec(), vec![0.0; h - 1])),
        ErrorCode::Dimension
    );
    assert_eq!(code(solve(vec![0.0; 3], vec![])), ErrorCode::Dimension);
    let e = format!(
        "{:?}",
        configure(serde_json::json!({"horizon": h})).unwrap_err()
    );
    assert!(e.contains("u_min and u_max"), "{e}");
    let e = format!(
        "{:?}",
        configure(serde_json::json!({"u_min": [lo], "u_max": [hi], "terminal": [1.0, 1.0]}))
            .unwrap_err()
    );
    assert!(e.contains("no terminal weight"), "{e}");
    assert!(SolveReply::decode(&solve(target.to_vec(), vec![]).unwrap()).is_ok());
}
