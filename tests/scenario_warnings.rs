//! A scenario whose MPC cannot solve (state bounds no plan can meet) still runs to the end, but
//! says so: `not_solved` with its statuses in report.json and the console summary, a warning on
//! stderr and in the report's `warnings`. The same run collects with the lockstep uniform
//! policy's `low`/`high`, which the data and its metadata honour.

mod common;

use koopman::data::Dataset;

const UNSOLVABLE: &str = r#"
name = "unsolvable"
[[sims]]
id = "pend"
env = "damped-pendulum"
[collect]
policy = { kind = "uniform", low = -0.5, high = [0.25] }
train_windows = 20
val_windows = 5
test_windows = 0
steps = 10
seed = 3
[train]
config = { iterations = 20, hidden = [8], n_mult = 2, batch = 8, validate_every = 10 }
[control]
x0 = [-1.0, 0.1]
reference = [0.0, 0.0]
steps = 6
# Every predicted angle in [5, 6] rad: no input within the bounds gets there in one step.
mpc = { horizon = 5, solver = "clarabel", x_min = [5.0, -100.0], x_max = [6.0, 100.0] }
"#;

#[test]
fn an_unsolvable_mpc_is_reported_and_warned_about() {
    let dir = common::scratch("unsolvable");
    let sc = dir.join("unsolvable.toml");
    std::fs::write(&sc, UNSOLVABLE).unwrap();
    let out = dir.join("out");
    let o = common::run_scenario(&sc, &out, &[]);
    let (stdout, stderr) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let c = &r["control"];
    assert_eq!(c["not_solved"], 6, "{c}");
    assert_eq!(
        c["not_solved_by_status"],
        serde_json::json!({ "fallback": 6 })
    );
    let warnings = r["warnings"].as_array().expect("warnings in the report");
    // The unsolved steps, then the missed goal with the diagnosis's next step.
    assert_eq!(warnings.len(), 2, "{warnings:?}");
    let missed = warnings[1].as_str().unwrap();
    assert!(
        missed.contains("did not reach its goal")
            && missed.contains("next: the MPC did not solve most steps"),
        "{missed}"
    );
    assert_eq!(r["diagnoses"][0]["model"], c["model"]);
    let w = warnings[0].as_str().unwrap();
    assert!(
        w.contains("did not solve 6 of 6 steps (fallback 6)") && w.contains("'pend'"),
        "{w}"
    );
    assert!(stderr.contains(&format!("warning: {w}")), "{stderr}");
    assert!(
        stdout.contains("not solved 6 of 6 (fallback 6)"),
        "{stdout}"
    );
    // The lockstep uniform policy drew within its own bounds, and the metadata says which.
    let d = Dataset::load_npz(&out.join("data/pend/train.npz")).unwrap();
    assert_eq!(d.meta.policy, "uniform low=[-0.5] high=[0.25]");
    assert!(d.u.iter().all(|u| (-0.5..=0.25).contains(u)), "{:?}", d.u);
    let (lo, hi) =
        d.u.iter()
            .fold((f64::MAX, f64::MIN), |(l, h), &u| (l.min(u), h.max(u)));
    assert!(
        lo < -0.4 && hi > 0.15,
        "the inputs do not span the bounds: [{lo}, {hi}]"
    );
    // With --fail-on-warning the same run (data and model reused) fails, after its report.
    std::fs::remove_file(out.join("report.json")).unwrap();
    let strict = std::process::Command::new(common::exe())
        .args(["run", sc.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .arg("--fail-on-warning")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&strict.stderr);
    assert_eq!(strict.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("2 warning(s) and --fail-on-warning"),
        "{stderr}"
    );
    assert!(out.join("report.json").is_file());
}

#[test]
fn uniform_bounds_beyond_the_simulators_fail_before_collection() {
    let dir = common::scratch("unsolvable-bounds");
    let sc = dir.join("bounds.toml");
    std::fs::write(&sc, UNSOLVABLE.replace("high = [0.25]", "high = [100.0]")).unwrap();
    let out = dir.join("out");
    let o = std::process::Command::new(common::exe())
        .args(["run", sc.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        stderr.contains("simulator 'pend'") && stderr.contains("exceed the simulator's"),
        "{stderr}"
    );
    assert!(!out.join("data/pend/train.npz").exists());
}
