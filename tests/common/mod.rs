//! Shared helpers of the integration tests: a fresh session with its own loopback port, child
//! processes started from the built `koopbridge` binary.
#![allow(dead_code)]

use std::path::PathBuf;
use std::time::Duration;

use bridge::keyexpr::fresh_session_id;
use bridge::orchestrator::{Cluster, RunOptions};
use bridge::procs::ChildProc;
use bridge::session::ZenohOptions;

/// Generous timeout for a loaded 2-core machine.
pub const READY: Duration = Duration::from_secs(90);

/// A scratch folder unique to this test.
pub fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!(
        "kb-it-{name}-{}-{}",
        std::process::id(),
        fresh_session_id()
    ));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The built binary.
pub fn exe() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_koopbridge"))
}

/// Run options for a test: fresh session, own port, own scratch folder.
pub fn options(name: &str) -> (RunOptions, String) {
    let session = fresh_session_id();
    (
        RunOptions {
            exe: exe(),
            out_dir: scratch(name),
            zenoh: ZenohOptions::default(),
            session: Some(session.clone()),
            ready_timeout: READY,
            attach_existing: false,
        },
        session,
    )
}

/// Starts a cluster of simulators `(id, env)` and services.
pub fn cluster(
    name: &str,
    sims: &[(&str, &str)],
    services: &[&str],
) -> (Cluster, RunOptions, String) {
    let (opts, session) = options(name);
    let sims: Vec<(String, String)> = sims
        .iter()
        .map(|(a, b)| (a.to_string(), b.to_string()))
        .collect();
    let c = Cluster::start(&opts, &session, &sims, services).expect("cluster did not start");
    (c, opts, session)
}

/// Starts another `koopbridge` child with `args` connected to the cluster.
pub fn spawn(c: &Cluster, opts: &RunOptions, name: &str, args: &[&str]) -> ChildProc {
    let mut a: Vec<String> = args.iter().map(|s| s.to_string()).collect();
    a.extend([
        "--stdin-lifeline".to_string(),
        "--connect".to_string(),
        c.endpoint.clone(),
    ]);
    ChildProc::spawn(
        name,
        &opts.exe,
        &a,
        &opts.out_dir.join(format!("logs/{name}.log")),
    )
    .unwrap()
}

/// Starts `koopbridge sim --env damped-pendulum --free-run` as simulator `id` at `rate` Hz for
/// `steps` steps, waiting up to 30 s for a state subscriber; `extra` adds more arguments.
pub fn spawn_free_run_pendulum(
    c: &Cluster,
    opts: &RunOptions,
    session: &str,
    id: &str,
    rate: u32,
    steps: u64,
    extra: &[&str],
) -> ChildProc {
    let (rate, steps) = (rate.to_string(), steps.to_string());
    let mut args = vec![
        "sim",
        "--env",
        "damped-pendulum",
        "--id",
        id,
        "--session",
        session,
        "--free-run",
        "--rate",
        &rate,
        "--steps",
        &steps,
        "--wait-subscriber",
        "30",
    ];
    args.extend_from_slice(extra);
    spawn(c, opts, id, &args)
}

/// Waits until simulator `id` has announced itself and then withdrawn its liveliness token
/// (a free-run simulator does so after its last step); panics after 120 s.
pub fn wait_until_sim_finished(c: &Cluster, id: &str) {
    use bridge::keyexpr::Role;
    c.live.wait_for(&[(Role::Sim, id.into())], READY).unwrap();
    let deadline = std::time::Instant::now() + Duration::from_secs(120);
    while !c.live.is_gone(Role::Sim, id) {
        assert!(
            std::time::Instant::now() < deadline,
            "free-run simulator '{id}' did not finish"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Writes damped-pendulum datasets (aligned pairing, 15 steps) `dir/{name}.npz` for each
/// `(name, windows, seed)`, and returns a function giving the job reference of a name.
pub fn pendulum_data(
    dir: &std::path::Path,
    sets: &[(&str, usize, u64)],
) -> impl Fn(&str) -> bridge::services::trainer::DatasetRef {
    let sys = koopman::systems::by_name("damped-pendulum").unwrap();
    std::fs::create_dir_all(dir).unwrap();
    for &(name, n, seed) in sets {
        koopman::data::generate(sys.as_ref(), n, 15, seed, koopman::data::Pairing::Aligned)
            .unwrap()
            .save_npz(&dir.join(format!("{name}.npz")))
            .unwrap();
    }
    let dir = dir.to_path_buf();
    move |n: &str| bridge::services::trainer::DatasetRef::Path {
        path: dir.join(format!("{n}.npz")),
    }
}

/// A training config (JSON object) from a `json!` literal.
pub fn config(v: serde_json::Value) -> serde_json::Map<String, serde_json::Value> {
    v.as_object().expect("a JSON object").clone()
}
