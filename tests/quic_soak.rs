//! Soak of the secure QUIC link (issue 29): `koopbridge router` on QUIC with the access-control
//! list of `config/router-quic-acl.json5`, the trainer and model store as one client
//! (`CN=trainer-host`), a damped pendulum as another (`CN=sim-host`), and this test as the
//! operator, which for `KB_SOAK_SECONDS` (default 20) at once steps the simulator in lockstep
//! at full speed, trains one small model after another through the trainer, and fetches a
//! 256×256 model from the store over and over (each copy compared with the stored file).
//! Counts every lockstep step without a reply within 10 s (no retries), every failed step,
//! transfer or job, and every process that died; all must be 0. `KB_SOAK_REPORT=FILE` writes
//! the figures as JSON. The 10-minute run: `scripts/soak-quic.sh 10`.

mod common;

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use bridge::client::{Client, Liveliness, SimClient};
use bridge::keyexpr::{fresh_session_id, Keys, Role};
use bridge::messages::ResetRequest;
use bridge::procs::ChildProc;
use bridge::services::models;
use bridge::services::trainer::{submit_and_wait, JobSpec, JobState};
use bridge::Error;
use common::pki::{
    client_opts, client_services, config, make_pki, open_retrying, plain_router, sim, Link,
};
use serde_json::json;

/// The services' id (`serve --id`, default `main`).
const ID: &str = "main";

/// Counters of the model-transfer thread.
#[derive(Default, Debug)]
struct Transfers {
    ok: u64,
    lost: u64,
    errors: u64,
    mismatched: u64,
    bytes: u64,
    last_error: Option<String>,
}

/// Counters of the trainer thread.
#[derive(Default, Debug)]
struct Training {
    done: u64,
    failed: u64,
    last_error: Option<String>,
}

/// Resident memory of process `pid` in KiB (0 when it is gone).
fn rss_kib(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse().ok())
        })
        .unwrap_or(0)
}

/// Fetches model `name` until `stop`, comparing each copy's weights with `reference`.
fn transfer_loop(
    client: &Client,
    name: &str,
    dir: &Path,
    reference: &[u8],
    stop: &AtomicBool,
) -> Transfers {
    let mut t = Transfers::default();
    let mut n = 0u64;
    while !stop.load(Ordering::Relaxed) {
        let into = dir.join(format!("fetch-{}", n % 2));
        let _ = std::fs::remove_dir_all(&into);
        n += 1;
        match models::fetch(client, name, &into, Duration::from_secs(10)) {
            Ok(d) => {
                let got = std::fs::read(d.join("model.safetensors")).unwrap_or_default();
                t.bytes += got.len() as u64;
                if got == reference {
                    t.ok += 1;
                } else {
                    t.mismatched += 1;
                }
            }
            Err(e @ Error::Timeout { .. }) => {
                t.lost += 1;
                t.last_error = Some(e.to_string());
            }
            Err(e) => {
                t.errors += 1;
                t.last_error = Some(e.to_string());
            }
        }
    }
    t
}

/// Trains small models one after another until `stop` (the last one is waited for).
fn training_loop(client: &Client, spec: &dyn Fn(u64) -> JobSpec, stop: &AtomicBool) -> Training {
    let mut t = Training::default();
    let live = Liveliness::new(client).unwrap();
    let mut n = 0;
    while !stop.load(Ordering::Relaxed) {
        n += 1;
        match submit_and_wait(client, &live, ID, &spec(n), &mut |_| {}) {
            Ok(r) if r.state == JobState::Done => t.done += 1,
            Ok(r) => {
                t.failed += 1;
                t.last_error = Some(format!("{r:?}"));
            }
            Err(e) => {
                t.failed += 1;
                t.last_error = Some(e.to_string());
            }
        }
    }
    t
}

