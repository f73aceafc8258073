//! `koopbridge run` with the scenario extras: a time-varying reference from a `.npy` a hook
//! writes into `{out}`, hooks at every phase (placeholders, logs, a failing hook naming itself),
//! and extra participants (one that dies names itself; a real Python planner is awaited).

mod common;

use std::path::{Path, PathBuf};
use std::process::Output;

fn run(dir: &Path, name: &str, text: &str, extra: &[&str]) -> (Output, PathBuf) {
    common::run_scenario_text(dir, name, text, extra)
}

fn json(p: &Path) -> serde_json::Value {
    common::json_file(p)
}

const BASE: &str = r#"
[[sims]]
id = "pend"
env = "damped-pendulum"
[collect]
policy = { kind = "uniform" }
train_windows = 40
val_windows = 10
test_windows = 10
steps = 15
seed = 7
"#;

#[test]
fn a_reference_file_written_by_a_hook_is_tracked_and_every_hook_runs_in_its_phase() {
    let dir = common::scratch("extras-ref");
    // Row k = [0.05 k, 0.05] for k < 10, then the last row repeats.
    let rows: Vec<[f64; 2]> = (0..10).map(|k| [0.05 * k as f64, 0.05]).collect();
    let src = dir.join("ramp.npy");
    let flat: Vec<f64> = rows.iter().flatten().copied().collect();
    std::fs::write(&src, koopman::data::npy::encode(&[10, 2], &flat)).unwrap();
    let text = format!(
        r#"name = "extras"
{BASE}
[train]
config = {{ iterations = 30, hidden = [16], n_mult = 2, batch = 16, validate_every = 15 }}
[control]
x0 = [0.0, 0.0]
reference_file = "{{out}}/ref.npy"
steps = 20
mpc = {{ horizon = 5 }}
[[hooks]]
phase = "before-collect"
command = "echo {{session}} {{connect}} > {{out}}/placeholders.txt; test ! -e {{out}}/data/pend/train.npz"
[[hooks]]
phase = "before-control"
command = ["cp", "{src}", "{{out}}/ref.npy"]
[[hooks]]
phase = "after-control"
command = "cp {{out}}/report.json {{out}}/report-seen.json"
"#,
        src = src.display()
    );
    let (o, out) = run(&dir, "extras", &text, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r = json(&out.join("report.json"));
    // The after-control hook saw the final report.
    assert_eq!(json(&out.join("report-seen.json")), r);
    let ph = std::fs::read_to_string(out.join("placeholders.txt")).unwrap();
    let session = r["session"].as_str().unwrap();
    assert!(ph.starts_with(&format!("{session} tcp/127.0.0.1:")), "{ph}");
    for n in 1..=3 {
        assert!(out.join(format!("logs/hook-{n}.log")).is_file());
    }
    let c = &r["control"];
    assert_eq!(c, &r["controls"][0]);
    let x: Vec<Vec<f64>> = serde_json::from_value(c["x"].clone()).unwrap();
    let refs: Vec<Vec<f64>> = serde_json::from_value(c["reference_trajectory"].clone()).unwrap();
    assert_eq!(x.len(), 21);
    assert_eq!(refs.len(), 21);
    for (k, rk) in refs.iter().enumerate() {
        assert_eq!(rk[..], rows[k.min(9)][..], "reference row {k}");
    }
    // Tracking figures recomputed here from the executed states (no angle wraps this close to 0).
    let err: Vec<[f64; 2]> = x
        .iter()
        .zip(&refs)
        .map(|(a, b)| [a[0] - b[0], a[1] - b[1]])
        .collect();
    let n = err.len() as f64;
    for i in 0..2 {
        let rms = (err.iter().map(|e| e[i] * e[i]).sum::<f64>() / n).sqrt();
        let got = c["tracking_rms"][i].as_f64().unwrap();
        assert!(
            (got - rms).abs() <= 1e-12 * rms.max(1.0),
            "state {i}: {got} vs {rms}"
        );
    }
    let total = (err.iter().flatten().map(|v| v * v).sum::<f64>() / (2.0 * n)).sqrt();
    assert!((c["tracking_rms_total"].as_f64().unwrap() - total).abs() <= 1e-12);
    let e: Vec<f64> = serde_json::from_value(c["error"].clone()).unwrap();
    for (k, ek) in err.iter().enumerate() {
        assert!(
            (e[k] - ek[0].hypot(ek[1])).abs() <= 1e-12,
            "error at step {k}"
        );
    }
    assert!(out.join("control.png").is_file());
    assert_eq!(r["control_loop"]["macro_steps"], 20);
}

#[test]
fn a_failing_hook_fails_the_run_before_collection_naming_itself() {
    let dir = common::scratch("extras-hook");
    let text = format!(
        "name = \"badhook\"\n{BASE}\n[[hooks]]\nphase = \"before-collect\"\ncommand = \"echo broken-hook-output; exit 7\"\n"
    );
    let (o, out) = run(&dir, "badhook", &text, &[]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("hook 1 (before-collect) failed"), "{err}");
    assert!(
        err.contains("exit 7") && err.contains("broken-hook-output"),
        "{err}"
    );
    assert!(!out.join("data/pend/train.npz").exists());
}

#[test]
fn a_participant_that_dies_fails_the_run_naming_it() {
    let dir = common::scratch("extras-dies");
    let text = format!(
        "name = \"dies\"\n{BASE}\n[[participants]]\nid = \"p\"\nrole = \"planner\"\ncommand = [\"sh\", \"-c\", \"echo planner-dies; exit 3\"]\n"
    );
    let (o, out) = run(&dir, "dies", &text, &["--ready-timeout", "30"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("participant planner/p exited"), "{err}");
    assert!(err.contains("planner-dies"), "{err}");
    assert!(!out.join("data/pend/train.npz").exists());
}

/// A minimal planner served by the Python SDK's `PlannerService` (the same flags as every
/// koopbridge adapter; it stops when its standard input closes).
const PLANNER: &str = r#"
import argparse, sys, threading
from koopbridge._native import PlannerService
p = argparse.ArgumentParser()
p.add_argument("--id"); p.add_argument("--session")
p.add_argument("--connect", action="append", default=[])
p.add_argument("--stdin-lifeline", action="store_true")
a = p.parse_args()
svc = PlannerService(lambda start, goal, dt: {"t": [0.0], "q": [goal], "qd": [[0.0, 0.0]], "duration": 0.0, "dt": dt, "passes": []}, 2)
threading.Thread(target=lambda: (sys.stdin.read(), svc.stop()), daemon=True).start()
print("planner serving", a.id, flush=True)
svc.serve(session=a.session, id=a.id, connect=a.connect)
"#;

#[test]
fn a_python_planner_participant_is_awaited_and_stopped_with_the_run() {
    let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv/bin/python");
    if !venv.exists() {
        eprintln!("skipped: no .venv (run scripts/setup-python.sh)");
        return;
    }
    let dir = common::scratch("extras-planner");
    std::fs::write(dir.join("planner.py"), PLANNER).unwrap();
    let text = format!(
        "name = \"planner\"\n{BASE}\n[[participants]]\nid = \"plan0\"\nrole = \"planner\"\ncommand = \"{} planner.py\"\n",
        venv.display()
    );
    let (o, out) = run(&dir, "planner", &text, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let log = std::fs::read_to_string(out.join("logs/planner-plan0.log")).unwrap();
    assert!(log.contains("planner serving plan0"), "{log}");
    assert!(out.join("data/pend/train.npz").is_file());
}
