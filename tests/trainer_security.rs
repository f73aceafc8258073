//! The trainer's data root over a real Zenoh session: a job naming a file outside the root
//! (`/etc/passwd`, a `../` escape, a symlink inside the root pointing outside) is refused at
//! submission with `forbidden`, whose message names no file, no job is queued for it, and the
//! service keeps serving: a job whose files lie inside the root is accepted and trains. A job
//! with an unknown training setting is refused at submission too, with `bad_request` naming the
//! valid settings.

mod common;

use std::path::PathBuf;
use std::time::Duration;

use bridge::orchestrator::{Cluster, SERVICES_ID};
use bridge::services::trainer::{submit_and_wait, DatasetRef, JobRecord, JobSpec, JobState};
use bridge::{Error, ErrorCode};

#[test]
fn paths_outside_the_data_root_are_forbidden_and_inside_ones_train() {
    let (opts, session) = common::options("trainer-security");
    // `koopbridge run`'s services get `--data-root {out}/data`: the data goes there.
    let r = common::pendulum_data(
        &opts.out_dir.join("data"),
        &[("train", 32, 1), ("val", 8, 2)],
    );
    let secret = opts.out_dir.join("secret");
    std::fs::create_dir_all(&secret).unwrap();
    std::fs::copy(
        opts.out_dir.join("data/train.npz"),
        secret.join("train.npz"),
    )
    .unwrap();
    std::os::unix::fs::symlink(secret.join("train.npz"), opts.out_dir.join("data/link.npz"))
        .unwrap();
    let path = |p: PathBuf| DatasetRef::Path { path: p };
    let spec = |train: DatasetRef| JobSpec {
        model: "guarded".into(),
        train,
        val: r("val"),
        test: None,
        config: common::config(serde_json::json!({"iterations": 20, "hidden": [8],
            "n_mult": 2, "batch": 8, "validate_every": 10})),
    };

    let c = Cluster::start(&opts, &session, &[], &["trainer", "models"]).unwrap();
    let jobs_key = c.client.keys.trainer_jobs(SERVICES_ID).unwrap();
    let submit = |s: &JobSpec| {
        c.client.query(
            &jobs_key,
            serde_json::to_vec(s).unwrap(),
            Duration::from_secs(30),
            "trainer",
        )
    };
    let refused = [
        path("/etc/passwd".into()),
        path("/etc/no-such-file".into()),
        path(opts.out_dir.join("data/../secret/train.npz")),
        path("../secret/train.npz".into()),
        path(opts.out_dir.join("data/link.npz")),
    ];
    for train in refused {
        let got = submit(&spec(train.clone()));
        match got {
            Err(Error::Remote { ref reply, .. }) => {
                assert_eq!(reply.code, ErrorCode::Forbidden, "{train:?}: {reply:?}");
                for word in ["passwd", "secret", "etc", "link", "no-such"] {
                    assert!(
                        !reply.message.contains(word),
                        "{train:?}: {}",
                        reply.message
                    );
                }
            }
            other => panic!("{train:?} was not refused: {other:?}"),
        }
        // Also as the validation or test set.
        let mut s = spec(r("train"));
        s.test = Some(train.clone());
        assert!(
            matches!(submit(&s), Err(Error::Remote { ref reply, .. }) if reply.code == ErrorCode::Forbidden),
            "test set {train:?}"
        );
    }
    // An unknown setting: bad_request at submission, listing the valid ones.
    let mut typo = spec(r("train"));
    typo.config.insert("iteratons".into(), 5.into());
    match submit(&typo) {
        Err(Error::Remote { ref reply, .. }) => {
            assert_eq!(reply.code, ErrorCode::BadRequest, "{reply:?}");
            for word in [
                "'iteratons'",
                "iterations",
                "validate_every",
                "hidden",
                "n_mult",
            ] {
                assert!(reply.message.contains(word), "{}", reply.message);
            }
        }
        other => panic!("a typo in the settings was accepted: {other:?}"),
    }
    // A setting of the wrong type: bad_request too.
    let mut wrong = spec(r("train"));
    wrong.config.insert("iterations".into(), "many".into());
    assert!(
        matches!(submit(&wrong), Err(Error::Remote { ref reply, .. }) if reply.code == ErrorCode::BadRequest),
        "a string for iterations was accepted"
    );
    // Nothing was queued for any of them.
    let b = c
        .client
        .query(&jobs_key, vec![], Duration::from_secs(30), "trainer")
        .unwrap();
    let list: Vec<JobRecord> = serde_json::from_slice(&b).unwrap();
    assert!(list.is_empty(), "{list:?}");

    // Inside the root, absolute or relative to it: accepted, and it trains.
    let rec = submit_and_wait(
        &c.client,
        &c.live,
        SERVICES_ID,
        &spec(r("train")),
        &mut |_| {},
    )
    .unwrap();
    assert_eq!(rec.state, JobState::Done, "{rec:?}");
    let relative = JobSpec {
        model: "relative".into(),
        ..spec(path("train.npz".into()))
    };
    let rec = submit_and_wait(&c.client, &c.live, SERVICES_ID, &relative, &mut |_| {}).unwrap();
    assert_eq!(rec.state, JobState::Done, "{rec:?}");
    assert!(opts
        .out_dir
        .join("models/relative/model.safetensors")
        .is_file());
}