#[test]
fn quic_router_holds_lockstep_training_and_model_transfers() {
    let seconds: u64 = std::env::var("KB_SOAK_SECONDS")
        .ok()
        .map(|s| s.parse().expect("KB_SOAK_SECONDS: seconds"))
        .unwrap_or(20);
    let dir = common::scratch("quic-soak");
    let Some(pki) = make_pki(&dir.join("pki")) else {
        eprintln!("SKIPPED: the openssl CLI is not installed (needed to make test certificates)");
        return;
    };
    let link = Link::Quic;
    let session = fresh_session_id();
    let keys = Keys::new(&session).unwrap();
    let ep = link.endpoint();
    let cfg = |who: &str| config(&link.client_config(), &pki, who, &[], &dir);
    let router_cfg = config(&link.router_acl_config(), &pki, "router", &[], &dir);
    let data = common::pendulum_data(&dir.join("state/data"), &[("train", 64, 1), ("val", 16, 2)]);
    let mut procs: Vec<ChildProc> = vec![plain_router(&dir, &ep, &router_cfg)];
    let operator = Client::new(
        open_retrying(&client_opts(&ep, Some(&cfg("operator")))),
        keys.clone(),
    );
    procs.push(client_services(
        &dir,
        &session,
        &ep,
        &["trainer", "models"],
        &cfg("trainer-host"),
    ));
    procs.push(sim(&dir, &session, "pend", &ep, Some(&cfg("sim-host"))));
    let live = Liveliness::new(&operator).unwrap();
    live.wait_for(
        &[(Role::Trainer, ID.into()), (Role::Models, ID.into())],
        common::READY,
    )
    .unwrap();

    // The model the transfers fetch: 256×256 hidden layers (a few hundred kB of weights).
    let spec = move |model: String, iterations: u64, hidden: u64| JobSpec {
        model,
        train: data("train"),
        val: data("val"),
        test: None,
        config: common::config(json!({"iterations": iterations, "hidden": [hidden, hidden],
            "n_mult": 4, "batch": 16, "validate_every": iterations})),
    };
    let spec = Arc::new(spec);
    submit_and_wait(
        &operator,
        &live,
        ID,
        &spec("soak-big".into(), 10, 256),
        &mut |_| {},
    )
    .expect("the model to transfer was not trained");
    let reference = std::fs::read(dir.join("models/soak-big/model.safetensors")).unwrap();

    let mut sim_client = SimClient::connect(&operator, "pend", common::READY).unwrap();
    sim_client.timeout = Duration::from_secs(10);
    sim_client.retries = 0;
    let stop = Arc::new(AtomicBool::new(false));
    let transfers = {
        let (c, stop, d, r) = (
            operator.clone(),
            stop.clone(),
            dir.clone(),
            reference.clone(),
        );
        std::thread::spawn(move || transfer_loop(&c, "soak-big", &d, &r, &stop))
    };
    let training = {
        let (c, stop) = (operator.clone(), stop.clone());
        let spec = spec.clone();
        std::thread::spawn(move || {
            training_loop(&c, &|n| spec(format!("soak-{n}"), 200, 16), &stop)
        })
    };

    eprintln!("quic-soak: {seconds} s of lockstep + training + model transfers through {ep}");
    let (mut steps, mut lost, mut step_errors, mut resets) = (0u64, 0u64, 0u64, 0u64);
    let mut next_reset = 0;
    let mut last_error = None;
    let mut deaths: Vec<String> = Vec::new();
    let t0 = Instant::now();
    let end = t0 + Duration::from_secs(seconds);
    while Instant::now() < end && deaths.is_empty() {
        if steps >= next_reset {
            next_reset += 10_000;
            sim_client
                .reset(&ResetRequest {
                    seed: Some(resets),
                    x0: None,
                    perturbation: None,
                })
                .unwrap();
            resets += 1;
        }
        let u = 0.5 * (steps as f64 / 50.0).sin();
        match sim_client.step(&[u], None) {
            Ok(_) => steps += 1,
            // No reply within the timeout: lost. The same k is sent again next (the adapter
            // answers a repeated step from its cache).
            Err(e @ Error::Timeout { .. }) => {
                lost += 1;
                last_error = Some(e.to_string());
            }
            Err(e) => {
                step_errors += 1;
                last_error = Some(e.to_string());
            }
        }
        if (steps + lost + step_errors) % 1000 == 0 {
            deaths.extend(procs.iter_mut().filter_map(|p| p.exited()));
        }
    }
    let elapsed = t0.elapsed().as_secs_f64();
    stop.store(true, Ordering::Relaxed);
    let transfers = transfers.join().unwrap();
    let training = training.join().unwrap();
    deaths.extend(procs.iter_mut().filter_map(|p| p.exited()));
    let rss: Vec<_> = ["router", "services", "sim"]
        .iter()
        .zip(&procs)
        .map(|(n, p)| json!({"process": n, "rss_kib": rss_kib(p.id())}))
        .collect();
    let report = json!({
        "link": "quic (mutual authentication, access-control list)",
        "seconds": elapsed,
        "lockstep": {"steps": steps, "lost_replies": lost, "errors": step_errors,
                     "resets": resets, "steps_per_second": steps as f64 / elapsed},
        "transfers": {"ok": transfers.ok, "lost": transfers.lost, "errors": transfers.errors,
                      "mismatched": transfers.mismatched, "bytes": transfers.bytes},
        "training": {"jobs_done": training.done, "jobs_failed": training.failed},
        "deaths": deaths,
        "rss_end": rss,
        "last_errors": [last_error, transfers.last_error, training.last_error],
        "logs": dir,
    });
    let text = serde_json::to_string_pretty(&report).unwrap();
    eprintln!("{text}");
    if let Ok(path) = std::env::var("KB_SOAK_REPORT") {
        std::fs::write(path, &text).unwrap();
    }
    assert!(deaths.is_empty(), "processes died: {deaths:?}");
    assert_eq!(
        (lost, step_errors),
        (0, 0),
        "lockstep replies lost / failed"
    );
    assert!(steps > 0 && transfers.ok > 0, "no traffic: {text}");
    assert_eq!(
        (transfers.lost, transfers.errors, transfers.mismatched),
        (0, 0, 0),
        "model transfers"
    );
    assert_eq!(training.failed, 0, "training jobs failed");
    assert!(training.done > 0, "no training job finished: {text}");
}
