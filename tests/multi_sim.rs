//! `scenarios/multi-sim.toml` end to end at a smoke budget (its default budget takes minutes):
//! two FMUs (FMI 2 and 3), a built-in Rust system, the MuJoCo Franka, the Drake Kinova and the
//! MuJoCo Go2 (with its own expert inputs and training settings) collected, trained and
//! controlled in one lockstep loop; a Go2 control entry of the wrong length refused before
//! collection; and (ignored: a measurement) the loop's macro-step rate against the slowest
//! simulator alone in the same run.

mod common;

use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The Python set-up the scenario needs (scripts/setup-python.sh), or why it is missing.
fn python_ready() -> Result<(), String> {
    for p in [
        ".venv/bin/python",
        "adapters/fmu/build/damped_pendulum.fmu",
        "adapters/fmu/build/double_pendulum.fmu",
    ] {
        if !root().join(p).exists() {
            return Err(format!("{p} is missing (run scripts/setup-python.sh)"));
        }
    }
    Ok(())
}

/// The file's budget lines and CI's smoke values for them (60 windows, a small model, 100 control
/// steps for every simulator).
const SMOKE: [(&str, &str); 4] = [
    (
        "train_windows = 600\nval_windows = 60\ntest_windows = 60\n",
        "train_windows = 60\nval_windows = 12\ntest_windows = 12\n",
    ),
    (
        "config = { iterations = 3000, hidden = [128, 128], n_mult = 8, ctrl = false, cov = false, validate_every = 500 }",
        "config = { iterations = 200, hidden = [32, 32], n_mult = 2, batch = 32, ctrl = false, cov = false, validate_every = 100 }",
    ),
    ("\nsteps = 300\n", "\nsteps = 100\n"),
    ("\nsteps = 200\n", "\nsteps = 100\n"),
];

/// `scenarios/multi-sim.toml` at the smoke budget with `steps = 100` replaced by `steps`, written
/// inside the repository as `target/{file}` (so that its commands resolve there); the scenario
/// name, and so the model names, are unchanged.
fn smoke_scenario(file: &str, steps: usize) -> PathBuf {
    let mut text = std::fs::read_to_string(root().join("scenarios/multi-sim.toml")).unwrap();
    for (from, to) in SMOKE {
        assert!(
            text.contains(from),
            "scenarios/multi-sim.toml no longer has {from:?}: update SMOKE"
        );
        text = text.replace(from, to);
    }
    let text = text.replace("\nsteps = 100\n", &format!("\nsteps = {steps}\n"));
    let path = root().join("target").join(file);
    std::fs::write(&path, text).unwrap();
    path
}

fn run(scenario: &Path, out: &Path, extra: &[&str]) -> serde_json::Value {
    let o = common::run_scenario(scenario, out, extra);
    eprintln!("{}", String::from_utf8_lossy(&o.stdout));
    serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap()
}

const SIMS: [&str; 6] = [
    "pend-fmu",
    "double-fmu",
    "rust-pend",
    "franka",
    "kinova",
    "go2",
];

