//! `koopbridge run` end to end on a tiny scenario: the orchestrator starts its own simulator and
//! services, collects, trains through the trainer service, controls through the MPC service and
//! writes a consistent report; collection is bit-for-bit identical across two runs.

mod common;

use std::process::Command;

const TINY: &str = r#"
name = "tiny"
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
[train]
config = { iterations = 30, hidden = [16], n_mult = 2, batch = 16, validate_every = 15 }
[control]
x0 = [-2.5, 0.1]
reference = [0.0, 0.0]
steps = 20
"#;

fn run_once(dir: &std::path::Path) -> serde_json::Value {
    let sc = dir.join("tiny.toml");
    std::fs::write(&sc, TINY).unwrap();
    let out = dir.join("out");
    let o = Command::new(common::exe())
        .args(["run", sc.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "koopbridge run failed:\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap()
}

#[test]
fn a_tiny_scenario_runs_end_to_end_and_repeats_its_data() {
    let a = common::scratch("scn-a");
    let b = common::scratch("scn-b");
    let ra = run_once(&a);
    assert_eq!(ra["collect"]["windows"], serde_json::json!([40, 10, 10]));
    assert_eq!(ra["train"][0]["model"], "tiny-pend");
    assert!(ra["train"][0]["metrics"]["test_prediction_error"]
        .as_f64()
        .unwrap()
        .is_finite());
    let x = ra["control"]["x"].as_array().unwrap();
    assert_eq!(x.len(), 21);
    assert_eq!(x[0], serde_json::json!([-2.5, 0.1]));
    assert_eq!(ra["control"]["u"].as_array().unwrap().len(), 20);
    assert!(a.join("out/control.png").is_file());
    let rb = run_once(&b);
    assert_ne!(ra["session"], rb["session"]);
    for f in ["train", "val", "test"] {
        let p = format!("out/data/pend/{f}.npz");
        assert_eq!(
            std::fs::read(a.join(&p)).unwrap(),
            std::fs::read(b.join(&p)).unwrap(),
            "{f} differs between runs"
        );
    }
}
