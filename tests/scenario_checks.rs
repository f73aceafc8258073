//! `koopbridge run` checks the whole scenario right after the readiness barrier, before any
//! data is collected; reruns reuse unchanged data and models; external simulator commands run in
//! the scenario file's repository, and a command that cannot start or dies at once is reported
//! with its command line, naming its simulator once.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const BASE: &str = r#"
name = "chk"
[[sims]]
id = "pend"
env = "damped-pendulum"
[collect]
policy = { kind = "uniform" }
train_windows = 20
val_windows = 5
test_windows = 5
steps = 15
seed = 11
[train]
config = { iterations = 20, hidden = [8], n_mult = 2, batch = 8, validate_every = 10 }
[control]
x0 = [-1.0, 0.1]
reference = [0.0, 0.0]
steps = 5
mpc = { horizon = 10 }
"#;

/// Runs `koopbridge run` on `text` written to `dir/name.toml`, output in `dir/out`, from the
/// folder `cwd`.
fn run_in(dir: &Path, name: &str, text: &str, cwd: &Path) -> Output {
    let sc = dir.join(format!("{name}.toml"));
    std::fs::write(&sc, text).unwrap();
    let out = dir.join("out");
    Command::new(common::exe())
        .args(["run", sc.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .current_dir(cwd)
        .output()
        .unwrap()
}

fn run(dir: &Path, name: &str, text: &str) -> Output {
    run_in(dir, name, text, dir)
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn bad_settings_fail_before_collection() {
    let dir = common::scratch("chk-early");
    for (what, from, to, expect) in [
        (
            "train",
            "iterations = 20",
            "itrations = 20",
            &["itrations", "valid settings", "validate_every"][..],
        ),
        (
            "mpc field",
            "horizon = 10",
            "horizn = 10",
            &["horizn", "horizon"][..],
        ),
        (
            "mpc q",
            "horizon = 10",
            "horizon = 10, q = [1.0, 1.0, 1.0]",
            &["Q: expected 2, got 3"][..],
        ),
        (
            "x0",
            "x0 = [-1.0, 0.1]",
            "x0 = [-1.0, 0.1, 0.0]",
            &["x0 has 3 values", "2 states"][..],
        ),
        (
            "reference",
            "reference = [0.0, 0.0]",
            "reference = [0.0]",
            &["reference has 1 values"][..],
        ),
        (
            "offset_free gains on a linear model",
            "mpc = { horizon = 10 }",
            "mpc = { horizon = 10 }\noffset_free = { mode = \"trajectory\", radius = 1.0, gain = [0.5] }",
            &["offset_free", "expected 2, got 1"][..],
        ),
        (
            "offset_free gains",
            "config = { iterations = 20,",
            "config = { bilinear = true, iterations = 20,",
            &[][..],
        ),
    ] {
        let d = dir.join(what.replace(' ', "-"));
        std::fs::create_dir_all(&d).unwrap();
        let mut text = BASE.replace(from, to);
        assert_ne!(text, BASE, "{what}: the replacement did not apply");
        let mut expect = expect.to_vec();
        if what == "offset_free gains" {
            // A bilinear model, and a correction with one gain for two states.
            text.push_str("offset_free = { mode = \"trajectory\", radius = 1.0, gain = [0.5] }\n");
            expect = vec!["offset_free", "expected 2, got 1"];
        }
        let o = run(&d, "chk", &text);
        let err = stderr(&o);
        assert!(!o.status.success(), "{what}: the run succeeded:\n{err}");
        for e in &expect {
            assert!(err.contains(e), "{what}: no {e:?} in:\n{err}");
        }
        assert!(
            !d.join("out/data/pend/train.npz").exists(),
            "{what}: data was collected before the check failed"
        );
    }
}

fn report(dir: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(dir.join("out/report.json")).unwrap()).unwrap()
}

fn modified(p: &Path) -> std::time::SystemTime {
    std::fs::metadata(p).unwrap().modified().unwrap()
}

#[test]
fn a_rerun_reuses_unchanged_data_and_models() {
    let dir = common::scratch("chk-reuse");
    let o = run(&dir, "chk", BASE);
    assert!(o.status.success(), "{}", stderr(&o));
    let first = report(&dir);
    assert_eq!(first["collect"]["reused"], false);
    let data = dir.join("out/data/pend/train.npz");
    let (t_data, model_cfg) = (modified(&data), dir.join("out/models/chk-pend/config.json"));
    let t_model = modified(&model_cfg);

    // Same scenario: nothing is collected or trained again, and the output says so.
    let o = run(&dir, "chk", BASE);
    assert!(o.status.success(), "{}", stderr(&o));
    let all = format!("{}{}", String::from_utf8_lossy(&o.stdout), stderr(&o));
    assert!(all.contains("reusing the data"), "{all}");
    assert!(all.contains("reusing model 'chk-pend'"), "{all}");
    let again = report(&dir);
    assert_eq!(again["collect"]["reused"], true);
    assert_eq!(again["train"][0]["reused"], true);
    assert_eq!(again["train"][0]["job"], first["train"][0]["job"]);
    assert_eq!(again["collect"]["files"], first["collect"]["files"]);
    assert_eq!(modified(&data), t_data);
    assert_eq!(modified(&model_cfg), t_model);
    assert_eq!(again["control"]["x"].as_array().unwrap().len(), 6);

    // Another [train]: the data is reused, the model trained again.
    let o = run(
        &dir,
        "chk",
        &BASE.replace("iterations = 20", "iterations = 30"),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let third = report(&dir);
    assert_eq!(third["collect"]["reused"], true);
    assert_eq!(third["train"][0]["reused"], false);
    assert_eq!(third["train"][0]["metrics"]["iterations"], 30);
    assert_eq!(modified(&data), t_data);

    // Another [collect]: collected again.
    let o = run(&dir, "chk", &BASE.replace("seed = 11", "seed = 12"));
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(report(&dir)["collect"]["reused"], false);
    assert_ne!(modified(&data), t_data);
}

/// A fake repository with an adapter script `bin/NAME.sh` (made executable) and a marker file.
fn fake_repo(dir: &Path, name: &str, script: &str) -> PathBuf {
    let repo = dir.join("repo");
    std::fs::create_dir_all(repo.join(".git")).unwrap();
    std::fs::create_dir_all(repo.join("bin")).unwrap();
    std::fs::create_dir_all(repo.join("scenarios")).unwrap();
    std::fs::write(repo.join("marker"), "").unwrap();
    let p = repo.join(format!("bin/{name}.sh"));
    std::fs::write(&p, script).unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).unwrap();
    repo
}

const COLLECT_ONLY: &str = r#"
name = "cmd"
[[sims]]
id = "pend"
env = "damped-pendulum"
command = ["bin/NAME.sh"]
[collect]
policy = { kind = "uniform" }
train_windows = 3
val_windows = 0
test_windows = 0
"#;

#[test]
fn commands_run_in_the_scenarios_repository_and_failures_name_their_simulator() {
    let dir = common::scratch("chk-cmd");
    let exe = common::exe();
    // It only works if run from the repository root: it checks for ./marker.
    let ok = format!(
        "#!/bin/sh\ntest -f ./marker || {{ echo 'not in the repository' >&2; exit 3; }}\nexec '{}' sim --env damped-pendulum \"$@\"\n",
        exe.display()
    );
    let repo = fake_repo(&dir, "ok", &ok);
    let elsewhere = dir.join("elsewhere");
    std::fs::create_dir_all(&elsewhere).unwrap();
    let o = run_in(
        &repo.join("scenarios"),
        "ok",
        &COLLECT_ONLY.replace("NAME", "ok"),
        &elsewhere,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(repo.join("scenarios/out/data/pend/train.npz").is_file());

    // A command that dies at start: its command line and the end of its log.
    fake_repo(
        &dir,
        "boom",
        "#!/bin/sh\necho 'boom: no such FMU' >&2\nexit 2\n",
    );
    let o = run_in(
        &repo.join("scenarios"),
        "boom",
        &COLLECT_ONLY.replace("NAME", "boom"),
        &elsewhere,
    );
    let err = stderr(&o);
    assert!(!o.status.success());
    assert!(err.contains("boom: no such FMU"), "{err}");
    assert!(err.contains("bin/boom.sh --id pend --session"), "{err}");

    // A program that does not exist: named with its simulator, once.
    let o = run_in(
        &repo.join("scenarios"),
        "missing",
        &COLLECT_ONLY.replace("bin/NAME.sh", "no-such-adapter-program"),
        &elsewhere,
    );
    let err = stderr(&o);
    assert!(!o.status.success());
    assert_eq!(err.matches("simulator 'pend'").count(), 1, "{err}");
    assert!(err.contains("no-such-adapter-program --id pend"), "{err}");
}
