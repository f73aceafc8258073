//! The bilinear pendulum scenario files (scenarios/damped-pendulum-bilinear.toml and
//! scenarios/damped-pendulum-fmu-bilinear.toml) end to end at a smoke budget: their budget lines
//! replaced, the pipeline runs (collect, train a bilinear model, control with it) and the
//! report has a finite final error and the bilinear model kind.

mod common;

use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The budget lines of both files and the smoke values for them (200 windows, 150 iterations of
/// a small model, 60 control steps).
const SMOKE: [(&str, &str); 3] = [
    (
        "train_windows = 2000\nval_windows = 400\ntest_windows = 400\n",
        "train_windows = 200\nval_windows = 40\ntest_windows = 40\n",
    ),
    (
        "config = { bilinear = true, iterations = 3000, ctrl = false, cov = false, validate_every = 500 }",
        "config = { bilinear = true, iterations = 150, hidden = [32, 32], n_mult = 2, batch = 32, ctrl = false, cov = false, validate_every = 50 }",
    ),
    ("\nsteps = 200\n", "\nsteps = 60\n"),
];

/// `scenarios/{file}` at the smoke budget, written inside the repository as `target/smoke-{file}`
/// (so that its commands resolve there).
fn smoke(file: &str) -> PathBuf {
    let mut text = std::fs::read_to_string(root().join("scenarios").join(file)).unwrap();
    for (from, to) in SMOKE {
        assert!(
            text.contains(from),
            "scenarios/{file} no longer has {from:?}: update SMOKE"
        );
        text = text.replace(from, to);
    }
    let path = root().join("target").join(format!("smoke-{file}"));
    std::fs::write(&path, text).unwrap();
    path
}

fn run_and_check(file: &str) {
    let out = common::scratch(file.trim_end_matches(".toml")).join("out");
    let o = common::run_scenario(&smoke(file), &out, &[]);
    assert!(
        o.status.success(),
        "{file}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let c = &r["controls"][0];
    assert_eq!(c["x"].as_array().unwrap().len(), 61, "{file}");
    assert_eq!(r["models"][0]["kind"], "bilinear", "{file}");
    let fin = r["models"][0]["control"]["final_error"].as_f64().unwrap();
    assert!(fin.is_finite() && fin >= 0.0, "{file}: final error {fin}");
    let test = r["train"][0]["metrics"]["test_prediction_error"]
        .as_f64()
        .unwrap();
    assert!(test.is_finite(), "{file}: test error {test}");
    let d = koopman::data::Dataset::load_npz(&out.join("data/pend/train.npz")).unwrap();
    assert_eq!((d.n, d.steps, d.nx, d.nu), (200, 15, 2, 1), "{file}");
}

#[test]
fn the_bilinear_pendulum_scenario_runs_at_a_smoke_budget() {
    run_and_check("damped-pendulum-bilinear.toml");
}

#[test]
fn the_bilinear_pendulum_fmu_scenario_runs_at_a_smoke_budget() {
    if !Path::new(&root().join("adapters/fmu/build/damped_pendulum.fmu")).exists()
        || !root().join(".venv/bin/python").exists()
    {
        eprintln!("skipped: the FMU or the venv is missing (run scripts/setup-python.sh)");
        return;
    }
    run_and_check("damped-pendulum-fmu-bilinear.toml");
}
