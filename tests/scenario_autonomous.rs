//! Autonomous systems (nu = 0) through the bridge, in several processes over Zenoh (issue 26
//! §1): `scenarios/autonomous.toml` (the polynomial map and the Van der Pol FMU) collects,
//! trains through the trainer service with ctrl off and reports prediction; asking for ctrl or
//! a `[control]` there fails before collection with the reason; the MPC service refuses an
//! autonomous model with a typed error and keeps serving; `koopbridge sweep` over polynomial
//! data defaults to cov and refuses `both`.

mod common;

use std::path::{Path, PathBuf};
use std::time::Duration;

use bridge::codec::{SolveReply, SolveRequest};
use bridge::error::{Error, ErrorCode};
use bridge::orchestrator::SERVICES_ID;
use koopman::data::Dataset;
use koopman::model::arch::Arch;
use koopman::model::koopman::KoopmanModel;
use koopman::mpc::MpcConfig;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The Python set-up the scenario needs (scripts/setup-python.sh), or why it is missing.
fn python_ready() -> Result<(), String> {
    for p in [".venv/bin/python", "adapters/fmu/build/van_der_pol.fmu"] {
        if !root().join(p).exists() {
            return Err(format!("{p} is missing (run scripts/setup-python.sh)"));
        }
    }
    Ok(())
}

/// `scenarios/autonomous.toml` at a tiny budget (40 / 8 / 8 windows, 60 iterations of a small
/// network), with `edit` applied, written inside the repository (so that its relative FMU path
/// and `{python}` resolve there) under a name of its own.
fn tiny_scenario(name: &str, edit: impl Fn(String) -> String) -> PathBuf {
    let text = std::fs::read_to_string(root().join("scenarios/autonomous.toml")).unwrap();
    let replace = |s: String, from: &str, to: &str| {
        assert!(
            s.contains(from),
            "scenarios/autonomous.toml has no '{from}'"
        );
        s.replace(from, to)
    };
    let mut text = replace(text, "train_windows = 2000\n", "train_windows = 40\n");
    text = replace(text, "val_windows = 400\n", "val_windows = 8\n");
    text = replace(text, "test_windows = 400\n", "test_windows = 8\n");
    let start = text.find("config = {").expect("a [train].config line");
    let end = start + text[start..].find('\n').unwrap();
    text.replace_range(
        start..end,
        "config = { iterations = 60, hidden = [16], n_mult = 2, batch = 8, validate_every = 20 }",
    );
    let file = root().join(format!(
        "target/kb-it-autonomous-{name}-{}-{}.toml",
        std::process::id(),
        bridge::keyexpr::fresh_session_id()
    ));
    std::fs::write(&file, edit(text)).unwrap();
    file
}

/// Van der Pol (mu = 1) over `t` seconds by classical RK4 at 0.1 ms: independent of the FMU's C
/// code and of its 1 ms substeps.
fn van_der_pol(x: &[f64], t: f64) -> [f64; 2] {
    let f = |y: [f64; 2]| [y[1], (1.0 - y[0] * y[0]) * y[1] - y[0]];
    let n = (t / 1e-4).round() as usize;
    let h = t / n as f64;
    let mut y = [x[0], x[1]];
    let add = |a: [f64; 2], k: [f64; 2], s: f64| [a[0] + s * k[0], a[1] + s * k[1]];
    for _ in 0..n {
        let k1 = f(y);
        let k2 = f(add(y, k1, h / 2.0));
        let k3 = f(add(y, k2, h / 2.0));
        let k4 = f(add(y, k3, h));
        for i in 0..2 {
            y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        }
    }
    y
}

/// The polynomial map of SPEC.md with n_poly = 5 (the default), written out here.
fn polynomial(x: &[f64]) -> [f64; 3] {
    let b = [0.9, 0.5, 0.1]; // linspace(0.9, 0.1, n_poly − 2)
    let sum: f64 = (1..=3).map(|p| b[p - 1] * x[0].powi(p as i32)).sum();
    [0.85 * x[0], 0.9 * x[1], 0.9 * x[2] + sum]
}

