//! `koopbridge sweep --budget` end to end on a small damped-pendulum dataset and one trainer the
//! sweep starts itself: the budget points train on ⌈c·N·ln N⌉ windows (capped at the pool, with a
//! note), a point an earlier fixed-m sweep trained is reused rather than trained again and joins
//! its budget curve, and the sweep leaves the per-c fits in scaling-budget/; results written before
//! budgets existed still load.

mod common;

use std::path::Path;

fn sweep(data: &Path, out: &Path, grid: &[&str]) -> String {
    let out_put = std::process::Command::new(common::exe())
        .arg("sweep")
        .arg("--data")
        .arg(data)
        .args(grid)
        .args(["--seeds", "1", "--iterations", "30"])
        .args(["--set", "hidden=[16,16]", "--set", "validate_every=10"])
        .args(["--local-trainers", "1", "--progress-every", "0", "--out"])
        .arg(out)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out_put.stdout).to_string();
    assert!(
        out_put.status.success(),
        "sweep {grid:?} failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out_put.stderr)
    );
    stdout
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).unwrap())
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The D values (N here) of one curve of a scaling.json.
fn curve_ds(curve: &serde_json::Value) -> Vec<f64> {
    curve["points"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p[0].as_f64().unwrap())
        .collect()
}

#[test]
fn a_budget_sweep_trains_c_n_ln_n_windows_and_reuses_a_fixed_m_point() {
    let dir = common::scratch("sweep-budget");
    let data = dir.join("data/pend");
    common::small_pendulum_dataset(&data, 7); // nx = 2, a train pool of 400 windows
    let out = dir.join("sweep");

    // A fixed-m sweep first: m = 56 = ⌈10·4·ln 4⌉ at n_mult 1 (N = 4).
    sweep(&data, &out, &["--samples", "56", "--n-mult", "1"]);
    let shared = out.join("runs/pend-m56-n1-s1-both-i30");
    let before = json(&shared.join("metrics.json"));
    assert!(before.get("budgets").is_none());

    // Budgets c = 10 (m = 56 at N = 4, 108 at N = 6) and c = 100 (555 and 1076: both capped).
    let stdout = sweep(&data, &out, &["--budget", "10,100", "--n-mult", "1,2"]);
    assert!(stdout.contains("sweep of 4 points"), "{stdout}");
    assert!(
        stdout.contains("1 points already finished"),
        "the m = 56 point is reused:\n{stdout}"
    );
    assert!(
        stdout.contains(
            "c = 100, n_mult 1 (N = 4): c·N·ln N = 555 windows exceeds the train pool of 400"
        ),
        "{stdout}"
    );
    assert!(
        !stdout.contains("pend-m56-n1-s1-both-i30 ->"),
        "retrained:\n{stdout}"
    );

    // The reused run now lists c = 10, and is otherwise the run of the first sweep.
    let mut after = json(&shared.join("metrics.json"));
    assert_eq!(after["budgets"], serde_json::json!([10.0]));
    after.as_object_mut().unwrap().remove("budgets");
    assert_eq!(after, before);
    assert_eq!(
        json(&shared.join("result.json"))["budgets"],
        serde_json::json!([10.0])
    );
    for (name, m, c) in [
        ("pend-m108-n2-s1-both-i30", 108, 10.0),
        ("pend-m400-n1-s1-both-i30", 400, 100.0),
        ("pend-m400-n2-s1-both-i30", 400, 100.0),
    ] {
        let r = json(&out.join("runs").join(name).join("result.json"));
        assert_eq!(r["m"], m, "{name}");
        assert_eq!(r["budgets"], serde_json::json!([c]), "{name}");
        let metrics = json(&out.join("runs").join(name).join("metrics.json"));
        assert_eq!(metrics["train_samples"], m, "{name}");
        assert_eq!(metrics["budgets"], serde_json::json!([c]), "{name}");
    }
    let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
    assert_eq!(csv.lines().count(), 5, "{csv}");
    assert!(csv.lines().next().unwrap().ends_with(",budgets"), "{csv}");
    assert!(
        csv.lines()
            .any(|l| l.starts_with("pend-m400-n1-") && l.ends_with(",100")),
        "{csv}"
    );
    let grid = json(&out.join("sweep.json"));
    assert_eq!(grid["budgets"], serde_json::json!([10.0, 100.0]));
    assert_eq!(grid["shape"], serde_json::json!({ "nx": 2, "pool": 400 }));

    // One curve per c over N = 4, 6 (two points each: listed, too few to fit).
    let fits = json(&out.join("scaling-budget/scaling.json"));
    assert_eq!(fits["over"], "budget");
    let curves = fits["curves"].as_array().unwrap();
    assert_eq!(curves.len(), 2, "{fits}");
    for k in curves {
        assert_eq!(curve_ds(k), [4.0, 6.0], "{k}");
    }
    assert!(out.join("scaling-budget/scaling.png").is_file());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_n_fit_of_a_mixed_sweep_keeps_to_the_fixed_m_family() {
    let dir = common::scratch("sweep-budget-n-fit");
    let data = dir.join("data/pend");
    common::small_pendulum_dataset(&data, 8);
    let out = dir.join("sweep");
    // Fixed m = 200 at N = 4, 6 and the c = 10 points m = 56, 108: four runs, four distinct m.
    let stdout = sweep(
        &data,
        &out,
        &["--samples", "200", "--n-mult", "1,2", "--budget", "10"],
    );
    assert!(stdout.contains("sweep of 4 points"), "{stdout}");
    // scaling-n: the m = 200 curve only (the budget points' own m would each be a one-point curve).
    let fits = json(&out.join("scaling-n/scaling.json"));
    let curves = fits["curves"].as_array().unwrap();
    assert_eq!(curves.len(), 1, "{fits}");
    assert_eq!(curve_ds(&curves[0]), [4.0, 6.0], "{fits}");
    // scaling-budget still has the c = 10 curve over the same N.
    let budget = json(&out.join("scaling-budget/scaling.json"));
    assert_eq!(budget["curves"].as_array().unwrap().len(), 1, "{budget}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn results_written_before_budgets_existed_still_load() {
    let old = r#"{"name": "d-m1000-n16-s1-both", "env": "damped-pendulum",
        "pairing": "reference", "m": 1000, "n_mult": 16, "latent_dim": 34, "seed": 1,
        "regularisers": "both", "iterations": 500, "test_error": 0.01,
        "gram_condition": null, "bbt_condition": null, "wall_seconds": 3.0,
        "trainer": "t0"}"#;
    let r: bridge::sweep::PointResult = serde_json::from_str(old).unwrap();
    assert!(r.budgets.is_empty());
    assert!(r.csv_row().ends_with(",t0,"), "{}", r.csv_row());
    let tagged = bridge::sweep::PointResult {
        budgets: vec![10.0, 40.0],
        ..r
    };
    assert!(
        tagged.csv_row().ends_with(",t0,10;40"),
        "{}",
        tagged.csv_row()
    );
    let back: bridge::sweep::PointResult =
        serde_json::from_str(&serde_json::to_string(&tagged).unwrap()).unwrap();
    assert_eq!(back, tagged);
}
