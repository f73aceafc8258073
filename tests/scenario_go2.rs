//! `scenarios/go2-survival.toml` end to end at a smoke budget, in several processes over Zenoh
//! (issue 25): the Go2 adapter's expert collects through the `collect` request, the trainer
//! service trains the z-scored Koopman model and EDMD, the before-control hook writes held-out
//! expert references, and the scenario engine tracks them (issue 47) with the MPC service, SPEC's
//! formulation and the recommended error-state controller — the survival rows (replay and every
//! model, finite), the table and plot, the RL expert's row and the perturbation suite. Until
//! session 27 this test also ran the Python loop that tracked this task before the engine did, on
//! the same references and models, and compared the survival per reference and the on-policy
//! windows row by row; that comparison had held on every CI run since session 24, and the Python
//! loop was deleted in session 27.

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
fn the_go2_toml_runs_end_to_end_in_the_engine() {
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

    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let tasks = report["tracking"]
        .as_array()
        .expect("report.json has `tracking`");
    let labels: Vec<&str> = tasks
        .iter()
        .map(|t| t["label"].as_str().unwrap_or(""))
        .collect();
    assert_eq!(
        labels,
        [
            "",
            "error-state",
            "push",
            "mass",
            "friction",
            "mass-friction"
        ],
        "SPEC's task, the recommended controller's and the perturbation suite"
    );
    let row = |task: usize, name: &str| {
        let rows = tasks[task]["rows"].as_array().unwrap();
        rows.iter()
            .find(|r| r["row"] == name)
            .unwrap_or_else(|| panic!("no row '{name}' in task {task}: {rows:?}"))
            .clone()
    };
    let rows = [
        row(0, "replay"),
        row(0, "go2-survival-go2"),
        row(0, "go2-survival-go2-edmd"),
        row(1, "go2-survival-go2+error-state"),
        row(1, "go2-survival-go2-edmd+error-state"),
    ];
    for r in &rows {
        let mean = r["survival"]["mean"].as_f64().unwrap();
        assert!(
            r["survival"]["n"] == 2 && (0.0..=40.0).contains(&mean),
            "{r}"
        );
    }
    assert_eq!(tasks[0]["steps"], 40);
    // The recommended controller's settings (docs/decisions/0017): Q on the joint positions only,
    // R = I.
    let es = &rows[3]["mpc"];
    let q = es["q"]
        .as_array()
        .unwrap_or_else(|| panic!("no mpc.q in {es}"));
    let weighted: Vec<usize> = (0..q.len())
        .filter(|&i| q[i].as_f64().unwrap() > 0.0)
        .collect();
    assert_eq!(
        weighted,
        (10..22).collect::<Vec<_>>(),
        "Q's weighted states"
    );
    assert!(es["r"].as_array().unwrap().iter().all(|v| v == 1.0), "{es}");
    // The RL expert's row (the after-control hook `legged_expert_row`): every survival task but
    // aggregation, its survivals within the references' length.
    let expert = report["expert"]["tasks"]
        .as_array()
        .unwrap_or_else(|| panic!("no expert row in report.json: {}", report["expert"]));
    let names: Vec<&str> = expert.iter().map(|e| e["task"].as_str().unwrap()).collect();
    assert_eq!(
        names,
        [
            "nominal",
            "error-state",
            "push",
            "mass",
            "friction",
            "mass-friction"
        ]
    );
    for e in expert {
        let s = e["survivals"].as_array().unwrap();
        assert!(
            s.len() == 2 && s.iter().all(|v| v.as_u64().is_some_and(|v| v <= 40)),
            "{e}"
        );
    }
    for f in [
        "tracking/survival.png",
        "tracking/table.md",
        "tracking/expert.md",
    ] {
        let len = std::fs::metadata(out.join(f)).map(|m| m.len());
        assert!(len.is_ok_and(|n| n > 0), "{f} missing or empty");
    }

    // The perturbation suite: each reference's push drawn in its window and sent with the
    // resets; every perturbed task has its own replay row, and a heavier trunk changes it.
    let pushes = tasks[2]["perturbations"].as_array().unwrap();
    assert_eq!(pushes.len(), 2);
    for p in pushes {
        let (step, v) = (&p["push"]["step"], &p["push"]["velocity"]);
        let speed = v[0].as_f64().unwrap().hypot(v[1].as_f64().unwrap());
        assert!(
            (20..80).contains(&step.as_u64().unwrap()) && (speed - 1.0).abs() < 1e-9,
            "{p}"
        );
    }
    for t in &tasks[2..] {
        assert_eq!(t["rows"][0]["row"], "replay");
        let name = format!("go2-survival-go2+{}", t["label"].as_str().unwrap());
        assert_eq!(t["rows"][1]["row"], name.as_str());
    }
    assert_eq!(tasks[3]["perturbations"][0]["mass_scale"], 1.2);
    assert_ne!(
        tasks[3]["rows"][0]["tracking_rms"], rows[0]["tracking_rms"],
        "the heavier trunk changed the replay"
    );

    // The collection ran the noisy expert the file asks for.
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("data/go2/train.json")).unwrap()).unwrap();
    assert!(
        meta["policy"].to_string().contains("expert+noise"),
        "the training data's policy: {}",
        meta["policy"]
    );
    assert_eq!(report["train"][0]["model"], "go2-survival-go2");
    assert!(out.join("models/go2-survival-go2/config.json").is_file());
    std::fs::remove_dir_all(&out).ok();
    std::fs::remove_file(&file).ok();
}
