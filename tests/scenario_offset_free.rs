//! `[control] offset_free` on a lifted-linear model through a real scenario run: the MPC service
//! takes the correction, the report records it, and the closed loop is the plain one until the
//! correction has a prediction error to act on, then another (the same model, reused).

mod common;

const LINEAR: &str = r#"
name = "linoff"
[[sims]]
id = "pend"
env = "damped-pendulum"
[collect]
policy = { kind = "uniform" }
train_windows = 20
val_windows = 5
test_windows = 0
steps = 10
seed = 5
[train]
config = { iterations = 20, hidden = [8], n_mult = 2, batch = 8, validate_every = 10 }
[control]
x0 = [0.3, 0.0]
reference = [0.0, 0.0]
steps = 8
mpc = { horizon = 5 }
"#;

fn report(out: &std::path::Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap()
}

#[test]
fn a_linear_models_offset_free_correction_runs_through_the_service() {
    let dir = common::scratch("linoff");
    let out = dir.join("out");
    let sc = dir.join("linoff.toml");
    std::fs::write(&sc, LINEAR).unwrap();
    common::run_scenario(&sc, &out, &[]);
    let plain = report(&out);
    assert!(plain["control"].get("offset_free").is_none());
    // The same model (reused: [collect] and [train] are unchanged), now with the correction.
    let with = LINEAR.replace(
        "mpc = { horizon = 5 }",
        "mpc = { horizon = 5 }\noffset_free = { mode = \"disturbance\", radius = 10.0, gain = [0.5, 0.5], angles = [0] }",
    );
    std::fs::write(&sc, with).unwrap();
    let o = common::run_scenario(&sc, &out, &[]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(stderr.contains("reusing model 'linoff-pend'"), "{stderr}");
    let corrected = report(&out);
    let c = &corrected["control"];
    assert_eq!(c["offset_free"]["mode"], "disturbance", "{c}");
    assert_eq!(c["not_solved"], 0);
    let (ux, uy) = (&plain["control"]["u"], &c["u"]);
    // Step 0 has no prediction error yet: the plain MPC's input. From step 1 on the estimate
    // (the trained model's one-step error on the plant) moves the plan.
    assert_eq!(ux[0], uy[0]);
    assert_ne!(ux, uy, "the correction changed nothing");
}
