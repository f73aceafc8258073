//! `koopbridge run` with a tracking task (`[control] references = ...`, issue 47) on the built-in
//! damped pendulum, in several processes over Zenoh: the run's own test windows are the
//! references (each with the inputs that realised it), so the replay row must reproduce every one
//! exactly (survival at the cap, tracking error 0: an independent check of the loop, the stop
//! rule and the scoring); the model's rows are scored beside it and leave on-policy windows; bad
//! references are refused naming the key.

mod common;

use std::path::Path;

use common::json_file as json;

use common::PENDULUM_BASE as BASE;

fn run(dir: &Path, name: &str, text: &str) -> (std::process::Output, std::path::PathBuf) {
    common::run_scenario_text(dir, name, text, &[])
}

#[test]
fn a_tracking_task_scores_every_reference_beside_an_exact_replay() {
    let dir = common::scratch("tracking");
    let text = format!(
        r#"name = "tracking"
{BASE}
[[control]]
references = "{{out}}/data/pend/test.npz"
survival = {{ threshold = 0.5, states = [0] }}
q_from_data = {{}}
[[control]]
label = "es"
references = "{{out}}/data/pend/test.npz"
survival = {{ threshold = 0.5, states = [0] }}
error_state = true
replay = false
onpolicy_steps = 5
q_from_data = {{ states = [0], also = [{{ states = [1], scale = 0.25 }}] }}
mpc = {{ horizon = 10, r = [0.1] }}
"#
    );
    let (o, out) = run(&dir, "ok", &text);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{}\n{stdout}",
        String::from_utf8_lossy(&o.stderr)
    );
    let report = json(&out.join("report.json"));
    let tasks = report["tracking"].as_array().unwrap();
    assert_eq!(tasks.len(), 2);
    let (spec, es) = (&tasks[0], &tasks[1]);
    assert_eq!(
        (spec["references"].as_u64(), spec["steps"].as_u64()),
        (Some(10), Some(15))
    );
    let replay = &spec["rows"][0];
    assert_eq!(replay["row"], "replay");
    // The simulator is deterministic and the state is all of it: replaying a window's inputs
    // from its first state is the window.
    assert_eq!(replay["survivals"], serde_json::json!(vec![15; 10]));
    assert_eq!(replay["survival"]["at_cap"], 10);
    for e in replay["tracking_rms"].as_array().unwrap() {
        assert!(e.as_f64().unwrap() < 1e-9, "replay error {e}");
    }
    let model = &spec["rows"][1];
    assert_eq!(model["row"], "tracking-pend");
    let s = model["survivals"].as_array().unwrap();
    assert_eq!(s.len(), 10);
    assert!(s.iter().all(|v| v.as_u64().unwrap() <= 15));
    let (above, below) = (
        model["above_replay"].as_u64().unwrap(),
        model["below_replay"].as_u64().unwrap(),
    );
    let short = s.iter().filter(|v| v.as_u64().unwrap() < 15).count() as u64;
    assert_eq!(
        (above, below),
        (0, short),
        "nothing beats a replay at the cap"
    );
    // Q from the training split's spread on every state (1/σ² > 0), R = 0 (SPEC).
    let q = model["mpc"]["q"].as_array().unwrap();
    assert!(
        q.len() == 2 && q.iter().all(|v| v.as_f64().unwrap() > 0.0),
        "{q:?}"
    );
    // A run stops at its first failing step: steps run = survival + 1 below the cap.
    for (run, sv) in model["steps_run"].as_array().unwrap().iter().zip(s) {
        let (run, sv) = (run.as_u64().unwrap(), sv.as_u64().unwrap());
        assert!(run == 15 || run == sv + 1, "ran {run} steps, survived {sv}");
    }
    // The error-state task: no replay row, its own row name, windows of 5 transitions.
    let rows = es["rows"].as_array().unwrap();
    // Its Q: 1/σ² on θ, a quarter of it on θ̇ (the `also` group), from the same spread.
    let es_q = rows[0]["mpc"]["q"].as_array().unwrap();
    let f = |v: &serde_json::Value| v.as_f64().unwrap();
    assert_eq!(f(&es_q[0]), f(&q[0]));
    assert!(
        (f(&es_q[1]) - 0.25 * f(&q[1])).abs() <= 1e-12 * f(&q[1]),
        "{es_q:?} {q:?}"
    );
    assert_eq!(rows.len(), 1);
    assert_eq!(rows[0]["row"], "tracking-pend+es");
    assert!(es["error_state"].as_bool().unwrap());
    let onp = &rows[0]["onpolicy"];
    assert_eq!(onp["steps"], 5);
    let ran: u64 = rows[0]["steps_run"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap() / 5)
        .sum();
    assert_eq!(
        onp["windows"].as_u64().unwrap(),
        ran,
        "back-to-back windows of 5 per run"
    );
    if ran > 0 {
        let d = koopman::data::Dataset::load_npz(Path::new(onp["path"].as_str().unwrap())).unwrap();
        assert_eq!((d.n as u64, d.steps, d.nx, d.nu), (ran, 5, 2, 1));
    }
    assert!(std::fs::metadata(out.join("tracking/survival.png")).is_ok_and(|m| m.len() > 0));
    assert!(std::fs::metadata(out.join("tracking/error.png")).is_ok_and(|m| m.len() > 0));
    // The first reference's error, step by step: the replay's is 0, the model's as long as its run.
    let first = replay["first_errors"].as_array().unwrap();
    assert_eq!(first.len(), 16);
    assert!(first.iter().all(|e| e.as_f64().unwrap() < 1e-9));
    let ran = model["steps_run"][0].as_u64().unwrap() as usize;
    assert_eq!(model["first_errors"].as_array().unwrap().len(), ran + 1);
    let table = std::fs::read_to_string(out.join("tracking/table.md")).unwrap();
    assert!(
        table.contains("| replay |") && table.contains("| tracking-pend+es |"),
        "{table}"
    );
    assert!(stdout.contains("| tracking-pend |"), "{stdout}");

    // References of the wrong width are refused before collection, naming the key and the file.
    let bad = dir.join("bad.npz");
    let x = koopman::data::npy::encode(&[1, 3, 3], &[0.0; 9]);
    koopman::data::npz::write_npz(&bad, &[("x.npy", &x)]).unwrap();
    let text = format!(
        "name = \"tracking-bad\"\n{BASE}\n[control]\nreferences = \"{}\"\nreplay = false\n",
        bad.display()
    );
    let (o, out) = run(&dir, "bad", &text);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        stderr.contains("[control].references") && stderr.contains("nx = 2"),
        "{stderr}"
    );
    assert!(
        !out.join("data/pend/train.npz").exists(),
        "nothing was collected"
    );

    // A perturbation the built-in system cannot apply is refused by it, naming why.
    let text = format!(
        "name = \"tracking-perturbed\"\n{BASE}\n[control]\nreferences = \"{{out}}/data/pend/test.npz\"\n\
         perturbation = {{ mass_scale = 1.2 }}\n"
    );
    let (o, _) = run(&dir, "perturbed", &text);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(stderr.contains("takes no perturbation"), "{stderr}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn aggregation_retrains_on_the_aggregation_tasks_windows_and_tracks_again() {
    let dir = common::scratch("tracking-agg");
    let text = format!(
        r#"name = "agg"
{BASE}
# The data: the run's own test windows, tracked to their end (one window of T = 15 each).
[[control]]
label = "data"
references = "{{out}}/data/pend/test.npz"
continue_after_failure = true
survival = {{ threshold = 0.5, states = [0] }}
aggregate = true
replay = false
[[control]]
references = "{{out}}/data/pend/test.npz"
survival = {{ threshold = 0.5, states = [0] }}
"#
    );
    let (o, out) = common::run_scenario_text(&dir, "ok", &text, &["--aggregate", "1"]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{}\n{stdout}",
        String::from_utf8_lossy(&o.stderr)
    );
    let report = json(&out.join("report.json"));
    let first = &report["tracking"][0]["rows"][0];
    assert_eq!(first["row"], "agg-pend+data");
    let windows = first["onpolicy"]["windows"].as_u64().unwrap();
    assert_eq!(
        windows, 10,
        "ten references run to their end: a window of 15 each"
    );
    let round = &report["tracking_aggregation"][0];
    assert_eq!(round["round"], 1);
    let sim = &round["sims"][0];
    assert_eq!(
        (sim["added_windows"].as_u64(), sim["train_windows"].as_u64()),
        (Some(windows), Some(40 + windows))
    );
    assert_eq!(sim["train"]["model"], "agg-pend-agg1");
    assert_eq!(sim["kind"], "koopman");
    let agg =
        koopman::data::Dataset::load_npz(&out.join("data/pend/train-agg-pend-agg1.npz")).unwrap();
    let train = koopman::data::Dataset::load_npz(&out.join("data/pend/train.npz")).unwrap();
    assert_eq!(agg.n as u64, 40 + windows);
    assert_eq!(
        &agg.x[..train.x.len()],
        &train.x[..],
        "the collected windows first"
    );
    // Every task again with the retrained model, the replay row unchanged.
    let again = round["tracking"].as_array().unwrap();
    assert_eq!(again.len(), 2);
    assert_eq!(again[0]["rows"][0]["row"], "agg-pend-agg1+data");
    assert_eq!(again[1]["rows"][1]["row"], "agg-pend-agg1");
    assert_eq!(
        again[1]["rows"][0]["survivals"],
        report["tracking"][1]["rows"][0]["survivals"]
    );
    assert!(stdout.contains("-> round 1:"), "{stdout}");

    // Without --aggregate the aggregation task (there only for its windows) does not run.
    let (o, out) = common::run_scenario_text(&dir, "plain", &text, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let plain = json(&out.join("report.json"));
    assert_eq!(plain["tracking"].as_array().unwrap().len(), 1);
    assert!(plain.get("tracking_aggregation").is_none());
    // Windows of another length than the training data's cannot be aggregated: refused when the
    // file is read.
    let bad = text.replace(
        "aggregate = true\n",
        "aggregate = true\nonpolicy_steps = 5\n",
    );
    let (o, _) = common::run_scenario_text(&dir, "steps", &bad, &["--aggregate", "1"]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && stderr.contains("onpolicy_steps"),
        "{stderr}"
    );
    // Without a task marked `aggregate`, --aggregate is refused before anything starts.
    let text = text.replace("aggregate = true\n", "");
    let (o, out) = common::run_scenario_text(&dir, "none", &text, &["--aggregate", "1"]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && stderr.contains("aggregate = true"),
        "{stderr}"
    );
    assert!(!out.join("data/pend/train.npz").exists());
    std::fs::remove_dir_all(&dir).ok();
}

/// `[train] pretrained`: a model trained by another run is one more row of the tracking task,
/// scored exactly as in the run that trained it (same references, same simulator: the same
/// survivals and errors), beside this run's own model (trained differently, so a row that used
/// the wrong model would show); a folder that is not a model or whose dimensions are not the
/// simulator's is refused before anything is collected, naming the entry.
#[test]
fn a_model_trained_elsewhere_is_a_row_scored_as_in_its_own_run() {
    let dir = common::scratch("tracking-pretrained");
    let task = r#"
[[control]]
references = "{out}/data/pend/test.npz"
survival = { threshold = 0.5, states = [0] }
"#;
    let (o, first) = run(&dir, "first", &format!("name = \"first\"\n{BASE}{task}"));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let model = first.join("models/first-pend");
    // The second run trains its own model for fewer iterations and scores the first one's too.
    let base = BASE.replace("iterations = 30,", "iterations = 10,");
    let given = format!(
        "pretrained = [{{ name = \"given\", path = \"{}\" }}]\n",
        model.display()
    );
    let (o, second) = run(
        &dir,
        "second",
        &format!("name = \"second\"\n{base}{given}{task}"),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rows = |out: &Path| json(&out.join("report.json"))["tracking"][0]["rows"].clone();
    let (a, b) = (rows(&first), rows(&second));
    let names: Vec<&str> = b
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["row"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["replay", "second-pend", "given"]);
    for key in ["survivals", "tracking_rms", "steps_run"] {
        assert_eq!(
            b[2][key], a[1][key],
            "{key}: the given model as in its own run"
        );
    }
    assert_ne!(
        b[1]["tracking_rms"], a[1]["tracking_rms"],
        "the second run's own model is another model"
    );
    let report = json(&second.join("report.json"));
    assert_eq!(report["pretrained"][0]["kind"], "koopman");
    assert!(second.join("models/given/config.json").is_file());

    // Not a model folder; a model of other dimensions: refused before collection.
    let fake = dir.join("fake");
    std::fs::create_dir_all(&fake).unwrap();
    for (name, config, why) in [
        ("none", None, "is not a model folder"),
        (
            "wide",
            Some(r#"{"kind": "koopman", "nx": 3, "nu": 1}"#),
            "its nx/nu are 3/1, simulator 'pend' has 2/1",
        ),
    ] {
        if let Some(c) = config {
            std::fs::write(fake.join("config.json"), c).unwrap();
        }
        let given = format!(
            "pretrained = [{{ name = \"given\", path = \"{}\" }}]\n",
            fake.display()
        );
        let (o, out) = run(&dir, name, &format!("name = \"bad\"\n{BASE}{given}{task}"));
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success());
        assert!(
            stderr.contains("[train] pretrained 'given'") && stderr.contains(why),
            "{stderr}"
        );
        assert!(
            !out.join("data/pend/train.npz").exists(),
            "nothing collected"
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn the_offset_free_correction_acts_about_each_reference_and_restarts_with_every_one() {
    let dir = common::scratch("tracking-offset");
    let defaults = |references: &str| {
        format!(
            "[control_defaults]\nreferences = \"{references}\"\n\
             survival = {{ threshold = 0.5, states = [0] }}\nerror_state = true\nreplay = false\n\
             mpc = {{ horizon = 10, r = [0.1] }}\n\
             offset_free = {{ mode = \"disturbance\", radius = 1e9, gain = [0.5, 0.5] }}\n"
        )
    };
    let (o, first) = run(
        &dir,
        "first",
        &format!(
            "name = \"first\"\n{BASE}{}[[control]]\n",
            defaults("{out}/data/pend/test.npz")
        ),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let task = json(&first.join("report.json"))["tracking"][0].clone();
    assert_eq!(task["offset_free"]["mode"], "disturbance");
    // The references are the plant's own windows with the inputs that realised them: on such a
    // plan the deviation's prediction error is zero, so the correction estimates nothing.
    for e in task["rows"][0]["tracking_rms"].as_array().unwrap() {
        assert!(e.as_f64().unwrap() < 1e-9, "on the plan: {e}");
    }

    // Plans the plant does not follow (their inputs × 1.3), forwards and reversed, scored by the
    // first run's model in a run that collects nothing.
    let mut refs = koopman::data::Dataset::load_npz(&first.join("data/pend/test.npz")).unwrap();
    refs.u.iter_mut().for_each(|u| *u *= 1.3);
    let forwards = dir.join("forwards.npz");
    refs.save_npz(&forwards).unwrap();
    let (sx, su) = ((refs.steps + 1) * refs.nx, refs.steps * refs.nu);
    refs.x = refs.x.chunks(sx).rev().flatten().copied().collect();
    refs.u = refs.u.chunks(su).rev().flatten().copied().collect();
    let reversed = dir.join("reversed.npz");
    refs.save_npz(&reversed).unwrap();
    let second = format!(
        "name = \"second\"\n[[sims]]\nid = \"pend\"\nenv = \"damped-pendulum\"\n[train]\n\
         pretrained = [{{ name = \"given\", path = \"{}\" }}]\n{}\
         [[control]]\nlabel = \"plain\"\noffset_free = {{ mode = \"disturbance\", radius = 1e9, gain = [0.0, 0.0] }}\n\
         [[control]]\nlabel = \"offset\"\n\
         [[control]]\nlabel = \"reversed\"\nreferences = \"{}\"\n",
        first.join("models/first-pend").display(),
        defaults(forwards.to_str().unwrap()),
        reversed.display()
    );
    let (o, out) = run(&dir, "second", &second);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let tasks = json(&out.join("report.json"))["tracking"].clone();
    let row = |i: usize, key: &str| -> Vec<f64> {
        serde_json::from_value(tasks[i]["rows"][0][key].clone()).unwrap()
    };
    let (plain, offset) = (row(0, "tracking_rms"), row(1, "tracking_rms"));
    let moved = plain
        .iter()
        .zip(&offset)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(
        moved > 1e-6,
        "the correction moves the loop off the plain one: {moved}"
    );
    // Each reference is its own episode (the estimate starts at zero): the reversed task's
    // figures are the forward task's, reversed, to the bit.
    for key in ["survivals", "tracking_rms", "steps_run"] {
        let mut back = tasks[2]["rows"][0][key].as_array().unwrap().clone();
        back.reverse();
        assert_eq!(
            serde_json::Value::Array(back),
            tasks[1]["rows"][0][key],
            "{key}"
        );
    }

    // About a plan only the disturbance estimate: another mode is refused before collection.
    let bad = format!(
        "name = \"bad\"\n{BASE}{}[[control]]\n",
        defaults("{out}/data/pend/test.npz").replace("\"disturbance\"", "\"integral\"")
    );
    let (o, out) = run(&dir, "bad", &bad);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        stderr.contains("offset_free") && stderr.contains("\"disturbance\" only"),
        "{stderr}"
    );
    assert!(!out.join("data/pend/train.npz").exists());
}
