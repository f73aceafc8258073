//! Tests of `koopbridge scaling --over budget`: runs of a budget sweep (m = c·N·ln N, their factors
//! c in metrics.json) are grouped into one curve per c, and each fit recovers the law they follow.

use super::tests::{write_budget_run as write_run, write_report};
use super::*;
use bridge::sweep::budget_windows;

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "koopbridge-scaling-budget-{name}-{}",
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// E_c(N) of the synthetic budget sweep: c = 10 follows 2·N^(−0.8) + 0.002, c = 40 follows
/// 1·N^(−1.5) + 0.0005.
fn law(c: f64, n: f64) -> f64 {
    if c == 10.0 {
        2.0 * n.powf(-0.8) + 0.002
    } else {
        n.powf(-1.5) + 0.0005
    }
}

#[test]
fn budget_curves_are_fitted_per_c_and_recover_their_exponents() {
    let root = temp("law");
    for c in [10.0, 40.0] {
        for n_mult in [1usize, 2, 4, 8, 16] {
            let n = 2 * (1 + n_mult);
            let m = budget_windows(c, n);
            let e = law(c, n as f64);
            for (seed, dev) in [(1u64, 1.01), (2, 0.99)] {
                let dir = root.join(format!("m{m}-n{n_mult}-s{seed}"));
                write_run(&dir, m, n_mult, seed, e * dev, &[c]);
            }
        }
    }
    // A fixed-m run (no budget) is not on any budget curve.
    write_run(&root.join("fixed"), 16000, 16, 1, 0.5, &[]);
    let runs = collect_runs(std::slice::from_ref(&root)).unwrap();
    assert_eq!(runs.len(), 21);
    let curves = fit_curves(&runs, Axis::Budget);
    assert_eq!(curves.len(), 2, "one curve per c");
    for (c, alpha, cc) in [(10.0, 0.8, 0.002), (40.0, 1.5, 0.0005)] {
        let curve = curves
            .iter()
            .find(|k| k.budget == Some(c))
            .unwrap_or_else(|| panic!("no curve for c = {c}"));
        assert!(
            curve.label.contains(&format!("m = c·N ln N, c = {c} ")),
            "{}",
            curve.label
        );
        assert_eq!(
            curve.points.iter().map(|p| p.0).collect::<Vec<_>>(),
            [4.0, 4.0, 6.0, 6.0, 10.0, 10.0, 18.0, 18.0, 34.0, 34.0]
        );
        let fit = curve.fit.as_ref().unwrap();
        assert!(
            (fit.alpha - alpha).abs() < 0.1,
            "c = {c}: α = {}",
            fit.alpha
        );
        assert!((fit.c - cc).abs() < cc * 0.5, "c = {c}: C = {}", fit.c);
        assert!(fit.r2 > 0.99, "c = {c}: R² = {}", fit.r2);
    }
    // Over N at fixed m, the budget points (each n_mult at its own m) make no fittable curve.
    assert!(fit_curves(&runs, Axis::N).iter().all(|k| k.fit.is_none()));

    let saved = write_report(&root, Axis::Budget);
    assert_eq!(saved["over"], "budget");
    let saved_curves = saved["curves"].as_array().unwrap();
    assert_eq!(saved_curves.len(), 2);
    for k in saved_curves {
        let c = k["budget"].as_f64().unwrap();
        let alpha = k["fit"]["alpha"].as_f64().unwrap();
        assert!((alpha - if c == 10.0 { 0.8 } else { 1.5 }).abs() < 0.1);
        for field in ["a", "c", "r2"] {
            assert!(k["fit"][field].is_number(), "{field} in {k}");
        }
    }
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn a_run_shared_by_two_budgets_is_on_both_curves() {
    let root = temp("shared");
    // n_mult 16 capped at the pool of 1000 for c = 10 and c = 40: one run, both curves.
    write_run(&root.join("capped"), 1000, 16, 1, 0.01, &[10.0, 40.0]);
    write_run(&root.join("a"), 56, 1, 1, 0.2, &[10.0]);
    write_run(&root.join("b"), 222, 1, 1, 0.1, &[40.0]);
    let curves = fit_curves(
        &collect_runs(std::slice::from_ref(&root)).unwrap(),
        Axis::Budget,
    );
    assert_eq!(curves.len(), 2);
    for k in &curves {
        assert_eq!(k.points.len(), 2, "{}", k.label);
        assert!(k.points.contains(&(34.0, 0.01)), "{}", k.label);
        assert!(k.fit.is_none(), "2 points are too few to fit");
    }
    // A metrics.json whose budgets are not numbers is an error naming the file.
    let metrics = root.join("a").join("metrics.json");
    let mut v: Value = serde_json::from_slice(&std::fs::read(&metrics).unwrap()).unwrap();
    v["budgets"] = serde_json::json!(["ten"]);
    std::fs::write(&metrics, v.to_string()).unwrap();
    let err = format!("{:#}", collect_runs(&[root.join("a")]).unwrap_err());
    assert!(err.contains("metrics.json: \"budgets\""), "{err}");
    std::fs::remove_dir_all(&root).unwrap();
}
