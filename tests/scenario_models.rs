//! Several model kinds in one scenario (`[train] model = ["koopman", "edmd"]`) end to end on the
//! built-in damped pendulum: the trainer service trains one model of each kind into its own
//! folder, the MPC service controls the pendulum with each (the first input of each run equals
//! the one that kind's controller computes in this process from the stored model), the report
//! and the printed summary set them side by side, and the test prediction errors the trainer
//! reported equal the ones computed here; a rerun with the kinds in the other order reuses both
//! models. Bad kinds are refused with the reason (an NNDM's random shooting with an input
//! weight, a bilinear model without inputs: before collection).

mod common;

use koopman::data::Dataset;
use koopman::mpc::{LoadedModel, MpcConfig};

const SCENARIO: &str = r#"
name = "kinds"
[[sims]]
id = "pend"
env = "damped-pendulum"
[collect]
policy = { kind = "uniform" }
train_windows = 200
val_windows = 20
test_windows = 20
steps = 15
seed = 5
[train]
model = ["koopman", "edmd"]
config = { iterations = 40, hidden = [16], n_mult = 2, batch = 16, validate_every = 20 }
[control]
x0 = [-0.6, 0.1]
reference = [0.0, 0.0]
steps = 25
mpc = { horizon = 8, r = [0.1] }
"#;

fn report(out: &std::path::Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap()
}