#[test]
fn the_autonomous_scenario_collects_trains_and_reports_prediction_without_control() {
    if let Err(why) = python_ready() {
        eprintln!("skipped: {why}");
        return;
    }
    let sc = tiny_scenario("run", |t| t);
    let out = common::scratch("autonomous").join("out");
    let o = common::run_scenario(&sc, &out, &[]);
    std::fs::remove_file(&sc).unwrap();
    eprintln!("{}", String::from_utf8_lossy(&o.stdout));
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(r["collect"]["sims"], serde_json::json!(["poly", "vdp"]));
    assert!(r["control"].is_null(), "{}", r["control"]);
    assert_eq!(r["controls"], serde_json::json!([]));
    assert!(r["control_loop"].is_null());
    for (j, id) in ["poly", "vdp"].iter().enumerate() {
        let t = &r["train"][j];
        assert_eq!(t["sim"], *id);
        assert_eq!(t["model"], format!("autonomous-{id}"));
        let m = &t["metrics"];
        let err = m["test_prediction_error"].as_f64().unwrap();
        assert!(err.is_finite() && err >= 0.0, "{id}: {err}");
        assert_eq!(m["config"]["ctrl"], false, "{id}: {m}");
        assert_eq!(m["config"]["cov"], true, "{id}");
        assert_eq!(m["final_loss"]["ctrl"], 0.0, "{id}");
        let cfg: serde_json::Value = serde_json::from_slice(
            &std::fs::read(out.join(format!("models/autonomous-{id}/config.json"))).unwrap(),
        )
        .unwrap();
        assert_eq!(cfg["nu"], 0, "{id}: {cfg}");
    }
    // The data: no inputs, and every transition is the system's own (checked against the
    // closed-form map and an independent fine-step integration of Van der Pol).
    let poly = Dataset::load_npz(&out.join("data/poly/train.npz")).unwrap();
    assert_eq!((poly.n, poly.steps, poly.nx, poly.nu), (40, 10, 3, 0));
    assert!(poly.u.is_empty());
    let vdp = Dataset::load_npz(&out.join("data/vdp/train.npz")).unwrap();
    assert_eq!((vdp.n, vdp.steps, vdp.nx, vdp.nu), (40, 10, 2, 0));
    assert!(vdp.meta.input_names.is_empty());
    assert!((vdp.meta.dt - 0.05).abs() < 1e-12, "{}", vdp.meta.dt);
    let (mut worst_poly, mut worst_vdp) = (0.0f64, 0.0f64);
    for i in 0..40 {
        let x0 = vdp.state(i, 0);
        assert!(x0[0].abs() <= 2.5 && x0[1].abs() <= 3.0, "{x0:?}");
        assert!(poly.state(i, 0).iter().all(|v| v.abs() <= 1.0));
        for k in 0..10 {
            let want = polynomial(poly.state(i, k));
            for (a, b) in poly.state(i, k + 1).iter().zip(want) {
                worst_poly = worst_poly.max((a - b).abs());
            }
            let want = van_der_pol(vdp.state(i, k), 0.05);
            for (a, b) in vdp.state(i, k + 1).iter().zip(want) {
                worst_vdp = worst_vdp.max((a - b).abs());
            }
        }
    }
    assert!(worst_poly < 1e-12, "polynomial map: {worst_poly}");
    assert!(worst_vdp < 1e-9, "Van der Pol: {worst_vdp}");
    // The windows are not all alike (the seeded resets drew different starts).
    assert!((vdp.state(0, 0)[0] - vdp.state(1, 0)[0]).abs() > 1e-6);
}

