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