#[test]
fn two_kinds_are_trained_and_each_controls() {
    let dir = common::scratch("scn-models");
    let sc = dir.join("kinds.toml");
    std::fs::write(&sc, SCENARIO).unwrap();
    let out = dir.join("out");
    let o = common::run_scenario(&sc, &out, &[]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    let r = report(&out);
    let test = Dataset::load_npz(&out.join("data/pend/test.npz")).unwrap();

    // One model per kind, each in its own folder, of its kind.
    let train = r["train"].as_array().unwrap();
    let names: Vec<&str> = train.iter().map(|t| t["model"].as_str().unwrap()).collect();
    assert_eq!(names, ["kinds-pend", "kinds-pend-edmd"]);
    let mut first_inputs = Vec::new();
    for (i, kind) in ["koopman", "edmd"].into_iter().enumerate() {
        let dir = out.join("models").join(names[i]);
        assert_eq!(koopman::model::store::read_kind(&dir).unwrap(), kind);
        assert_eq!(train[i]["metrics"]["kind"], kind);
        // The trainer's test error is the stored model's (computed here independently).
        let reported = train[i]["metrics"]["test_prediction_error"]
            .as_f64()
            .unwrap();
        let model = koopman::model::load_lifted(&dir).unwrap();
        let here = koopman::analysis::prediction_error(model.as_ref(), &test, 0.8).unwrap();
        assert!(
            reported.is_finite() && (reported - here).abs() <= 1e-6 * (1.0 + here.abs()),
            "{kind}: the trainer reported {reported}, the stored model gives {here}"
        );

        // Its control run: with this model, finite, within the pendulum's bounds.
        let c = &r["controls"][i];
        assert_eq!(c["model"], names[i]);
        assert_eq!(c["sim"], "pend");
        let u: Vec<f64> = c["u"]
            .as_array()
            .unwrap()
            .iter()
            .map(|u| u[0].as_f64().unwrap())
            .collect();
        assert_eq!((c["x"].as_array().unwrap().len(), u.len()), (26, 25));
        assert!(u.iter().all(|u| u.is_finite() && u.abs() <= 8.0 + 1e-9));
        assert!(c["final_error"].as_f64().unwrap().is_finite());
        // The service planned with this kind's controller on this model: its first input is the
        // one the same controller computes here from x0 with the settings it solved with.
        let cfg: MpcConfig = serde_json::from_value(c["mpc"].clone()).unwrap();
        let mut ctl = LoadedModel::load(&dir)
            .unwrap()
            .controller(&cfg, None)
            .unwrap();
        let mine = ctl.solve(&[-0.6, 0.1], &[0.0, 0.0]).unwrap().u[0];
        assert!(
            (u[0] - mine).abs() <= 1e-6 * (1.0 + mine.abs()),
            "{kind}: the service applied {}, its controller here computes {mine}",
            u[0]
        );
        first_inputs.push(u[0]);

        // Its diagnosis: the one-step error along the closed loop, computed here step by step
        // with the model's lift and matrices; the test set's window error; the commands at
        // the pendulum's ±8 bounds.
        let d = &r["diagnoses"][i];
        assert_eq!((&d["sim"], &d["model"]), (&c["sim"], &c["model"]));
        let xs: Vec<Vec<f64>> = serde_json::from_value(c["x"].clone()).unwrap();
        let (a, b) = (model.a(), model.b());
        let mut sq = 0.0;
        for (k, uk) in u.iter().enumerate() {
            let z = model.lift(&xs[k]);
            for (j, want) in xs[k + 1].iter().enumerate() {
                let pred: f64 =
                    (0..z.len()).map(|l| a[(j, l)] * z[l]).sum::<f64>() + b[(j, 0)] * uk;
                sq += (pred - want).powi(2);
            }
        }
        let one_step = sq / (2.0 * u.len() as f64);
        let got = d["one_step_closed_loop"].as_f64().unwrap();
        assert!(
            (got - one_step).abs() <= 1e-9 * (1.0 + one_step),
            "{kind}: diagnosis says {got}, the loop's one-step error is {one_step}"
        );
        let window = koopman::analysis::prediction_error(model.as_ref(), &test, 1.0).unwrap();
        assert_eq!(d["window_test"].as_f64(), Some(window));
        let at_bound = u.iter().filter(|u| u.abs() >= 8.0 - 1e-5).count();
        assert_eq!(
            d["saturated_fraction"].as_f64(),
            Some(at_bound as f64 / u.len() as f64)
        );
        assert!(!d["next_step"].as_str().unwrap().is_empty());

        // Side by side.
        let m = &r["models"][i];
        assert_eq!(
            (&m["sim"], &m["kind"], &m["model"]),
            (&c["sim"], &serde_json::json!(kind), &c["model"])
        );
        assert_eq!(m["test_prediction_error"].as_f64(), Some(reported));
        assert_eq!(m["control"]["final_error"], c["final_error"]);
        assert_eq!(m["control"]["steps"], 25);
    }
    assert_eq!(r["models"].as_array().unwrap().len(), 2);
    assert!(
        (first_inputs[0] - first_inputs[1]).abs() > 1e-9,
        "both kinds planned the same first input {first_inputs:?}: one model controlled twice?"
    );
    let table: Vec<&str> = stdout
        .lines()
        .skip_while(|l| !l.contains("the models side by side"))
        .collect();
    assert!(table.len() >= 4, "no side-by-side table in:\n{stdout}");
    assert!(table[1].contains("test L_pred") && table[1].contains("final error"));
    assert!(
        table[2].contains("pend") && table[2].contains("koopman"),
        "{stdout}"
    );
    assert!(
        table[3].contains("pend") && table[3].contains("edmd"),
        "{stdout}"
    );
    assert!(stdout.contains("control of 'pend' with model 'kinds-pend-edmd'"));
    assert!(out.join("control.png").is_file());
    assert!(out.join("control-kinds-pend-edmd.png").is_file());

    // The same kinds in the other order: each model is reused (the reuse is keyed on the kind).
    std::fs::write(
        &sc,
        SCENARIO.replace(r#"["koopman", "edmd"]"#, r#"["edmd", "koopman"]"#),
    )
    .unwrap();
    common::run_scenario(&sc, &out, &[]);
    let again = report(&out);
    let by_name = |rep: &serde_json::Value, name: &str| -> serde_json::Value {
        rep["train"]
            .as_array()
            .unwrap()
            .iter()
            .find(|t| t["model"] == name)
            .unwrap()
            .clone()
    };
    for name in names {
        let t = by_name(&again, name);
        assert_eq!(t["reused"], true, "{name} was trained again");
        assert_eq!(t["job"], by_name(&r, name)["job"]);
    }
    assert_eq!(again["models"][0]["kind"], "edmd");
}

#[test]
fn bad_kinds_are_refused_with_the_reason() {
    let dir = common::scratch("scn-models-bad");
    let run = |name: &str, text: &str| -> String {
        let sc = dir.join(format!("{name}.toml"));
        std::fs::write(&sc, text).unwrap();
        let o = std::process::Command::new(common::exe())
            .args(["run", sc.to_str().unwrap(), "--out"])
            .arg(dir.join(name))
            .output()
            .unwrap();
        assert!(!o.status.success(), "{name} ran");
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    // Refused when the file is read: nothing started, no output folder.
    let e = run("unknown", &SCENARIO.replace(r#""edmd"]"#, r#""dmd"]"#));
    assert!(
        e.contains("unknown model kind 'dmd'; valid kinds: koopman, bilinear, edmd, nndm"),
        "{e}"
    );
    assert!(!dir.join("unknown").exists());
    let e = run(
        "twice",
        &SCENARIO.replace(r#""edmd"]"#, r#""edmd", "koopman"]"#),
    );
    assert!(e.contains("'koopman' is listed twice"), "{e}");
    // Random shooting on an NNDM has no terminal weight: refused before collection.
    let e = run(
        "shooting",
        &SCENARIO
            .replace(r#""edmd"]"#, r#""nndm"]"#)
            .replace("r = [0.1] }", "r = [0.1], terminal = [1.0, 1.0] }"),
    );
    assert!(
        e.contains("with model kind 'nndm'") && e.contains("no terminal weight"),
        "{e}"
    );
    assert!(!dir.join("shooting/data/pend/train.npz").exists());
    // A bilinear model of a system without inputs: refused once its info is known, before
    // collection.
    let auto = r#"
name = "auto"
[[sims]]
id = "poly"
env = "polynomial"
[collect]
policy = { kind = "uniform" }
train_windows = 10
val_windows = 2
test_windows = 2
steps = 1
[train]
model = ["koopman", "bilinear"]
"#;
    let e = run("auto", auto);
    assert!(
        e.contains("a bilinear model cannot be trained for simulator 'poly'")
            && e.contains("nu = 0"),
        "{e}"
    );
    assert!(!dir.join("auto/data/poly/train.npz").exists());
}

/// With several kinds, the MPC entry runs once per kind and a baseline that needs no model once
/// (in the first pass), not once per kind.
#[test]
fn a_baseline_row_runs_once_beside_every_kinds_mpc_row() {
    let dir = common::scratch("scn-models-baseline");
    let text = SCENARIO.replace("[control]\n", "[[control]]\nlabel = \"mpc\"\n")
        + "[[control]]\nlabel = \"zero\"\ncontroller = \"zero-input\"\nx0 = [-0.6, 0.1]\n\
         reference = [0.0, 0.0]\nsteps = 25\n";
    let sc = dir.join("kinds.toml");
    std::fs::write(&sc, text).unwrap();
    let out = dir.join("out");
    common::run_scenario(&sc, &out, &[]);
    let rows: Vec<(String, String)> = report(&out)["controls"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            (
                c["label"].as_str().unwrap().to_string(),
                c["model"].as_str().unwrap().to_string(),
            )
        })
        .collect();
    let want = [
        ("mpc", "kinds-pend"),
        ("zero", "kinds-pend"),
        ("mpc", "kinds-pend-edmd"),
    ];
    assert_eq!(
        rows,
        want.map(|(l, m)| (l.to_string(), m.to_string())).to_vec()
    );
    std::fs::remove_dir_all(&dir).ok();
}