/// Runs `koopbridge run SCENARIO` expecting it to fail; returns its stderr.
fn run_failing(sc: &Path, out: &Path) -> String {
    let o = std::process::Command::new(common::exe())
        .args(["run", sc.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .output()
        .unwrap();
    std::fs::remove_file(sc).unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(!o.status.success(), "the run succeeded:\n{stderr}");
    stderr
}

#[test]
fn ctrl_or_control_on_an_autonomous_simulator_fails_before_collection() {
    if let Err(why) = python_ready() {
        eprintln!("skipped: {why}");
        return;
    }
    let dir = common::scratch("autonomous-refused");
    let sc = tiny_scenario("ctrl", |t| {
        t.replace(
            "validate_every = 20 }",
            "validate_every = 20, ctrl = true }",
        )
    });
    let out = dir.join("ctrl");
    let stderr = run_failing(&sc, &out);
    assert!(
        stderr.contains("ctrl = true")
            && stderr.contains("needs inputs")
            && stderr.contains("'poly'"),
        "{stderr}"
    );
    assert!(!out.join("data/poly/train.npz").exists());
    assert!(!out.join("data/vdp/train.npz").exists());

    let sc = tiny_scenario("control", |t| {
        t + "\n[control]\nsim = \"vdp\"\nx0 = [1.0, 0.0]\nreference = [0.0, 0.0]\nsteps = 10\n"
    });
    let out = dir.join("control");
    let stderr = run_failing(&sc, &out);
    assert!(
        stderr.contains("no inputs to control") && stderr.contains("'vdp'"),
        "{stderr}"
    );
    assert!(!out.join("data/vdp/train.npz").exists());
}

fn remote(r: bridge::Result<Vec<u8>>) -> bridge::error::ErrorReply {
    match r {
        Err(Error::Remote { reply, .. }) => reply,
        other => panic!("expected a typed error reply, got {other:?}"),
    }
}

#[test]
fn the_mpc_service_refuses_an_autonomous_model_and_keeps_serving() {
    let (opts, session) = common::options("mpc-autonomous");
    let store = opts.out_dir.join("models");
    KoopmanModel::init(Arch::new(3, 0, &[16], 2).unwrap(), 5)
        .unwrap()
        .save(&store.join("auto"))
        .unwrap();
    KoopmanModel::init(Arch::new(2, 1, &[16], 2).unwrap(), 7)
        .unwrap()
        .save(&store.join("m1"))
        .unwrap();
    let c = bridge::orchestrator::Cluster::start(&opts, &session, &[], &["mpc", "models"]).unwrap();
    let configure_key = c.client.keys.under(&["mpc", SERVICES_ID, "configure"]);
    let configure = |model: &str, cfg: serde_json::Value| {
        let body = serde_json::to_vec(&serde_json::json!({"model": model, "mpc": cfg})).unwrap();
        c.client
            .query(&configure_key, body, Duration::from_secs(60), "mpc")
    };
    let solve_key = c.client.keys.mpc_solve(SERVICES_ID).unwrap();
    let solve = |model: &str, x: Vec<f64>| {
        let req = SolveRequest {
            model: model.into(),
            reference: vec![0.0; x.len()],
            x,
            feedforward: Vec::new(),
        };
        c.client
            .query(&solve_key, req.encode(), Duration::from_secs(30), "mpc")
    };
    // Configured with the defaults, and asked to solve without configuring: the same refusal.
    for reply in [
        remote(configure("auto", serde_json::json!({}))),
        remote(solve("auto", vec![0.1, 0.2, 0.3])),
    ] {
        assert_eq!(reply.code, ErrorCode::BadRequest, "{reply:?}");
        assert!(
            reply.message.contains("no inputs to control") && reply.message.contains("nu = 0"),
            "{reply:?}"
        );
    }
    // Still serving: a model with an input is configured and solved.
    let cfg = MpcConfig::with_bounds(vec![-2.0], vec![2.0]);
    let r: serde_json::Value =
        serde_json::from_slice(&configure("m1", serde_json::to_value(&cfg).unwrap()).unwrap())
            .unwrap();
    assert_eq!(r["horizon"], 15);
    let plan = SolveReply::decode(&solve("m1", vec![0.5, -0.3]).unwrap()).unwrap();
    assert_eq!(plan.u.len(), 15);
    assert!(plan
        .u
        .iter()
        .all(|u| u.is_finite() && u.abs() <= 2.0 + 1e-9));
    // ... and the autonomous model is refused again, the same way.
    assert_eq!(
        remote(solve("auto", vec![0.0; 3])).code,
        ErrorCode::BadRequest
    );
}

#[test]
fn a_sweep_over_autonomous_data_defaults_to_cov_and_refuses_both() {
    let dir = common::scratch("sweep-autonomous");
    let data = dir.join("poly");
    let o = std::process::Command::new(common::exe())
        .args([
            "data",
            "gen",
            "--env",
            "polynomial",
            "--windows",
            "300",
            "--out",
        ])
        .arg(&data)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let sweep = |out: &Path, extra: &[&str]| {
        std::process::Command::new(common::exe())
            .args(["sweep", "--data"])
            .arg(&data)
            .args(["--samples", "50,100", "--n-mult", "2", "--iterations", "20"])
            .args([
                "--set",
                "hidden=[8]",
                "--set",
                "batch=8",
                "--set",
                "validate_every=10",
            ])
            .args(["--local-trainers", "1", "--out"])
            .arg(out)
            .args(extra)
            .output()
            .unwrap()
    };
    let out = dir.join("sweep");
    let o = sweep(&out, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 2, "{csv}");
    for row in &rows {
        assert_eq!(row[col("regularisers")], "cov", "{csv}");
        assert_eq!(row[col("env")], "polynomial", "{csv}");
        let e: f64 = row[col("test_error")].parse().unwrap();
        assert!(e.is_finite() && e >= 0.0, "{csv}");
    }
    for (setting, out) in [("both", "both"), ("none,ctrl", "ctrl")] {
        let out = dir.join(out);
        let o = sweep(&out, &["--regularisers", setting]);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{setting}: {stderr}");
        let named = setting.rsplit(',').next().unwrap();
        assert!(
            stderr.contains(&format!("regulariser setting '{named}'"))
                && stderr.contains("needs inputs")
                && stderr.contains("nu = 0"),
            "{setting}: {stderr}"
        );
        assert!(!out.join("results.csv").exists(), "{setting}");
    }
}
