//! A bilinear scenario end to end: `[train] config = { bilinear = true }` trains a bilinear model
//! through the trainer service, the MPC service plans with the sequential convex MPC and its
//! trajectory correction (`[control] offset_free`), and every input the loop applied equals the
//! one a `BilinearMpc` in this process computes from the same states with the same settings — so
//! the service kept the correction's history across the loop's solves (a service that forgot it,
//! or planned without the correction, would send other inputs: checked too).

mod common;

use koopman::model::bilinear::BilinearModel;
use koopman::mpc::{BilinearMpc, MpcConfig, OffsetFreeConfig, OffsetMode, Policy, ScpOptions};

const SCENARIO: &str = r#"
name = "bil"
[[sims]]
id = "pend"
env = "damped-pendulum"
[collect]
policy = { kind = "uniform" }
train_windows = 60
val_windows = 10
test_windows = 10
steps = 15
seed = 5
[train]
config = { bilinear = true, iterations = 40, hidden = [16], n_mult = 2, batch = 16, validate_every = 20 }
[control]
x0 = [-0.6, 0.1]
reference = [0.0, 0.0]
steps = 25
mpc = { horizon = 8, r = [0.1] }
offset_free = { mode = "trajectory", radius = 10.0, gain = [0.5, 0.5], angles = [0] }
"#;

fn rows(v: &serde_json::Value) -> Vec<Vec<f64>> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|r| {
            r.as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect()
        })
        .collect()
}

#[test]
fn a_bilinear_model_is_trained_and_controlled_through_the_services() {
    let dir = common::scratch("scn-bilinear");
    let sc = dir.join("bil.toml");
    std::fs::write(&sc, SCENARIO).unwrap();
    let out = dir.join("out");
    common::run_scenario(&sc, &out, &[]);
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let name = report["train"][0]["model"].as_str().unwrap().to_string();
    let model_dir = out.join("models").join(&name);
    assert_eq!(
        koopman::model::store::read_kind(&model_dir).unwrap(),
        "bilinear"
    );
    let model = BilinearModel::load(&model_dir).unwrap();
    let (xs, us) = (rows(&report["control"]["x"]), rows(&report["control"]["u"]));
    assert_eq!((xs.len(), us.len()), (26, 25));

    // The same controller here: the simulator's bounds (±8), the scenario's settings.
    let cfg = MpcConfig {
        horizon: 8,
        r: Some(vec![0.1]),
        ..MpcConfig::with_bounds(vec![-8.0], vec![8.0])
    };
    let offset = OffsetFreeConfig {
        mode: OffsetMode::Trajectory,
        radius: 10.0,
        gain: vec![0.5, 0.5],
        angles: vec![0],
    };
    let replay = |correction: Option<OffsetFreeConfig>| -> Vec<Vec<f64>> {
        let mut mpc = BilinearMpc::new(&model, &cfg, ScpOptions::default()).unwrap();
        mpc.set_offset_free(correction).unwrap();
        let r = [0.0, 0.0];
        xs[..us.len()]
            .iter()
            .map(|x| mpc.act(x, &r, &r).unwrap().u)
            .collect()
    };
    let here = replay(Some(offset));
    for (k, (a, b)) in us.iter().zip(&here).enumerate() {
        assert!(
            (a[0] - b[0]).abs() <= 1e-9 * (1.0 + b[0].abs()),
            "step {k}: the service applied {a:?}, this process computes {b:?}"
        );
    }
    // The correction changed the inputs: without it the plans differ.
    let plain = replay(None);
    let differ = us
        .iter()
        .zip(&plain)
        .filter(|(a, b)| (a[0] - b[0]).abs() > 1e-6)
        .count();
    assert!(differ > 0, "the correction never changed an input");
}
