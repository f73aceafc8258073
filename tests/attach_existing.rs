//! `koopbridge run --attach-existing` against participants started separately behind a
//! `koopbridge router`: the runner finds the services and the simulator by their liveliness
//! tokens and starts none of its own; without the flag it refuses to start duplicates.

mod common;

use std::process::Command;
use std::time::Duration;

use bridge::client::{Client, Liveliness};
use bridge::keyexpr::{fresh_session_id, Keys, Role};
use bridge::procs::ChildProc;
use bridge::session::{free_loopback_endpoint, open_session, ZenohOptions};

const TINY: &str = r#"
name = "ext"
[[sims]]
id = "pend"
env = "damped-pendulum"
[collect]
policy = { kind = "uniform" }
train_windows = 20
val_windows = 5
test_windows = 5
seed = 5
[train]
config = { iterations = 20, hidden = [8], n_mult = 2, batch = 8, validate_every = 10 }
[control]
x0 = [-1.0, 0.1]
reference = [0.0, 0.0]
steps = 5
"#;

#[test]
fn a_scenario_runs_against_participants_started_separately() {
    let dir = common::scratch("ext");
    let session = fresh_session_id();
    let ep = free_loopback_endpoint().unwrap();
    let a = |v: &[&str]| v.iter().map(|x| x.to_string()).collect::<Vec<_>>();
    let path = |p: &str| dir.join(p).display().to_string();
    let _router = ChildProc::spawn(
        "router",
        &common::exe(),
        &a(&["router", "--listen", &ep, "--stdin-lifeline"]),
        &dir.join("router.log"),
    )
    .unwrap();
    let z = ZenohOptions::peer(vec![], vec![ep.clone()]);
    let client = Client::new(open_session(&z).unwrap(), Keys::new(&session).unwrap());
    let live = Liveliness::new(&client).unwrap();
    let (store, state) = (path("ext-models"), path("ext-state"));
    let _services = ChildProc::spawn(
        "services",
        &common::exe(),
        &a(&[
            "serve",
            "trainer",
            "models",
            "mpc",
            "--session",
            &session,
            "--store",
            &store,
            "--state-dir",
            &state,
            "--data-root",
            &path(""),
            "--connect",
            &ep,
            "--stdin-lifeline",
        ]),
        &dir.join("services.log"),
    )
    .unwrap();
    let _sim = ChildProc::spawn(
        "sim",
        &common::exe(),
        &a(&[
            "sim",
            "--env",
            "damped-pendulum",
            "--id",
            "pend",
            "--session",
            &session,
            "--connect",
            &ep,
            "--stdin-lifeline",
        ]),
        &dir.join("sim.log"),
    )
    .unwrap();
    let who = [
        (Role::Sim, "pend".to_string()),
        (Role::Trainer, "main".to_string()),
        (Role::Models, "main".to_string()),
        (Role::Mpc, "main".to_string()),
    ];
    live.wait_for(&who, common::READY).unwrap();
    let sc = dir.join("ext.toml");
    std::fs::write(&sc, TINY).unwrap();
    let run = |out: &str, attach: bool| {
        let mut args = a(&[
            "run",
            sc.to_str().unwrap(),
            "--out",
            &path(out),
            "--session",
            &session,
            "--connect",
            &ep,
        ]);
        if attach {
            args.push("--attach-existing".into());
        }
        Command::new(common::exe()).args(args).output().unwrap()
    };

    // Without the flag: refused, naming the duplicates, before anything is started.
    let o = run("dup", false);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("sim/pend") && err.contains("trainer/main"),
        "{err}"
    );
    assert!(!dir.join("dup/logs").exists(), "children were started");

    let o = run("out", true);
    let all = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(o.status.success(), "{all}");
    assert!(
        all.contains("using the participants already in session"),
        "{all}"
    );
    // Nothing of its own was started: no child logs; the separate trainer stored the model.
    assert!(!dir.join("out/logs").exists(), "the run started children");
    assert!(dir.join("ext-models/ext-pend/config.json").is_file());
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("out/report.json")).unwrap()).unwrap();
    assert_eq!(r["control"]["x"].as_array().unwrap().len(), 6);
    assert_eq!(r["collect"]["windows"], serde_json::json!([20, 5, 5]));
    // The separately started participants are still there after the run.
    std::thread::sleep(Duration::from_millis(200));
    assert!(who.iter().all(|(r, id)| live.is_alive(*r, id)));
}
