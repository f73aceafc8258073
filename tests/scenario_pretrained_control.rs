//! A scenario that scores models trained elsewhere: no `[collect]`, `[train] pretrained` only,
//! single closed loops naming their `model`, and `observation_noise` on the state the MPC sees.
//! The independent computation: the same model in the run that trained it, from the same start
//! with the same reference, steps the same states to the last bit.

mod common;

use std::path::Path;

const LOOP: &str = "x0 = [0.4, 0.1]\nreference = [0.0, 0.0]\nsteps = 25\n";

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

fn floats(v: &serde_json::Value) -> Vec<Vec<f64>> {
    serde_json::from_value(v.clone()).unwrap()
}

#[test]
fn a_named_model_runs_as_in_the_run_that_trained_it_and_noise_moves_only_the_mpc() {
    let dir = common::scratch("pretrained-control");
    let first = format!(
        "name = \"first\"\n{}[control]\n{LOOP}",
        common::PENDULUM_BASE
    );
    let (o, first_out) = common::run_scenario_text(&dir, "first", &first, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let trained = json(&first_out.join("report.json"))["controls"][0].clone();
    let model = first_out.join("models/first-pend");

    let second = format!(
        "name = \"second\"\n[[sims]]\nid = \"pend\"\nenv = \"damped-pendulum\"\n\
         [train]\npretrained = [{{ name = \"given\", path = \"{}\" }}]\n\
         [control_defaults]\n{LOOP}\
         [[control]]\nlabel = \"given\"\nmodel = \"given\"\n\
         [[control]]\nlabel = \"noisy\"\nmodel = \"given\"\n\
         observation_noise = {{ sigma = 0.05, states = [0], seed = 3 }}\n\
         [[control]]\nlabel = \"zero\"\ncontroller = \"zero-input\"\n\
         [[control]]\nlabel = \"lqr\"\nmodel = \"given\"\nmpc = {{ law = \"lqr\", r = [0.1] }}\n",
        model.display()
    );
    let (o, out) = common::run_scenario_text(&dir, "second", &second, &[]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout.contains("collected nothing"), "{stdout}");
    let r = json(&out.join("report.json"));
    assert!(r.get("collect").is_none() && r["train"].as_array().unwrap().is_empty());
    assert!(!out.join("data/pend").exists(), "nothing collected");
    let rows = r["controls"].as_array().unwrap();
    let labels: Vec<&str> = rows.iter().map(|c| c["label"].as_str().unwrap()).collect();
    assert_eq!(labels, ["given", "noisy", "zero", "lqr"]);
    assert_eq!(rows[0]["model"], "given");
    // The given model: the first run's closed loop, bit for bit.
    assert_eq!(floats(&rows[0]["x"]), floats(&trained["x"]));
    assert_eq!(floats(&rows[0]["u"]), floats(&trained["u"]));
    // Noise on θ as the MPC sees it: other inputs, the states the true ones (x0 exact), the
    // noise in the report.
    let (xn, un) = (floats(&rows[1]["x"]), floats(&rows[1]["u"]));
    assert_eq!(xn[0], vec![0.4, 0.1]);
    assert_ne!(un, floats(&trained["u"]));
    assert_eq!(rows[1]["observation_noise"]["sigma"], 0.05);
    assert!(rows[0].get("observation_noise").is_none());
    // The LQR law through the service: its first input is the one the same settings give
    // in-process from the stored model.
    let cfg: koopman::mpc::MpcConfig = serde_json::from_value(rows[3]["mpc"].clone()).unwrap();
    assert_eq!(cfg.law, koopman::mpc::ControlLaw::Lqr);
    let mut lqr = koopman::mpc::LoadedModel::load(&out.join("models/given"))
        .unwrap()
        .controller(&cfg, None)
        .unwrap();
    let want = lqr.solve(&[0.4, 0.1], &[0.0, 0.0]).unwrap().u[0];
    assert_eq!(floats(&rows[3]["u"])[0][0], want);
    assert_ne!(floats(&rows[3]["u"]), floats(&trained["u"]));
    // A second run with the same seed draws the same noise.
    let (o, again) = common::run_scenario_text(&dir, "again", &second, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        floats(&json(&again.join("report.json"))["controls"][1]["u"]),
        un
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_scenario_without_collect_is_refused_where_it_would_need_data() {
    let sims = "name = \"s\"\n[[sims]]\nid = \"pend\"\nenv = \"damped-pendulum\"\n";
    let given = "pretrained = [{ name = \"given\", path = \"m/given\" }]\n";
    let parse = |t: String| {
        bridge::scenario::Scenario::parse(&t)
            .map(|_| ())
            .map_err(|e| e.to_string())
    };
    // Training settings without data.
    let e = parse(format!(
        "{sims}[train]\nconfig = {{ iterations = 5 }}\n{given}[control]\n{LOOP}model = \"given\"\n"
    ));
    assert!(e.unwrap_err().contains("no [collect] table"));
    // An MPC row without a model to use.
    let e = parse(format!("{sims}[train]\n{given}[control]\n{LOOP}"));
    assert!(e.unwrap_err().contains("name the MPC's model"));
    // A model that is neither pretrained nor trained here.
    let e = parse(format!(
        "{sims}[train]\n{given}[control]\n{LOOP}model = \"other\"\n"
    ));
    assert!(e.unwrap_err().contains("model 'other' is neither"));
    // The MPC's keys on a baseline; bad noise.
    let zero = "controller = \"zero-input\"\n";
    let e = parse(format!(
        "{sims}[train]\n{given}[control]\n{LOOP}{zero}model = \"given\"\n"
    ));
    assert!(e.unwrap_err().contains("`model` is the MPC's"));
    for (noise, why) in [
        ("sigma = -1.0, states = [0]", "sigma must be finite"),
        ("sigma = 0.1, states = []", "distinct state indices"),
        ("sigma = 0.1, states = [0, 0]", "distinct state indices"),
    ] {
        let e = parse(format!(
            "{sims}[train]\n{given}[control]\n{LOOP}model = \"given\"\nobservation_noise = {{ {noise} }}\n"
        ));
        assert!(e.as_ref().unwrap_err().contains(why), "{noise}: {e:?}");
    }
    // A tracking task's rows are its models: no `model` key there.
    let e = parse(format!(
        "{sims}[train]\n{given}[control]\nreferences = \"r.npz\"\nmodel = \"given\"\n"
    ));
    assert!(e
        .unwrap_err()
        .contains("`model` is not a key of a tracking task"));
    assert!(parse(format!(
        "{sims}[train]\n{given}[control]\n{LOOP}model = \"given\"\n"
    ))
    .is_ok());
}
