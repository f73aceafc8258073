//! `koopbridge sweep` against two real trainer services in separate processes: the points are
//! spread over both, a trainer killed mid-sweep loses its point to the other and, restarted, has
//! its orphaned job cancelled (no point trained twice, none lost), `results.csv` and the run
//! folders are complete, and a rerun trains nothing; a trainer the sweep started itself
//! (`--local-trainers`) that is killed is started again and resumes its job from its checkpoint.

mod common;

use std::collections::BTreeSet;
use std::path::Path;
use std::time::{Duration, Instant};

use bridge::keyexpr::Role;
use bridge::orchestrator::Cluster;
use bridge::services::trainer::{JobRecord, JobState};

fn jobs(c: &Cluster, trainer: &str) -> Vec<JobRecord> {
    let b = c
        .client
        .query(
            &c.client.keys.trainer_jobs(trainer).unwrap(),
            Vec::new(),
            Duration::from_secs(10),
            trainer,
        )
        .unwrap();
    serde_json::from_slice(&b).unwrap()
}

fn trainer(
    c: &Cluster,
    opts: &bridge::orchestrator::RunOptions,
    session: &str,
    id: &str,
    n: u32,
) -> bridge::procs::ChildProc {
    let state = opts.out_dir.join(id);
    let (store, state) = (
        state.join("models").display().to_string(),
        state.display().to_string(),
    );
    let root = opts.out_dir.join("data").display().to_string();
    common::spawn(
        c,
        opts,
        &format!("{id}-{n}"),
        &[
            "serve",
            "trainer",
            "models",
            "--session",
            session,
            "--id",
            id,
            "--store",
            &store,
            "--state-dir",
            &state,
            "--train-threads",
            "1",
            "--data-root",
            &root,
        ],
    )
}

fn sweep_cmd(
    c: &Cluster,
    session: &str,
    data: &Path,
    out: &Path,
    sets: &[&str],
) -> std::process::Command {
    let mut cmd = std::process::Command::new(common::exe());
    cmd.args(["sweep", "--data"])
        .arg(data)
        .args([
            "--samples",
            "200,400",
            "--seeds",
            "1,2",
            "--iterations",
            "3000",
        ])
        .args(["--set", "hidden=[32,32]", "--set", "validate_every=250"])
        .args(["--progress-every", "0"])
        .args([
            "--grace",
            "2",
            "--session",
            session,
            "--connect",
            &c.endpoint,
            "--out",
        ])
        .arg(out);
    for s in sets {
        cmd.args(["--set", s]);
    }
    cmd
}