#[test]
fn the_multi_sim_scenario_collects_trains_and_controls_every_simulator_in_one_loop() {
    if let Err(why) = python_ready() {
        eprintln!("skipped: {why}");
        return;
    }
    let out = common::scratch("multi-sim").join("out");
    let r = run(&smoke_scenario("multi-sim-smoke.toml", 100), &out, &[]);
    assert_eq!(r["collect"]["sims"], serde_json::json!(SIMS));
    let nx = [2, 4, 2, 14, 14, 35];
    for (j, id) in SIMS.iter().enumerate() {
        let c = &r["controls"][j];
        assert_eq!(c["sim"], *id);
        assert_eq!(c["model"], format!("multi-sim-{id}"));
        let x = c["x"].as_array().unwrap();
        assert_eq!(x.len(), 101, "{id}");
        assert_eq!(x[0].as_array().unwrap().len(), nx[j], "{id}");
        assert_eq!(c["u"].as_array().unwrap().len(), 100, "{id}");
        assert!(
            c["tracking_rms_total"].as_f64().unwrap().is_finite(),
            "{id}"
        );
        assert!(r["train"][j]["metrics"]["test_prediction_error"]
            .as_f64()
            .unwrap()
            .is_finite());
        let png = if j == 0 {
            "control.png".to_string()
        } else {
            format!("control-{id}.png")
        };
        assert!(out.join(png).is_file(), "{id}");
        // The simulators' data were collected together, from their own info.
        let d = common::collected(&out, id, "train");
        assert_eq!((d.n, d.steps, d.nx), (60, 15, nx[j]));
        // rust-pend and kinova have their own data region ([[sims]] x0_center/x0_radius): it
        // reached the simulator (every window starts in it) and the metadata record it.
        if matches!(*id, "rust-pend" | "kinova") {
            let reg = d.meta.region.as_ref().expect("the region in the metadata");
            let (lo, hi) = (reg.x0_low.clone().unwrap(), reg.x0_high.clone().unwrap());
            for w in 0..d.n {
                let x0 = &d.x[w * 16 * nx[j]..w * 16 * nx[j] + nx[j]];
                assert!(
                    x0.iter()
                        .zip(lo.iter().zip(&hi))
                        .all(|(v, (l, h))| l <= v && v <= h),
                    "{id} window {w} starts at {x0:?}, outside {lo:?}..{hi:?}"
                );
            }
        } else {
            assert!(d.meta.region.is_none(), "{id}");
        }
        // The Go2 collected with its own inputs (the expert) and trained with its own settings
        // (z-scored, n_mult 4: N = 35 · 5) over the smoke's shared ones (raw, n_mult 2).
        let model: serde_json::Value = serde_json::from_slice(
            &std::fs::read(out.join(format!("models/multi-sim-{id}/config.json"))).unwrap(),
        )
        .unwrap();
        if *id == "go2" {
            assert_eq!(d.meta.policy, r#"adapter-{"kind":"expert"}"#);
            assert_eq!(model["latent_dim"], 175);
            assert!(
                model["normalisation"].is_object(),
                "{}",
                model["normalisation"]
            );
            // A fall is in its control entry (step_flags), with the step it began.
            let f = &c["step_flags"];
            assert!(
                f.is_null() || f["first_terminated"].is_u64() == (f["terminated"] != 0),
                "{f}"
            );
        } else {
            assert_eq!(d.meta.policy, "adapter-uniform", "{id}");
            assert_eq!(model["latent_dim"], nx[j] * 3, "{id}");
            assert!(model["normalisation"].is_null(), "{id}");
        }
    }
    assert_eq!(r["control"], r["controls"][0]);
    let l = &r["control_loop"];
    assert_eq!(l["sims"], serde_json::json!(SIMS));
    assert_eq!(l["macro_steps"], 100);
    assert!(l["macro_steps_per_second"].as_f64().unwrap() > 0.0);
    assert_eq!(l["step_round_trip_median_us"].as_array().unwrap().len(), 6);
    // After the warm-up the loop named its critical path, and every other simulator (all were
    // started by this run) was given a lower CPU priority.
    let critical = l["critical_path"].as_str().expect("a critical path");
    let others: Vec<&str> = SIMS.iter().copied().filter(|s| *s != critical).collect();
    assert_eq!(others.len(), 5, "{critical} is not one of {SIMS:?}");
    assert_eq!(l["deprioritised"], serde_json::json!(others));
}

/// The Go2's `[[sims]]` and `[[control]]` entries of `scenarios/multi-sim.toml`, as they are there.
fn go2_entries() -> (String, String) {
    let text = std::fs::read_to_string(root().join("scenarios/multi-sim.toml")).unwrap();
    let block = |start: &str| {
        let i = text.find(start).unwrap_or_else(|| panic!("no {start:?}"));
        let rest = &text[i..];
        let end = rest[1..].find("\n[").map_or(rest.len(), |e| e + 1);
        rest[..end].to_string()
    };
    (
        block("[[sims]]\nid = \"go2\""),
        block("[[control]]\nsim = \"go2\""),
    )
}

#[test]
fn a_go2_control_entry_of_the_wrong_length_fails_before_collection_naming_it() {
    if let Err(why) = python_ready() {
        eprintln!("skipped: {why}");
        return;
    }
    let (sim, control) = go2_entries();
    let dir = common::scratch("multi-sim-go2-bad");
    // Cut one value off x0, then off the reference (the last one: `, 0.2…]` → `]`).
    let cut = |key: &str| {
        let line = control
            .lines()
            .find(|l| l.starts_with(&format!("{key} = [")))
            .unwrap();
        let short = format!("{}]", &line[..line.rfind(", ").unwrap()]);
        control.replace(line, &short)
    };
    for (i, (entry, expect)) in [
        (
            cut("x0"),
            "x0 has 34 values, the simulator has 35 states (base_qw",
        ),
        (cut("reference"), "reference has 34 values; expected 35"),
    ]
    .into_iter()
    .enumerate()
    {
        let text = format!(
            "name = \"go2-bad\"\n{sim}\n[collect]\npolicy = {{ kind = \"adapter\", block = 4 }}\n\
             train_windows = 4\nval_windows = 4\ntest_windows = 4\n[train]\nconfig = {{ iterations = 5 }}\n\n{entry}"
        );
        // Inside the repository, so that `{python}` is its venv.
        let file = root().join("target").join(format!("go2-bad-{i}.toml"));
        std::fs::write(&file, text).unwrap();
        let out = dir.join(format!("out{i}"));
        let stderr = common::run_scenario_refused(&file, &out, &format!("case {i}"));
        assert!(
            stderr.contains("[control] for simulator 'go2'") && stderr.contains(expect),
            "case {i}: {stderr}"
        );
        assert!(!out.join("data/go2").exists(), "case {i} collected");
        assert!(!out.join("report.json").exists(), "case {i} reported");
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// The figure of issue 14: the macro-step rate of the five-simulator control loop against the
/// slowest simulator alone in the same loop, measured in one run (500 control steps, the smoke
/// budget's models). Run with
/// `cargo test --release --test multi_sim -- --ignored --nocapture`.
#[test]
#[ignore]
fn the_multi_sim_loop_against_the_slowest_simulator_alone() {
    python_ready().expect("the Python set-up");
    let file = smoke_scenario("multi-sim-bench.toml", 500);
    let out = common::scratch("multi-sim-bench").join("out");
    let r = run(&file, &out, &["--loop-baseline"]);
    let l = &r["control_loop"];
    eprintln!("{}", serde_json::to_string_pretty(l).unwrap());
    let ratio = l["slowdown_vs_slowest_alone"].as_f64().unwrap();
    eprintln!(
        "loop: {:.0} macro steps/s; alone: {}; slowdown vs the slowest alone: {ratio:.3}",
        l["macro_steps_per_second"].as_f64().unwrap(),
        l["alone_steps_per_second"]
    );
    assert!(ratio.is_finite() && ratio > 0.0);
}
