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

    // The default degree is the largest within 250 features: far larger.
    let auto = dir.join("edmd-auto");
    let r = train(&auto, &["--model", "edmd"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(latent_dim(&auto) > 200, "{}", latent_dim(&auto));

    // A smaller feature budget chooses a smaller degree.
    let budget = dir.join("edmd-budget");
    let r = train(&budget, &["--model", "edmd", "--edmd-max-features", "30"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(latent_dim(&budget) <= 30 && latent_dim(&budget) > n3);

    // EDMD options on another model kind: refused, naming the fix, nothing written.
    let wrong = dir.join("koopman");
    let r = train(&wrong, &["--model", "koopman", "--edmd-degree", "3"]);
    assert!(!r.status.success());
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("--model edmd"), "{err}");
    assert!(!wrong.join("config.json").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}