#[test]
fn a_sweep_survives_a_trainer_killed_midway_and_resumes_without_training_twice() {
    let (c, opts, session) = common::cluster("sweep", &[], &[]);
    let data = opts.out_dir.join("data/pend");
    common::small_pendulum_dataset(&data, 3);
    let out = opts.out_dir.join("sweep");

    // `n_mult` is a grid field: setting it through --set is refused before anything runs.
    let refused = sweep_cmd(&c, &session, &data, &out, &["n_mult=2"])
        .output()
        .unwrap();
    assert!(!refused.status.success());
    assert!(
        String::from_utf8_lossy(&refused.stderr).contains("'n_mult' is set by the sweep's grid")
    );

    let mut t1 = trainer(&c, &opts, &session, "t1", 1);
    let _t2 = trainer(&c, &opts, &session, "t2", 1);
    c.live
        .wait_for(
            &[(Role::Trainer, "t1".into()), (Role::Trainer, "t2".into())],
            common::READY,
        )
        .unwrap();
    let log = opts.out_dir.join("sweep.log");
    let mut sweep = sweep_cmd(&c, &session, &data, &out, &[])
        .stdout(std::fs::File::create(&log).unwrap())
        .stderr(std::fs::File::create(opts.out_dir.join("sweep.err")).unwrap())
        .spawn()
        .unwrap();

    // Kill t1 while it trains a point, then bring it back after its point went to t2.
    let deadline = Instant::now() + common::READY;
    let orphan = loop {
        assert!(Instant::now() < deadline, "t1 never ran a job");
        if let Some(r) = jobs(&c, "t1")
            .into_iter()
            .find(|r| r.state == JobState::Running)
        {
            break r;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    t1.kill();
    let deadline = Instant::now() + common::READY;
    while !std::fs::read_to_string(&log)
        .unwrap_or_default()
        .contains("goes to another")
    {
        assert!(
            Instant::now() < deadline,
            "the killed trainer's point was not moved"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let _t1 = trainer(&c, &opts, &session, "t1", 2);
    c.live
        .wait_for(&[(Role::Trainer, "t1".into())], common::READY)
        .unwrap();

    let status = sweep.wait().unwrap();
    let stdout = std::fs::read_to_string(&log).unwrap();
    assert!(
        status.success(),
        "sweep failed:\n{stdout}\n{}",
        std::fs::read_to_string(opts.out_dir.join("sweep.err")).unwrap_or_default()
    );

    // Four points, each once, in the CSV and as run folders that `koopbridge scaling` reads.
    let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().skip(1).collect();
    assert_eq!(rows.len(), 4, "{csv}");
    let names: BTreeSet<&str> = rows.iter().map(|r| r.split(',').next().unwrap()).collect();
    assert_eq!(names.len(), 4);
    for r in &rows {
        let f: Vec<&str> = r.split(',').collect();
        let err: f64 = f[9].parse().unwrap();
        assert!(err.is_finite() && err > 0.0, "{r}");
        assert!(f[10].parse::<f64>().unwrap() >= 1.0, "κ(G) ≥ 1: {r}");
    }
    assert!(out.join("scaling-m/scaling.json").is_file(), "{stdout}");
    // Without a terminal, progress lines name the running points' iterations.
    assert!(
        stdout
            .lines()
            .any(|l| l.contains("points done") && l.contains("/3000 (t")),
        "{stdout}"
    );

    // The job t1 held when it died was either resumed (its point still waiting when t1 came
    // back) or cancelled (its point already on t2); either way no model of the sweep is done
    // on both trainers.
    let t1_jobs = jobs(&c, "t1");
    let o = t1_jobs
        .iter()
        .find(|r| r.job == orphan.job)
        .expect("t1 kept its job record");
    assert!(
        matches!(o.state, JobState::Cancelled | JobState::Done),
        "orphan: {o:?}"
    );
    let done = |t: &str| -> BTreeSet<String> {
        jobs(&c, t)
            .into_iter()
            .filter(|r| r.state == JobState::Done)
            .map(|r| r.spec.model)
            .collect()
    };
    let (d1, d2) = (done("t1"), done("t2"));
    assert!(
        d1.is_disjoint(&d2),
        "trained twice: {:?}",
        d1.intersection(&d2).collect::<Vec<_>>()
    );
    assert_eq!(d1.len() + d2.len(), 4);

    // A rerun finds everything finished and trains nothing.
    let again = sweep_cmd(&c, &session, &data, &out, &[]).output().unwrap();
    let text = String::from_utf8_lossy(&again.stdout);
    assert!(again.status.success(), "{text}");
    assert!(text.contains("4 points already finished"), "{text}");
    assert!(text.contains("0 trained in this run"), "{text}");
}

/// The pid of the process whose command line holds `needle` as one argument (not this one).
fn pid_with_argument(needle: &str) -> Option<u32> {
    std::fs::read_dir("/proc").ok()?.flatten().find_map(|e| {
        let pid: u32 = e.file_name().to_str()?.parse().ok()?;
        let cmd = std::fs::read(e.path().join("cmdline")).ok()?;
        let hit = cmd.split(|b| *b == 0).any(|a| a == needle.as_bytes());
        (hit && pid != std::process::id()).then_some(pid)
    })
}

/// Whether a file ending in `.ckpt` lies anywhere below `dir`.
fn has_checkpoint(dir: &Path) -> bool {
    std::fs::read_dir(dir).is_ok_and(|rd| {
        rd.flatten().any(|e| {
            let p = e.path();
            if p.is_dir() {
                has_checkpoint(&p)
            } else {
                p.extension().is_some_and(|x| x == "ckpt")
            }
        })
    })
}

#[test]
fn a_local_trainer_killed_midway_is_started_again_and_resumes_its_job() {
    let dir = common::scratch("sweep-local");
    let data = dir.join("data/pend");
    common::small_pendulum_dataset(&data, 5);
    let out = dir.join("sweep");
    let log = dir.join("sweep.log");
    let mut sweep = std::process::Command::new(common::exe())
        .arg("sweep")
        .arg("--data")
        .arg(&data)
        .args(["--samples", "200", "--seeds", "1", "--iterations", "2000"])
        .args(["--set", "hidden=[32,32]", "--set", "validate_every=250"])
        .args(["--local-trainers", "1", "--progress-every", "0", "--out"])
        .arg(&out)
        .stdout(std::fs::File::create(&log).unwrap())
        .stderr(std::fs::File::create(dir.join("sweep.err")).unwrap())
        .spawn()
        .unwrap();

    // Kill the trainer the sweep started once its job has written a checkpoint.
    let state = out.join("trainers/local0");
    let deadline = Instant::now() + common::READY;
    while !has_checkpoint(&state) {
        assert!(
            Instant::now() < deadline,
            "the local trainer wrote no checkpoint"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let pid = pid_with_argument(&state.display().to_string()).expect("the local trainer runs");
    let killed = std::process::Command::new("kill")
        .args(["-9", &pid.to_string()])
        .status()
        .unwrap();
    assert!(killed.success());

    let status = sweep.wait().unwrap();
    let stdout = std::fs::read_to_string(&log).unwrap();
    let stderr = std::fs::read_to_string(dir.join("sweep.err")).unwrap_or_default();
    assert!(status.success(), "sweep failed:\n{stdout}\n{stderr}");
    assert!(
        stdout.contains("trainer 'local0' exited") && stdout.contains("started again (1 of 3)"),
        "{stdout}"
    );
    // The first life's log is kept beside the second's.
    assert!(state.join("trainer.log.1").is_file() && state.join("trainer.log").is_file());
    // The point was finished by the restarted trainer from its checkpoint, not from scratch,
    // and never moved elsewhere (there is no other trainer).
    let metrics: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("runs/pend-m200-n16-s1-both-i2000/metrics.json"))
            .unwrap(),
    )
    .unwrap();
    let resumed = metrics["resumed_from"].as_u64().unwrap();
    assert!((250..2000).contains(&resumed), "resumed from {resumed}");
    assert!(!stdout.contains("goes to another"), "{stdout}");
    let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
    assert_eq!(csv.lines().count(), 2, "{csv}");
}
