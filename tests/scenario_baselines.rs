//! `koopbridge run` with several labelled `[[control]]` entries on one simulator: the MPC row and
//! the baselines that need no model (`controller = "zero-input"`, `"feedforward"` with and
//! without a position loop) run one after another on the built-in damped pendulum, each from its
//! own start, and every baseline's states are the pendulum stepped here with the inputs its rule
//! gives (the independent computation).

mod common;

use common::faults::local_states;

/// The plan: 21 states (θ_k = 0.5 − 0.02 k, θ̇ = 0) and the 20 torques that "realise" it.
fn plan() -> (Vec<[f64; 2]>, Vec<f64>) {
    let states = (0..21).map(|k| [0.5 - 0.02 * k as f64, 0.0]).collect();
    let inputs = (0..20).map(|k| 1.5 * (0.3 * k as f64).sin()).collect();
    (states, inputs)
}

fn scenario(dir: &std::path::Path) -> std::path::PathBuf {
    let (states, inputs) = plan();
    let flat: Vec<f64> = states.iter().flatten().copied().collect();
    std::fs::write(
        dir.join("plan.npy"),
        koopman::data::npy::encode(&[21, 2], &flat),
    )
    .unwrap();
    std::fs::write(
        dir.join("ff.npy"),
        koopman::data::npy::encode(&[20, 1], &inputs),
    )
    .unwrap();
    let plan = dir.join("plan.npy").display().to_string();
    let ff = dir.join("ff.npy").display().to_string();
    let text = format!(
        "name = \"rows\"\n{base}\
         [control_defaults]\nx0 = [0.4, 0.1]\nsteps = 20\n\
         [[control]]\nlabel = \"mpc\"\nreference = [0.0, 0.0]\n\
         [[control]]\nlabel = \"zero\"\ncontroller = \"zero-input\"\nreference = [0.0, 0.0]\n\
         [[control]]\nlabel = \"ff\"\ncontroller = \"feedforward\"\nreference_file = \"{plan}\"\n\
         feedforward_file = \"{ff}\"\nmpc = {{ u_min = [-1.0], u_max = [1.0] }}\n\
         [[control]]\nlabel = \"ff-loop\"\ncontroller = \"feedforward\"\nreference_file = \"{plan}\"\n\
         feedforward_file = \"{ff}\"\nposition_loop = {{ position = [0], velocity = [1], gain = 20.0 }}\n\
         mpc = {{ u_min = [-2.0], u_max = [2.0] }}\n",
        base = common::PENDULUM_BASE
    );
    let sc = dir.join("rows.toml");
    std::fs::write(&sc, text).unwrap();
    sc
}

fn floats(v: &serde_json::Value) -> Vec<Vec<f64>> {
    serde_json::from_value(v.clone()).unwrap()
}

#[test]
fn labelled_rows_run_one_after_another_and_the_baselines_follow_their_rules() {
    let dir = common::scratch("scn-rows");
    let out = dir.join("out");
    let o = common::run_scenario(&scenario(&dir), &out, &[]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let rows = r["controls"].as_array().unwrap();
    let labels: Vec<&str> = rows.iter().map(|c| c["label"].as_str().unwrap()).collect();
    assert_eq!(labels, ["mpc", "zero", "ff", "ff-loop"]);
    let controllers: Vec<&str> = rows
        .iter()
        .map(|c| c["controller"].as_str().unwrap())
        .collect();
    assert_eq!(
        controllers,
        ["mpc", "zero-input", "feedforward", "feedforward"]
    );
    assert_eq!(r["control"]["label"], "mpc", "`control` is the first entry");
    let (states, inputs) = plan();

    // Zero input: the pendulum left alone from x0.
    assert_eq!(floats(&rows[1]["x"]), local_states(&[0.4, 0.1], &[0.0; 20]));
    assert!(floats(&rows[1]["u"]).iter().all(|u| u == &[0.0]));
    // The plan's inputs open loop, clipped to the entry's bounds (±1: the plan reaches ±1.5).
    let clipped: Vec<f64> = inputs.iter().map(|u| u.clamp(-1.0, 1.0)).collect();
    assert_ne!(clipped, inputs);
    assert_eq!(floats(&rows[2]["x"]), local_states(&[0.4, 0.1], &clipped));
    // With the loop: u_k = clip(u_ff,k − 20 (θ_k − θ_plan,k), ±2), the entry's own bounds.
    let x = floats(&rows[3]["x"]);
    let want_u: Vec<f64> = (0..20)
        .map(|k| (inputs[k] - 20.0 * (x[k][0] - states[k][0])).clamp(-2.0, 2.0))
        .collect();
    let u: Vec<f64> = floats(&rows[3]["u"]).into_iter().map(|u| u[0]).collect();
    for (a, b) in u.iter().zip(&want_u) {
        assert!((a - b).abs() < 1e-12, "{u:?}\n{want_u:?}");
    }
    assert!(
        u.iter().any(|v| v.abs() == 2.0),
        "the clip is exercised: {u:?}"
    );
    assert_eq!(x, local_states(&[0.4, 0.1], &u));
    // The MPC row solved; the baselines asked no solver.
    assert!(rows[0]["solve_median_us"].as_f64().unwrap() > 0.0);
    assert!(rows[1..]
        .iter()
        .all(|c| c["solve_median_us"].as_f64().unwrap() == 0.0));
    for label in ["zero", "ff", "ff-loop"] {
        assert!(
            out.join(format!("control-{label}.png")).is_file(),
            "{label}"
        );
        let line = stdout
            .lines()
            .find(|l| l.contains(&format!("control of 'pend' ({label})")))
            .unwrap_or_else(|| panic!("no summary of {label}:\n{stdout}"));
        assert!(
            line.contains("(no model)") && !line.contains("solve median"),
            "{line}"
        );
    }
    assert!(out.join("control.png").is_file());
    assert!(stdout
        .lines()
        .any(|l| l.contains("control of 'pend' (mpc)") && l.contains("solve median")));
}

#[test]
fn an_unlabelled_second_entry_for_a_simulator_is_refused_before_anything_starts() {
    let dir = common::scratch("scn-rows-bad");
    let text = format!(
        "name = \"rows-bad\"\n{}\
         [[control]]\nx0 = [0.4, 0.1]\nreference = [0.0, 0.0]\nsteps = 5\n\
         [[control]]\ncontroller = \"zero-input\"\nx0 = [0.4, 0.1]\nreference = [0.0, 0.0]\nsteps = 5\n",
        common::PENDULUM_BASE
    );
    let sc = dir.join("bad.toml");
    std::fs::write(&sc, text).unwrap();
    let err = common::run_scenario_refused(&sc, &dir.join("out"), "two unlabelled entries");
    assert!(err.contains("distinct `label`"), "{err}");
    assert!(!dir.join("out/data").exists(), "nothing collected");
}

#[test]
fn aggregation_over_labelled_rows_is_refused_before_anything_starts() {
    let dir = common::scratch("scn-rows-agg");
    let text = format!(
        "name = \"rows-agg\"\n{}\
         [[control]]\nlabel = \"mpc\"\nx0 = [0.4, 0.1]\nreference = [0.0, 0.0]\nsteps = 5\n",
        common::PENDULUM_BASE
    );
    let (o, out) = common::run_scenario_text(&dir, "agg", &text, &["--aggregate", "1"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("labelled [control] entries"), "{err}");
    assert!(!out.join("data").exists(), "nothing collected");
}
