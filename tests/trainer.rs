//! The trainer service over Zenoh: a submitted job trains a real (tiny) model whose reported test
//! error matches an independent evaluation of the stored model, a job left unfinished by a
//! previous service run (without a checkpoint) is re-run from its persisted spec when the service
//! starts again, and a new spec for the same model supersedes an unfinished job.

mod common;

use bridge::orchestrator::{Cluster, SERVICES_ID};
use bridge::services::trainer::{submit_and_wait, JobRecord, JobSpec, JobState};

fn tiny_config() -> serde_json::Map<String, serde_json::Value> {
    common::config(
        serde_json::json!({"iterations": 40, "hidden": [16], "n_mult": 2, "batch": 16, "validate_every": 20}),
    )
}

#[test]
fn jobs_train_store_models_and_resume_after_a_restart() {
    let (opts, session) = common::options("trainer");
    let dir = opts.out_dir.join("data");
    let r = common::pendulum_data(&dir, &[("train", 64, 1), ("val", 16, 2), ("test", 16, 3)]);
    let spec = |model: &str| JobSpec {
        model: model.into(),
        train: r("train"),
        val: r("val"),
        test: Some(r("test")),
        config: tiny_config(),
    };
    // A job left `running` by a "previous" service: it must be re-run on start.
    let jobs = opts.out_dir.join("state/trainer/jobs");
    std::fs::create_dir_all(&jobs).unwrap();
    let stale = JobRecord {
        job: "j0000-stale".into(),
        spec: spec("resumed"),
        state: JobState::Running,
        progress: None,
        metrics: None,
        error: None,
        attempts: 1,
        resumed_from: 0,
    };
    std::fs::write(
        jobs.join("j0000-stale.json"),
        serde_json::to_vec(&stale).unwrap(),
    )
    .unwrap();

    let c = Cluster::start(&opts, &session, &[], &["trainer", "models"]).unwrap();
    let mut progress = 0;
    let rec = submit_and_wait(&c.client, &c.live, SERVICES_ID, &spec("fresh"), &mut |_| {
        progress += 1
    })
    .unwrap();
    assert_eq!(rec.state, JobState::Done);
    let model_dir = opts.out_dir.join("models/fresh");
    let model = koopman::model::koopman::KoopmanModel::load(&model_dir).unwrap();
    let test = koopman::data::Dataset::load_npz(&dir.join("test.npz")).unwrap();
    let mine = koopman::train::prediction_error(&model, &test, 0.8).unwrap();
    let reported = rec.metrics.as_ref().unwrap()["test_prediction_error"]
        .as_f64()
        .unwrap();
    assert!(
        (mine - reported).abs() <= 1e-5 * mine.abs().max(1e-12),
        "reported {reported}, recomputed {mine}"
    );
    assert!(model_dir.join("metrics.json").is_file());

    // The stale job ran again (attempt 2) and produced its model.
    let deadline = std::time::Instant::now() + common::READY;
    loop {
        let b = c
            .client
            .query(
                &c.client
                    .keys
                    .trainer_job(SERVICES_ID, "j0000-stale")
                    .unwrap(),
                vec![],
                std::time::Duration::from_secs(30),
                "trainer",
            )
            .unwrap();
        let r: JobRecord = serde_json::from_slice(&b).unwrap();
        if r.state == JobState::Done {
            assert_eq!(r.attempts, 2);
            break;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "stale job not resumed: {r:?}"
        );
        std::thread::sleep(std::time::Duration::from_millis(200));
    }
    assert!(opts
        .out_dir
        .join("models/resumed/model.safetensors")
        .is_file());
    // A bad job spec is refused with a typed error and the service keeps serving.
    let bad = c.client.query(
        &c.client.keys.trainer_jobs(SERVICES_ID).unwrap(),
        br#"{"model": 3}"#.to_vec(),
        std::time::Duration::from_secs(30),
        "trainer",
    );
    assert!(
        matches!(bad, Err(bridge::Error::Remote { ref reply, .. }) if reply.code == bridge::ErrorCode::BadRequest),
        "{bad:?}"
    );
    let _ = progress;

    // A new spec for the same model supersedes an unfinished job with another spec.
    let long = JobSpec {
        config: common::config(serde_json::json!({"iterations": 100000, "hidden": [16],
            "n_mult": 2, "batch": 16, "validate_every": 1000})),
        ..spec("shared")
    };
    let b = c
        .client
        .query(
            &c.client.keys.trainer_jobs(SERVICES_ID).unwrap(),
            serde_json::to_vec(&long).unwrap(),
            std::time::Duration::from_secs(30),
            "trainer",
        )
        .unwrap();
    let old = serde_json::from_slice::<bridge::services::trainer::SubmitReply>(&b)
        .unwrap()
        .job;
    let newer = submit_and_wait(
        &c.client,
        &c.live,
        SERVICES_ID,
        &spec("shared"),
        &mut |_| {},
    )
    .unwrap();
    assert_ne!(newer.job, old);
    let b = c
        .client
        .query(
            &c.client.keys.trainer_job(SERVICES_ID, &old).unwrap(),
            vec![],
            std::time::Duration::from_secs(30),
            "trainer",
        )
        .unwrap();
    let r: JobRecord = serde_json::from_slice(&b).unwrap();
    assert_eq!(r.state, JobState::Cancelled, "{r:?}");
    assert!(r
        .error
        .unwrap()
        .contains(&format!("superseded by job {}", newer.job)));
}
