//! Shared helpers of the integration tests: a fresh session with its own loopback port, child
//! processes started from the built `koopbridge` binary.
#![allow(dead_code)]

use std::path::PathBuf;
use std::time::Duration;

use bridge::keyexpr::fresh_session_id;
use bridge::orchestrator::{Cluster, RunOptions};
use bridge::procs::ChildProc;
use bridge::session::ZenohOptions;

pub mod faults;
pub mod netns;
pub mod pki;

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

/// Kills process `pid` with SIGKILL (no chance to clean up: the fault a crash or an OOM kill is).
pub fn sigkill(pid: u32) {
    let ok = std::process::Command::new("kill")
        .args(["-9", &pid.to_string()])
        .status()
        .unwrap()
        .success();
    assert!(ok, "kill -9 {pid} failed");
}

/// Opens a Zenoh client session to the router at `ep`, retrying (up to 20 s) until it listens.
pub fn connect_client(ep: &str) -> bridge::zenoh::Session {
    let z = ZenohOptions {
        connect: vec![ep.to_string()],
        mode: Some(bridge::session::Mode::Client),
        ..Default::default()
    };
    (0..100)
        .find_map(|_| {
            bridge::session::open_session(&z)
                .map_err(|_| std::thread::sleep(Duration::from_millis(200)))
                .ok()
        })
        .expect("could not reach the router")
}

/// Starts a damped-pendulum simulator `id` of `session` as a Zenoh client of the router at `ep`
/// (log in `dir/{id}.log`).
pub fn spawn_client_sim(dir: &std::path::Path, id: &str, session: &str, ep: &str) -> ChildProc {
    let args = [
        "sim",
        "--env",
        "damped-pendulum",
        "--id",
        id,
        "--session",
        session,
        "--mode",
        "client",
        "--connect",
        ep,
        "--stdin-lifeline",
    ];
    ChildProc::spawn(
        "sim",
        &exe(),
        &args.map(String::from),
        &dir.join(format!("{id}.log")),
    )
    .unwrap()
}

/// Starts this test executable again as a helper process that runs only its ignored test
/// `test` (which does nothing unless `env` is set), with standard input as its lifeline.
pub fn spawn_helper(
    name: &str,
    test: &str,
    env: &[(&str, &str)],
    log: &std::path::Path,
) -> ChildProc {
    let args = [
        "--exact",
        test,
        "--ignored",
        "--nocapture",
        "--test-threads",
        "1",
    ]
    .map(String::from);
    ChildProc::spawn_env(name, &std::env::current_exe().unwrap(), &args, env, log).unwrap()
}

/// A flag set when standard input reaches its end (the lifeline of a helper process).
pub fn stdin_closed() -> std::sync::Arc<std::sync::atomic::AtomicBool> {
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let s = stop.clone();
    std::thread::spawn(move || {
        let _ = std::io::copy(&mut std::io::stdin(), &mut std::io::sink());
        s.store(true, std::sync::atomic::Ordering::Relaxed);
    });
    stop
}

/// The process ids whose parent is `parent` (from `/proc`).
pub fn children_of(parent: u32) -> Vec<u32> {
    let mut found = Vec::new();
    for e in std::fs::read_dir("/proc").into_iter().flatten().flatten() {
        let Ok(pid) = e.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        let stat = std::fs::read_to_string(e.path().join("stat")).unwrap_or_default();
        // pid (comm) state ppid …; comm may hold spaces, so split after the last ')'.
        let ppid = stat
            .rsplit(')')
            .next()
            .and_then(|r| r.split_whitespace().nth(1))
            .and_then(|p| p.parse::<u32>().ok());
        if ppid == Some(parent) {
            found.push(pid);
        }
    }
    found
}

/// Whether process `pid` still runs (a zombie does not).
pub fn running(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .ok()
        .and_then(|s| s.rsplit(')').next().map(|r| r.trim_start().to_string()))
        .is_some_and(|r| !r.starts_with('Z'))
}

