//! The trainer service gives the same model bits for the same job whatever the machine's thread
//! pool: two services whose rayon pools differ (RAYON_NUM_THREADS 1 and 3) train the same spec on
//! the same data into byte-identical `model.safetensors`.

mod common;

use bridge::keyexpr::Role;
use bridge::orchestrator::Cluster;
use bridge::procs::ChildProc;
use bridge::services::trainer::{submit_and_wait, JobSpec, JobState};

#[test]
fn the_same_job_gives_the_same_model_bits_on_different_thread_pools() {
    let (opts, session) = common::options("trainer-det");
    let r = common::pendulum_data(
        &opts.out_dir.join("data"),
        &[("train", 128, 1), ("val", 32, 2)],
    );
    let spec = JobSpec {
        model: "same".into(),
        train: r("train"),
        val: r("val"),
        test: None,
        config: common::config(serde_json::json!({"iterations": 300, "hidden": [16, 16],
            "n_mult": 4, "batch": 64, "validate_every": 100})),
    };
    let c = Cluster::start(&opts, &session, &[], &[]).unwrap();
    let (mut models, mut threads) = (Vec::new(), Vec::new());
    let data_root = opts.out_dir.join("data");
    for (id, pool) in [("ta", "1"), ("tb", "3")] {
        let base = opts.out_dir.join(id);
        let args: Vec<String> = [
            "serve",
            "trainer",
            "--id",
            id,
            "--session",
            &session,
            "--store",
            base.join("models").to_str().unwrap(),
            "--state-dir",
            base.join("state").to_str().unwrap(),
            "--data-root",
            data_root.to_str().unwrap(),
            "--stdin-lifeline",
            "--connect",
            &c.endpoint,
        ]
        .map(String::from)
        .to_vec();
        let _svc = ChildProc::spawn_env(
            id,
            &opts.exe,
            &args,
            &[("RAYON_NUM_THREADS", pool)],
            &opts.out_dir.join(format!("logs/{id}.log")),
        )
        .unwrap();
        c.live
            .wait_for(&[(Role::Trainer, id.into())], common::READY)
            .unwrap();
        let rec = submit_and_wait(&c.client, &c.live, id, &spec, &mut |_| {}).unwrap();
        assert_eq!(rec.state, JobState::Done);
        threads.push(rec.metrics.as_ref().unwrap()["config"]["threads"].clone());
        models.push(std::fs::read(base.join("models/same/model.safetensors")).unwrap());
    }
    assert_eq!(
        models[0], models[1],
        "the two services trained different bits"
    );
}
