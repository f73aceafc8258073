//! `koopbridge train --model edmd` dictionary options, run as a user runs them: the degree
//! reaches the fit (the model's latent size is the dictionary's feature count) and the EDMD
//! options are refused for the other model kinds.

mod common;

use std::path::Path;
use std::process::Command;

fn koopbridge() -> Command {
    Command::new(common::exe())
}

fn latent_dim(model: &Path) -> u64 {
    let text = std::fs::read_to_string(model.join("config.json")).unwrap();
    let config: serde_json::Value = serde_json::from_str(&text).unwrap();
    config["latent_dim"].as_u64().unwrap()
}

#[test]
fn edmd_degree_sets_the_dictionary_and_is_refused_for_other_models() {
    let dir = common::scratch("train-cli-edmd");
    let data = dir.join("data");
    let ok = koopbridge()
        .args([
            "data",
            "gen",
            "--env",
            "damped",
            "--windows",
            "900",
            "--out",
        ])
        .arg(&data)
        .output()
        .unwrap();
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );

    let train = |out: &Path, extra: &[&str]| {
        koopbridge()
            .args(["train", "--data"])
            .arg(&data)
            .arg("--out")
            .arg(out)
            .args(extra)
            .output()
            .unwrap()
    };
    // Degree 3 on the pendulum's 2 states: every monomial of total degree 1..=3 (2 + 3 + 4 = 9)
    // plus the constant, counted here independently of the dictionary code.
    let low = dir.join("edmd3");
    let r = train(&low, &["--model", "edmd", "--edmd-degree", "3"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let monomials: u64 = (1..=3u64).map(|d| d + 1).sum();
    let n3 = latent_dim(&low);
    assert_eq!(n3, monomials + 1, "latent_dim");

    // By default every degree up to the largest within 250 features (20 on 2 states: 231) is
    // tried on the validation split, and the lowest within 5 % of the best error is kept.
    let selection = |model: &Path| -> (u64, Vec<(u64, u64, Option<f64>)>) {
        let text = std::fs::read_to_string(model.join("metrics.json")).unwrap();
        let m: serde_json::Value = serde_json::from_str(&text).unwrap();
        let s = &m["degree_selection"];
        let trials = s["trials"]
            .as_array()
            .unwrap()
            .iter()
            .map(|t| {
                (
                    t["degree"].as_u64().unwrap(),
                    t["features"].as_u64().unwrap(),
                    t["validation_error"].as_f64(),
                )
            })
            .collect();
        (s["chosen"].as_u64().unwrap(), trials)
    };
    let auto = dir.join("edmd-auto");
    let r = train(&auto, &["--model", "edmd"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let (chosen, trials) = selection(&auto);
    assert_eq!(
        trials.iter().map(|t| t.0).collect::<Vec<_>>(),
        (1..=20).collect::<Vec<_>>()
    );
    assert_eq!(trials[19].1, 231);
    let best = trials
        .iter()
        .filter_map(|t| t.2)
        .fold(f64::INFINITY, f64::min);
    let want = trials
        .iter()
        .find(|t| t.2.is_some_and(|e| e <= best * 1.05))
        .unwrap();
    assert_eq!(chosen, want.0);
    assert_eq!(latent_dim(&auto), want.1);
    // The given degree is the only trial (the degree-3 model above).
    assert_eq!(selection(&low), (3, vec![(3, n3, selection(&low).1[0].2)]));

    // A smaller feature budget tries fewer degrees (1..=6: 28 features, degree 7 has 36).
    let budget = dir.join("edmd-budget");
    let r = train(&budget, &["--model", "edmd", "--edmd-max-features", "30"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert_eq!(selection(&budget).1.len(), 6);
    assert!(latent_dim(&budget) <= 30);

    // EDMD options on another model kind: refused, naming the fix, nothing written.
    let wrong = dir.join("koopman");
    let r = train(&wrong, &["--model", "koopman", "--edmd-degree", "3"]);
    assert!(!r.status.success());
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("--model edmd"), "{err}");
    assert!(!wrong.join("config.json").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}
