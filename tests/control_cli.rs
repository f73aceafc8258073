//! `koopbridge control` as a user runs it: the pre-flight diagnostics (holding input against the
//! bounds, control authority of the model) reach stderr and `diagnostics.json`, the zero-input
//! baseline runs, and bad arguments are clear errors.

mod common;

use std::process::Command;

/// `koopbridge control --env ENV --solver zero-input --out OUT` plus `extra`.
fn zero_input(env: &str, out: &std::path::Path, extra: &[&str]) -> std::process::Output {
    Command::new(common::exe())
        .args(["control", "--env", env, "--solver", "zero-input", "--out"])
        .arg(out)
        .args(extra)
        .output()
        .expect("run koopbridge control")
}

#[test]
fn double_pendulum_target_is_reported_as_not_holdable_within_the_bounds() {
    let out_dir = common::scratch("control-double");
    let out = zero_input(
        "double-pendulum",
        &out_dir,
        &["--fit", "20", "--steps", "20"],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("no controller can hold it"), "{stderr}");
    let diag: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out_dir.join("diagnostics.json")).unwrap()).unwrap();
    // τ = G(θ) at [1.2, −0.8] (SPEC's closed form), 2.7× the ±6 bounds.
    let u = diag["holding"]["u"].as_array().unwrap();
    let g1 = 2.0 * 9.8 * 1.2f64.cos() + 9.8 * 0.4f64.cos();
    assert!((u[0].as_f64().unwrap() - g1).abs() < 1e-4, "{diag}");
    assert_eq!(diag["holding"]["within_bounds"], false);
    assert!(diag["authority"]["projection"].is_number(), "{diag}");
    // The zero-input run wrote its metrics.
    let metrics: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out_dir.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(metrics[0]["controller"], "zero-input");
    assert_eq!(metrics[0]["steps"], 20);
    // With bounds that allow the holding torque the warning goes away.
    let wide = zero_input(
        "double-pendulum",
        &out_dir.join("wide"),
        &["--fit", "20", "--steps", "5", "--u-bound", "20"],
    );
    let stderr = String::from_utf8_lossy(&wide.stderr);
    assert!(
        wide.status.success() && !stderr.contains("no controller can hold it"),
        "{stderr}"
    );
}

#[test]
fn bad_x0_is_a_clear_error() {
    let out_dir = common::scratch("control-bad-x0");
    let out = zero_input("damped-pendulum", &out_dir, &["--x0=1.0"]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("--x0 needs 2 finite values"), "{stderr}");
}

#[test]
fn the_offset_free_row_runs_on_a_lifted_model_and_needs_its_mode() {
    let out_dir = common::scratch("control-offset-free");
    let run = |extra: &[&str]| {
        Command::new(common::exe())
            .args([
                "control",
                "--env",
                "damped-pendulum",
                "--fit",
                "20",
                "--steps",
                "20",
            ])
            .args(extra)
            .arg("--out")
            .arg(&out_dir)
            .output()
            .expect("run koopbridge control")
    };
    let o = run(&["--solver", "offset-free"]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        stderr.contains("--solver offset-free needs a lifted model"),
        "{stderr}"
    );
    let o = run(&["--solver", "all", "--offset-free", "disturbance"]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let metrics: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out_dir.join("metrics.json")).unwrap()).unwrap();
    let names: Vec<&str> = metrics
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m["controller"].as_str().unwrap())
        .collect();
    assert!(
        names.contains(&"koopman-mpc/dedicated+disturbance")
            && names.contains(&"koopman-mpc/dedicated"),
        "{names:?}"
    );
    assert!(out_dir.join("metrics-offset-free.json").is_file());
}
