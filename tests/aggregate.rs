//! `koopbridge run --aggregate ROUNDS` at a tiny budget: the recorder records each closed-loop
//! rollout (checked window by window against the executed states and inputs), the trainer
//! retrains on the union of the collected windows and every rollout so far, control runs again,
//! and the report chains the error before and after each round.

mod common;

use koopman::data::Dataset;

/// The small pendulum scenario ([`common::PENDULUM_BASE`]) with a regulation task.
fn tiny() -> String {
    format!(
        "name = \"agg\"\n{}[control]\nx0 = [-1.0, 0.1]\nreference = [0.0, 0.0]\nsteps = 45\n",
        common::PENDULUM_BASE
    )
}

/// Window `w` of `d` as (x rows, u rows).
fn window(d: &Dataset, w: usize) -> (Vec<Vec<f64>>, Vec<Vec<f64>>) {
    (
        (0..=d.steps).map(|t| d.state(w, t).to_vec()).collect(),
        (0..d.steps).map(|t| d.input(w, t).to_vec()).collect(),
    )
}

/// One window: its states and its inputs.
type Window = (Vec<Vec<f64>>, Vec<Vec<f64>>);

/// The executed trajectory of a control report cut into windows of `t` transitions.
fn executed(c: &serde_json::Value, t: usize) -> Vec<Window> {
    let x: Vec<Vec<f64>> = serde_json::from_value(c["x"].clone()).unwrap();
    let u: Vec<Vec<f64>> = serde_json::from_value(c["u"].clone()).unwrap();
    (0..u.len() / t)
        .map(|w| {
            (
                x[w * t..=(w + 1) * t].to_vec(),
                u[w * t..(w + 1) * t].to_vec(),
            )
        })
        .collect()
}

#[test]
fn aggregation_retrains_on_the_recorded_rollouts_and_controls_again() {
    let dir = common::scratch("aggregate");
    let sc = dir.join("agg.toml");
    std::fs::write(&sc, tiny()).unwrap();
    let out = dir.join("out");
    let o = common::run_scenario(&sc, &out, &["--aggregate", "2"]);
    let (stdout, stderr) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let rounds = r["aggregation"].as_array().unwrap();
    assert_eq!(rounds.len(), 2);
    let collected = Dataset::load_npz(&out.join("data/pend/train.npz")).unwrap();
    // The control run each rollout was recorded from: the first run, then round 1's.
    let sources = [&r["control"], &rounds[0]["sims"][0]["control"]];
    let mut previous_after = r["control"]["tracking_rms_total"].as_f64().unwrap();
    for (i, round) in rounds.iter().enumerate() {
        let n = i + 1;
        let a = &round["sims"][0];
        assert_eq!(round["round"], n);
        assert_eq!(a["sim"], "pend");
        assert_eq!(a["recorded"]["windows"], 3, "45 steps = 3 windows of 15");
        assert_eq!(a["recorded"]["gaps"], 0);
        assert_eq!(a["train_windows"], 40 + 3 * n);
        assert_eq!(a["train"]["model"], format!("agg-pend-agg{n}"));
        assert!(a["train"]["metrics"]["test_prediction_error"]
            .as_f64()
            .unwrap()
            .is_finite());
        // The recorded rollout is exactly the executed closed loop, window by window.
        let rollout = Dataset::load_npz(&out.join(format!("data/pend/rollout-{n}.npz"))).unwrap();
        let want = executed(sources[i], 15);
        assert_eq!(rollout.n, want.len());
        for (w, ex) in want.iter().enumerate() {
            assert_eq!(&window(&rollout, w), ex, "round {n}, window {w}");
        }
        // The union: the collected windows, then every rollout so far, in order.
        let union = Dataset::load_npz(&out.join(format!("data/pend/train-agg{n}.npz"))).unwrap();
        assert_eq!(union.n, 40 + 3 * n);
        for w in 0..40 {
            assert_eq!(window(&union, w), window(&collected, w));
        }
        for w in 0..3 {
            assert_eq!(window(&union, 40 + 3 * i + w), window(&rollout, w));
        }
        // Before this round = after the previous one; after = this round's control run.
        assert_eq!(a["error_before"].as_f64().unwrap(), previous_after);
        assert_eq!(a["error_after"], a["control"]["tracking_rms_total"]);
        assert_eq!(a["control"]["model"], format!("agg-pend-agg{n}"));
        assert_eq!(a["control"]["x"][0], serde_json::json!([-1.0, 0.1]));
        previous_after = a["error_after"].as_f64().unwrap();
        // Each round beside the previous one; a round that made control worse is a warning.
        let before = if i == 0 {
            &r["control"]
        } else {
            &rounds[i - 1]["sims"][0]["control"]
        };
        for (field, of) in [
            ("time_to_goal", "time_to_goal_steps"),
            ("not_solved", "not_solved"),
            ("final_error", "final_error"),
        ] {
            assert_eq!(a[format!("{field}_before")], before[of], "{field}");
            assert_eq!(a[format!("{field}_after")], a["control"][of], "{field}");
        }
        let (fb, fa) = (
            a["final_error_before"].as_f64().unwrap(),
            a["final_error_after"].as_f64().unwrap(),
        );
        if fa > fb * 1.1 + 1e-3 {
            assert!(
                a["regression"].as_str().unwrap().contains("final error"),
                "{a}"
            );
        }
        let warned = format!("aggregation round {n} made control of 'pend' worse");
        assert_eq!(
            a.get("regression").is_some(),
            stderr.contains(&format!("warning: {warned}")),
            "{stderr}"
        );
        assert_eq!(
            a.get("regression").is_some(),
            r["warnings"]
                .as_array()
                .is_some_and(|w| w.iter().any(|w| w.as_str().unwrap().starts_with(&warned))),
        );
        assert!(
            stdout.contains(&format!("aggregation round {n} 'pend'"))
                && stdout.contains("previous round -> this round"),
            "{stdout}"
        );
    }
    assert!(out.join("aggregation.png").is_file());
}
