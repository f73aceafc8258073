//! The trainer service trains every model kind named by a job's `config.kind` over Zenoh: an
//! NNDM and an EDMD job store a model of their kind whose reported test error equals an
//! independent evaluation of the stored model here; an unknown kind and a setting the kind
//! cannot honour are refused at submission with `bad_request` naming them, and the service goes
//! on serving.

mod common;

use bridge::orchestrator::{Cluster, SERVICES_ID};
use bridge::services::trainer::{submit_and_wait, JobSpec, JobState};

#[test]
fn each_kind_is_trained_and_bad_kinds_are_refused() {
    let (opts, session) = common::options("trainer-kinds");
    let dir = opts.out_dir.join("data");
    let r = common::pendulum_data(&dir, &[("train", 80, 1), ("val", 16, 2), ("test", 16, 3)]);
    let spec = |model: &str, config: serde_json::Value| JobSpec {
        model: model.into(),
        train: r("train"),
        val: r("val"),
        test: Some(r("test")),
        config: common::config(config),
    };
    let c = Cluster::start(&opts, &session, &[], &["trainer", "models"]).unwrap();
    let submit = |s: &JobSpec| submit_and_wait(&c.client, &c.live, SERVICES_ID, s, &mut |_| {});
    let refused = |s: &JobSpec| -> String {
        match submit(s) {
            Err(bridge::Error::Remote { reply, .. }) => {
                assert_eq!(reply.code, bridge::ErrorCode::BadRequest, "{reply:?}");
                reply.message
            }
            other => panic!("not refused: {other:?}"),
        }
    };
    let e = refused(&spec("bad", serde_json::json!({"kind": "dmd"})));
    assert!(
        e.contains("unknown model kind 'dmd'; valid kinds: koopman, bilinear, edmd, nndm"),
        "{e}"
    );
    let e = refused(&spec(
        "bad",
        serde_json::json!({"kind": "edmd", "iterations": 5}),
    ));
    assert!(
        e.contains("iterations does not apply to an edmd model"),
        "{e}"
    );
    let e = refused(&spec(
        "bad",
        serde_json::json!({"kind": "nndm", "normalise": true}),
    ));
    assert!(e.contains("not nndm"), "{e}");
    assert!(!opts.out_dir.join("models/bad").exists());

    let test = koopman::data::Dataset::load_npz(&dir.join("test.npz")).unwrap();
    let nndm = submit(&spec(
        "n",
        serde_json::json!({"kind": "nndm", "iterations": 30, "hidden": [16], "n_mult": 2,
            "batch": 16, "validate_every": 15, "ctrl": false}),
    ))
    .unwrap();
    let edmd = submit(&spec(
        "e",
        serde_json::json!({"kind": "edmd", "gamma": 0.8}),
    ))
    .unwrap();
    for (rec, name, kind) in [(&nndm, "n", "nndm"), (&edmd, "e", "edmd")] {
        assert_eq!(rec.state, JobState::Done, "{rec:?}");
        let m = rec.metrics.as_ref().unwrap();
        assert_eq!(m["kind"], kind);
        let model_dir = opts.out_dir.join("models").join(name);
        assert_eq!(koopman::model::store::read_kind(&model_dir).unwrap(), kind);
        let mine = if kind == "nndm" {
            let model = koopman::model::nndm::NndmModel::load(&model_dir).unwrap();
            koopman::train::nndm::prediction_error(&model, &test, 0.8).unwrap()
        } else {
            let model = koopman::model::edmd::EdmdModel::load(&model_dir).unwrap();
            model.prediction_error(&test, 0.8).unwrap()
        };
        let reported = m["test_prediction_error"].as_f64().unwrap();
        assert!(
            mine.is_finite() && (reported - mine).abs() <= 1e-9 * (1.0 + mine.abs()),
            "{kind}: reported {reported}, the stored model gives {mine}"
        );
    }
}
