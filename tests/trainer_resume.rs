//! A trainer service killed with SIGKILL in the middle of a job resumes it from its checkpoint
//! when it starts again: the job reports that it started at an iteration > 0, the resubmitted
//! spec finds the same job, and the model equals bit for bit that of an uninterrupted run.

mod common;

use std::time::{Duration, Instant};

use bridge::keyexpr::fresh_session_id;
use bridge::orchestrator::{Cluster, SERVICES_ID};
use bridge::services::koopman_trainer::{train_config, DEFAULT_TRAIN_THREADS};
use bridge::services::trainer::{submit_and_wait, JobRecord, JobSpec, JobState, SubmitReply};
use koopman::data::Dataset;

/// Long enough (a few seconds) that the service can be killed between its first checkpoint
/// (iteration 200) and the end.
fn config() -> serde_json::Map<String, serde_json::Value> {
    common::config(
        serde_json::json!({"iterations": 3000, "hidden": [64, 64], "n_mult": 8,
                                      "batch": 64, "validate_every": 200}),
    )
}

#[test]
fn a_killed_trainer_resumes_its_job_from_the_checkpoint() {
    let (opts, session) = common::options("trainer-resume");
    let dir = opts.out_dir.join("data");
    let r = common::pendulum_data(&dir, &[("train", 256, 1), ("val", 32, 2)]);
    let spec = JobSpec {
        model: "resumed".into(),
        train: r("train"),
        val: r("val"),
        test: None,
        config: config(),
    };

    // First service: submit, wait for the first checkpoint, kill -9.
    let c = Cluster::start(&opts, &session, &[], &["trainer"]).unwrap();
    let b = c
        .client
        .query(
            &c.client.keys.trainer_jobs(SERVICES_ID).unwrap(),
            serde_json::to_vec(&spec).unwrap(),
            Duration::from_secs(30),
            "trainer",
        )
        .unwrap();
    let job = serde_json::from_slice::<SubmitReply>(&b).unwrap().job;
    let jobs = opts.out_dir.join("state/trainer/jobs");
    let ckpt = jobs.join(format!("{job}.ckpt"));
    let deadline = Instant::now() + common::READY;
    while !ckpt.exists() {
        assert!(Instant::now() < deadline, "no checkpoint appeared");
        std::thread::sleep(Duration::from_millis(2));
    }
    let pid = c.children[0].id().to_string();
    let killed = std::process::Command::new("kill")
        .args(["-9", &pid])
        .status()
        .unwrap();
    assert!(killed.success());
    drop(c);
    let rec: JobRecord =
        serde_json::from_slice(&std::fs::read(jobs.join(format!("{job}.json"))).unwrap()).unwrap();
    assert_eq!(
        rec.state,
        JobState::Running,
        "the job must have been interrupted (it finished before the kill: make it longer)"
    );
    assert!(!opts.out_dir.join("models/resumed").exists());
    let at_kill = koopman::train::Checkpoint::load(&ckpt).unwrap().iteration;
    assert!((200..3000).contains(&at_kill), "{at_kill}");

    // Second service on the same state: the job continues; resubmitting finds it.
    let c = Cluster::start(&opts, &fresh_session_id(), &[], &["trainer", "models"]).unwrap();
    let mut first_progress = None;
    let done = submit_and_wait(&c.client, &c.live, SERVICES_ID, &spec, &mut |p| {
        if first_progress.is_none() {
            first_progress = p["iteration"].as_u64();
        }
    })
    .unwrap();
    assert_eq!(
        done.job, job,
        "the resubmitted spec must find the unfinished job"
    );
    assert_eq!(done.state, JobState::Done);
    assert_eq!(done.attempts, 2);
    assert!(done.resumed_from >= at_kill as u64, "{done:?}");
    assert_eq!(
        done.metrics.as_ref().unwrap()["resumed_from"],
        done.resumed_from
    );
    if let Some(it) = first_progress {
        assert!(it > done.resumed_from, "progress started at {it}");
    }
    assert!(
        !ckpt.exists(),
        "the checkpoint of a finished job is deleted"
    );

    // The same training, uninterrupted and in this process: the same bits.
    let mut cfg = train_config(&spec.config).unwrap();
    cfg.threads = DEFAULT_TRAIN_THREADS;
    let tr = Dataset::load_npz(&dir.join("train.npz")).unwrap();
    let va = Dataset::load_npz(&dir.join("val.npz")).unwrap();
    let whole = koopman::train::train(&cfg, &tr, &va, None, &mut |_| {
        std::ops::ControlFlow::Continue(())
    })
    .unwrap();
    let mine = opts.out_dir.join("uninterrupted");
    whole.model.save(&mine).unwrap();
    assert_eq!(
        std::fs::read(mine.join("model.safetensors")).unwrap(),
        std::fs::read(opts.out_dir.join("models/resumed/model.safetensors")).unwrap(),
        "the resumed job's model differs from an uninterrupted run's"
    );
}
