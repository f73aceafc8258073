//! `scenarios/go2-survival.toml` end to end at a smoke budget, in several processes over Zenoh
//! (issue 25): the Go2 adapter's expert collects through the `collect` request, the trainer
//! service trains the z-scored Koopman model and EDMD, and the before-control hook tracks held-out
//! expert references with the MPC service, SPEC's formulation and the recommended error-state
//! controller — the survival table (floor and every row, finite),
//! its plots and the MCAP recording are written under the run's folder.

use std::path::PathBuf;
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The shipped file with `from` replaced by `to` (each must be there: a renamed setting fails
/// here rather than silently running the default budget).
fn shrink(mut text: String, edits: &[(&str, &str)]) -> String {
    for (from, to) in edits {
        assert!(
            text.contains(from),
            "scenarios/go2-survival.toml has no '{from}'"
        );
        text = text.replace(from, to);
    }
    text
}

#[test]
fn go2_survival_scenario_runs_collect_train_and_the_survival_hook() {
    if !root().join(".venv/bin/python").exists() {
        panic!(".venv is missing: run scripts/setup-python.sh (the README's test command does)");
    }
    let text = std::fs::read_to_string(root().join("scenarios/go2-survival.toml")).unwrap();
    let text = shrink(
        text,
        &[
            ("block = 250", "block = 40"),
            ("train_windows = 3000\n", "train_windows = 120\n"),
            ("val_windows = 500\n", "val_windows = 40\n"),
            ("test_windows = 500\n", "test_windows = 40\n"),
            (
                "iterations = 3000, n_mult = 4, hidden = [128, 128], validate_every = 500",
                "iterations = 40, n_mult = 1, hidden = [32], validate_every = 20",
            ),
            (
                "\"--references\", \"50\", \"--steps\", \"300\"",
                "\"--references\", \"2\", \"--steps\", \"40\"",
            ),
        ],
    );
    let tag = format!(
        "{}-{}",
        std::process::id(),
        bridge::keyexpr::fresh_session_id()
    );
    // Inside the repository, so that `{python}` is its venv, as for the shipped file.
    let file = root().join(format!("target/kb-it-go2-{tag}.toml"));
    std::fs::write(&file, text).unwrap();
    let out = std::env::temp_dir().join(format!("kb-it-go2-{tag}"));
    let run = Command::new(env!("CARGO_BIN_EXE_koopbridge"))
        .arg("run")
        .arg(&file)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "koopbridge run failed:\n{stderr}");

    let survival = out.join("survival");
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(survival.join("report.json")).unwrap()).unwrap();
    let table = report["table"].as_array().unwrap();
    let row = |name: &str| {
        table
            .iter()
            .find(|r| r["controller"].as_str().unwrap().starts_with(name))
            .unwrap_or_else(|| panic!("no '{name}' row in {table:?}"))
    };
    for r in [
        row("open-loop replay"),
        row("go2-survival-go2 (koopman)"),
        row("go2-survival-go2-edmd (edmd)"),
        row("go2-survival-go2+error-state (koopman)"),
        row("go2-survival-go2-edmd+error-state (edmd)"),
    ] {
        let mean = r["mean"].as_f64().unwrap();
        assert!(r["n"] == 2 && (0.0..=40.0).contains(&mean), "{r}");
    }
    assert_eq!(report["task"]["steps"], 40);
    // The recommended controller's settings (docs/decisions/0017): Q on the joint positions only.
    let es = &report["task"]["error_state"];
    assert!(es["q"].as_str().unwrap().starts_with("joints"), "{es}");
    assert_eq!(es["r"], 1.0);
    let q = report["models"]["go2-survival-go2+error-state"]["weights"]["q"]
        .as_array()
        .unwrap_or_else(|| panic!("no weights.q in {}", report["models"]));
    let weighted: Vec<usize> = (0..q.len())
        .filter(|&i| q[i].as_f64().unwrap() > 0.0)
        .collect();
    assert_eq!(
        weighted,
        (10..22).collect::<Vec<_>>(),
        "Q's weighted states"
    );
    // The collection ran the noisy expert the file asks for.
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("data/go2/train.json")).unwrap()).unwrap();
    assert!(
        meta["policy"].to_string().contains("expert+noise"),
        "the training data's policy: {}",
        meta["policy"]
    );
    for f in ["survival.png", "tracking.png", "tracking.mcap", "table.md"] {
        let len = std::fs::metadata(survival.join(f)).map(|m| m.len());
        assert!(len.is_ok_and(|n| n > 0), "{f} missing or empty");
    }
    // The model the hook tracked is the one this run trained.
    let trained: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(trained["train"][0]["model"], "go2-survival-go2");
    assert!(out.join("models/go2-survival-go2/config.json").is_file());
    std::fs::remove_dir_all(&out).ok();
    std::fs::remove_file(&file).ok();
}
