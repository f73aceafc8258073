//! `koopbridge run` end to end on a tiny scenario: the orchestrator starts its own simulator and
//! services, collects, trains through the trainer service, controls through the MPC service and
//! writes a consistent report; collection is bit-for-bit identical across two runs.

mod common;

use std::process::Command;

/// The small pendulum scenario ([`common::PENDULUM_BASE`]) with a regulation task.
fn tiny() -> String {
    format!(
        "name = \"tiny\"\n{}[control]\nx0 = [-2.5, 0.1]\nreference = [0.0, 0.0]\nsteps = 20\n",
        common::PENDULUM_BASE
    )
}

fn run_once(dir: &std::path::Path) -> serde_json::Value {
    let sc = dir.join("tiny.toml");
    std::fs::write(&sc, tiny()).unwrap();
    let out = dir.join("out");
    let o = common::run_scenario(&sc, &out, &[]);
    assert_quiet_logs(
        &String::from_utf8_lossy(&o.stdout),
        &String::from_utf8_lossy(&o.stderr),
        &out,
    );
    serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap()
}

/// A successful run prints no colour codes and no Zenoh `ERROR` lines (closing-order
/// artefacts), neither on its own stderr nor in its children's log files, and says "never"
/// rather than `None` for a goal it did not reach.
fn assert_quiet_logs(stdout: &str, stderr: &str, out: &std::path::Path) {
    let mut texts = vec![
        ("koopbridge run's stdout".to_string(), stdout.to_string()),
        ("koopbridge run's stderr".to_string(), stderr.to_string()),
    ];
    for e in std::fs::read_dir(out.join("logs")).expect("the run keeps logs/") {
        let p = e.unwrap().path();
        texts.push((
            p.display().to_string(),
            std::fs::read_to_string(&p).unwrap(),
        ));
    }
    assert!(texts.len() > 1, "no child logs in {}", out.display());
    for (name, text) in &texts {
        assert!(
            !text.contains('\u{1b}'),
            "ANSI escape codes in {name}:\n{text}"
        );
        assert!(
            !text.lines().any(|l| l.contains(" ERROR ")),
            "ERROR lines in {name} of a successful run:\n{text}"
        );
    }
    let line = stdout
        .lines()
        .find(|l| l.contains("time to goal"))
        .unwrap_or_else(|| panic!("no control summary in:\n{stdout}"));
    assert!(!line.contains("None"), "{line}");
}

#[test]
fn a_tiny_scenario_runs_end_to_end_and_repeats_its_data() {
    let a = common::scratch("scn-a");
    let b = common::scratch("scn-b");
    let ra = run_once(&a);
    assert_eq!(ra["collect"]["windows"], serde_json::json!([40, 10, 10]));
    assert_eq!(ra["train"][0]["model"], "tiny-pend");
    assert!(ra["train"][0]["metrics"]["test_prediction_error"]
        .as_f64()
        .unwrap()
        .is_finite());
    let x = ra["control"]["x"].as_array().unwrap();
    assert_eq!(x.len(), 21);
    assert_eq!(x[0], serde_json::json!([-2.5, 0.1]));
    assert_eq!(ra["control"]["u"].as_array().unwrap().len(), 20);
    assert!(a.join("out/control.png").is_file());
    let rb = run_once(&b);
    assert_ne!(ra["session"], rb["session"]);
    for f in ["train", "val", "test"] {
        let p = format!("out/data/pend/{f}.npz");
        assert_eq!(
            std::fs::read(a.join(&p)).unwrap(),
            std::fs::read(b.join(&p)).unwrap(),
            "{f} differs between runs"
        );
    }
}

/// Long enough training (a few seconds) that the simulator can be killed between the first
/// checkpoint and the end.
const SLOW_TRAIN: &str = r#"
name = "restart"
[[sims]]
id = "pend"
env = "damped-pendulum"
[collect]
policy = { kind = "uniform" }
train_windows = 200
val_windows = 40
test_windows = 40
steps = 15
seed = 3
[train]
config = { iterations = 3000, hidden = [64, 64], n_mult = 8, batch = 64, validate_every = 200 }
[control]
x0 = [-1.0, 0.1]
reference = [0.0, 0.0]
steps = 10
"#;

/// The child process of `parent` whose command line has the argument `arg`.
fn child_with_arg(parent: u32, arg: &str) -> Option<u32> {
    common::children_of(parent).into_iter().find(|pid| {
        let cmd = std::fs::read(format!("/proc/{pid}/cmdline")).unwrap_or_default();
        cmd.split(|&b| b == 0).any(|a| a == arg.as_bytes())
    })
}

#[test]
fn a_simulator_killed_in_training_ends_the_run_at_once_and_the_rerun_resumes() {
    use std::time::{Duration, Instant};
    let dir = common::scratch("scn-restart");
    let sc = dir.join("restart.toml");
    std::fs::write(&sc, SLOW_TRAIN).unwrap();
    let out = dir.join("out");
    let args = ["run", sc.to_str().unwrap(), "--out", out.to_str().unwrap()];
    let mut run = Command::new(common::exe())
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Wait until training has written its first checkpoint, then kill the simulator.
    let jobs = out.join("state/trainer/jobs");
    let deadline = Instant::now() + common::READY;
    let ckpt = loop {
        let found = std::fs::read_dir(&jobs).ok().and_then(|d| {
            d.flatten()
                .map(|e| e.path())
                .find(|p| p.extension().is_some_and(|x| x == "ckpt"))
        });
        if let Some(p) = found {
            break p;
        }
        assert!(run.try_wait().unwrap().is_none(), "the run ended early");
        assert!(Instant::now() < deadline, "training never checkpointed");
        std::thread::sleep(Duration::from_millis(5));
    };
    let sim = child_with_arg(run.id(), "sim").expect("the simulator child process");
    let t0 = Instant::now();
    assert!(Command::new("kill")
        .args(["-9", &sim.to_string()])
        .status()
        .unwrap()
        .success());
    let status = loop {
        if let Some(s) = run.try_wait().unwrap() {
            break s;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "the run did not end after its simulator died"
        );
        std::thread::sleep(Duration::from_millis(5));
    };
    let ended = t0.elapsed();
    eprintln!("the run ended {ended:?} after its simulator was killed");
    let mut stderr = String::new();
    std::io::Read::read_to_string(run.stderr.as_mut().unwrap(), &mut stderr).unwrap();
    assert!(!status.success());
    assert!(stderr.contains("simulator 'pend'"), "{stderr}");
    assert!(
        ended < Duration::from_secs(1),
        "the run took {ended:?} to end"
    );
    // The job was interrupted mid-training: its checkpoint is still there.
    assert!(ckpt.is_file(), "the interrupted job kept its checkpoint");
    assert!(!out.join("report.json").exists());

    // The same command again, same output folder, nothing cleaned: it succeeds, and the
    // training continues from the interrupted job's checkpoint.
    let o = Command::new(common::exe()).args(args).output().unwrap();
    assert!(
        o.status.success(),
        "the rerun failed:\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let job = ckpt.file_stem().unwrap().to_str().unwrap();
    assert_eq!(
        r["train"][0]["job"], job,
        "the rerun found the interrupted job"
    );
    let from = r["train"][0]["metrics"]["resumed_from"].as_u64().unwrap();
    assert!(from >= 200, "resumed_from = {from}");
    assert_eq!(r["control"]["x"].as_array().unwrap().len(), 11);
    assert!(!ckpt.exists());
}
