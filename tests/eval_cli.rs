//! `koopbridge eval --per-state` run as a user runs it: on a z-scored Koopman model each state's
//! error comes back in raw units, consistent with the z-scored prediction error the same command
//! prints, and the option is refused for a model kind it does not cover.

mod common;

use std::path::Path;
use std::process::{Command, Output};

/// Runs `koopbridge ARGS... --FLAG PATH...` (each `(flag, path)` pair appended in order).
fn koopbridge(args: &[&str], paths: &[(&str, &Path)]) -> Output {
    let mut cmd = Command::new(common::exe());
    cmd.args(args);
    for (flag, p) in paths {
        cmd.arg(flag).arg(p);
    }
    cmd.output().unwrap()
}

fn succeeded(out: Output) -> Output {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

#[test]
fn per_state_errors_are_raw_units_of_the_z_scored_prediction_error() {
    let dir = common::scratch("eval-cli-per-state");
    let (data, model) = (dir.join("data"), dir.join("model"));
    common::small_pendulum_dataset(&data, 3);
    let small = [
        "train",
        "--normalise",
        "--iterations",
        "60",
        "--n-mult",
        "2",
        "--hidden",
        "16,16",
    ];
    succeeded(koopbridge(&small, &[("--data", &data), ("--out", &model)]));
    let test = data.join("test.npz");
    let eval = ["eval", "--json", "--per-state", "--gamma", "1"];
    let out = succeeded(koopbridge(&eval, &[("--model", &model), ("--data", &test)]));
    let rep: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let config = common::json_file(&model.join("config.json"));
    let std: Vec<f64> = serde_json::from_value(config["normalisation"]["x_std"].clone()).unwrap();
    let states = rep["per_state"].as_array().unwrap();
    assert_eq!(states.len(), 2);
    assert_eq!(states[0]["name"], "theta");
    // Back in z units, the states' mean square error is the z-scored L_pred at γ = 1.
    let mean_sq_z: f64 = states
        .iter()
        .zip(&std)
        .map(|(s, sd)| (s["rms"].as_f64().unwrap() / sd).powi(2))
        .sum::<f64>()
        / 2.0;
    let l_pred = rep["prediction_error"].as_f64().unwrap();
    assert!(
        (mean_sq_z - l_pred).abs() < 1e-6 * l_pred,
        "{mean_sq_z} vs {l_pred}"
    );
    assert!(
        std.iter().all(|s| (s - 1.0).abs() > 1e-3),
        "the check needs σ ≠ 1"
    );

    let nndm = dir.join("nndm");
    let nndm_args = ["train", "--model", "nndm", "--iterations", "5"];
    succeeded(koopbridge(
        &nndm_args,
        &[("--data", &data), ("--out", &nndm)],
    ));
    let refused = koopbridge(
        &["eval", "--per-state"],
        &[("--model", &nndm), ("--data", &test)],
    );
    assert!(!refused.status.success());
    assert!(
        String::from_utf8_lossy(&refused.stderr).contains("--per-state is for Koopman and EDMD")
    );
}