/// Writes a small damped-pendulum dataset (reference pairing, 400 / 64 / 64 windows of 15
/// steps, data seed `seed`) into `dir` as train/val/test `.npz`.
pub fn small_pendulum_dataset(dir: &std::path::Path, seed: u64) {
    use koopman::data::{generate_splits, Pairing, SplitSpec};
    let sys = koopman::systems::by_name("damped-pendulum").unwrap();
    let spec = SplitSpec {
        windows: 528,
        train: 400,
        val: 64,
        test: 64,
        seed,
        pairing: Pairing::Reference,
        steps: Some(15),
        region: None,
    };
    generate_splits(sys.as_ref(), &spec)
        .unwrap()
        .save(dir)
        .unwrap();
}

/// Runs `koopbridge run SCENARIO --out OUT EXTRA…` to the end and returns its output; fails the
/// test with the run's stderr when it did not succeed.
pub fn run_scenario(
    scenario: &std::path::Path,
    out: &std::path::Path,
    extra: &[&str],
) -> std::process::Output {
    let o = koopbridge_run(scenario, out, extra);
    assert!(
        o.status.success(),
        "koopbridge run failed:\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    o
}

/// The `split` (`train`, `val`, `test`) a scenario run into `out` collected for simulator `sim`
/// (`OUT/data/SIM/SPLIT.npz`).
pub fn collected(out: &std::path::Path, sim: &str, split: &str) -> koopman::data::Dataset {
    let path = out.join(format!("data/{sim}/{split}.npz"));
    koopman::data::Dataset::load_npz(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Runs `koopbridge run SCENARIO --out OUT` expecting a refusal: fails the test (naming `case`)
/// when the run succeeds, and returns its stderr for the caller's checks of the message.
pub fn run_scenario_refused(
    scenario: &std::path::Path,
    out: &std::path::Path,
    case: &str,
) -> String {
    let o = koopbridge_run(scenario, out, &[]);
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(!o.status.success(), "{case} ran:\n{stderr}");
    stderr
}

/// `koopbridge run SCENARIO --out OUT EXTRA…`, run to its end, whatever its outcome.
fn koopbridge_run(
    scenario: &std::path::Path,
    out: &std::path::Path,
    extra: &[&str],
) -> std::process::Output {
    std::process::Command::new(exe())
        .args([
            "run",
            scenario.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .args(extra)
        .output()
        .unwrap()
}

/// `koopbridge run` of scenario `text` written to `dir/{name}.toml`, into `dir/out-{name}` (with
/// the extra arguments `extra`): its output and the output folder.
pub fn run_scenario_text(
    dir: &std::path::Path,
    name: &str,
    text: &str,
    extra: &[&str],
) -> (std::process::Output, PathBuf) {
    let sc = dir.join(format!("{name}.toml"));
    std::fs::write(&sc, text).unwrap();
    let out = dir.join(format!("out-{name}"));
    let mut args = vec!["run", sc.to_str().unwrap(), "--out", out.to_str().unwrap()];
    args.extend_from_slice(extra);
    (
        std::process::Command::new(exe())
            .args(&args)
            .output()
            .unwrap(),
        out,
    )
}

/// A JSON file, parsed.
pub fn json_file(p: &std::path::Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
}

/// The small damped-pendulum scenario of many tests, without a name or `[control]`: uniform
/// inputs, 40 / 10 / 10 windows of 15 steps (seed 7), a tiny Koopman model.
pub const PENDULUM_BASE: &str = r#"
[[sims]]
id = "pend"
env = "damped-pendulum"
[collect]
policy = { kind = "uniform" }
train_windows = 40
val_windows = 10
test_windows = 10
steps = 15
seed = 7
[train]
config = { iterations = 30, hidden = [16], n_mult = 2, batch = 16, validate_every = 15 }
"#;
