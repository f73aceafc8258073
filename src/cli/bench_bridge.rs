//! `koopbridge bench bridge`: round trips over Zenoh on loopback between separate processes —
//! a bare query (echo), a lockstep step and an MPC solve, measured in the same run — and an
//! optional free-run stream check (rate, sequence gaps).

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use bridge::client::{Client, SimClient};
use bridge::codec::{SolveReply, SolveRequest, StateMsg};
use bridge::keyexpr::{fresh_session_id, Keys, Role};
use bridge::messages::ResetRequest;
use bridge::orchestrator::{Cluster, RunOptions, SERVICES_ID};
use bridge::procs::ChildProc;
use bridge::session::{open_session, ZenohOptions};
use bridge::zenoh::Wait;

/// Arguments of `koopbridge bench bridge`.
#[derive(clap::Args)]
pub struct BenchBridgeArgs {
    /// One JSON object per line (`what`, `median_us`, `p99_us`, ...).
    #[arg(long)]
    pub json: bool,
    /// Round trips per measurement (after 200 warm-up ones).
    #[arg(long, default_value_t = 5000)]
    pub iterations: usize,
    /// Also run a free-run stream at --rate for this many seconds and count sequence gaps.
    #[arg(long, default_value_t = 0.0)]
    pub free_run_seconds: f64,
    /// Free-run rate in Hz.
    #[arg(long, default_value_t = 1000.0)]
    pub rate: f64,
    /// Scratch folder (logs, the benchmark model).
    #[arg(long, default_value = "results/bench-bridge")]
    pub out: PathBuf,
    /// (internal) serve the echo queryable of session SESSION and exit when stdin closes.
    #[arg(long, hide = true, value_name = "SESSION")]
    pub echo_server: Option<String>,
    #[command(flatten)]
    pub zenoh: super::ZenohArgs,
}

fn stats(mut v: Vec<f64>) -> (f64, f64) {
    v.sort_by(|a, b| a.total_cmp(b));
    let p = |q: f64| v[((v.len() as f64 * q) as usize).min(v.len() - 1)];
    (p(0.5), p(0.99))
}

fn echo_server(session_id: &str, z: &ZenohOptions) -> anyhow::Result<()> {
    let keys = Keys::new(session_id)?;
    let session = open_session(z)?;
    let key = keys.under(&["bench", "echo"]);
    let (tx, rx) = std::sync::mpsc::channel();
    let _q = session
        .declare_queryable(&key)
        .callback(move |q| {
            let _ = tx.send(q);
        })
        .wait()
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let _t = session
        .liveliness()
        .declare_token(keys.alive(Role::Sim, "echo")?)
        .wait()
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let stop = super::sim::stdin_lifeline();
    // Answered on this thread, like the adapter does, so that both paths cost the same hops.
    while !stop.load(Ordering::Relaxed) {
        if let Ok(q) = rx.recv_timeout(Duration::from_millis(100)) {
            let p = q
                .payload()
                .map(|p| p.to_bytes().into_owned())
                .unwrap_or_default();
            let mut reply = p.clone();
            reply.extend_from_slice(&[0u8; 16]);
            let _ = q.reply(q.key_expr().clone(), reply).wait();
        }
    }
    Ok(())
}

fn line(json: bool, what: &str, samples: Vec<f64>, extra: serde_json::Value) -> f64 {
    let n = samples.len();
    let (med, p99) = stats(samples);
    if json {
        let mut o = serde_json::json!({"what": what, "median_us": med, "p99_us": p99, "n": n});
        if let (Some(o), Some(e)) = (o.as_object_mut(), extra.as_object()) {
            o.extend(e.clone());
        }
        println!("{o}");
    } else {
        println!("{what:>14}: median {med:8.1} µs   p99 {p99:8.1} µs   (n = {n}) {extra}");
    }
    med
}

/// Runs `koopbridge bench bridge`.
pub fn run(args: BenchBridgeArgs) -> anyhow::Result<()> {
    if let Some(s) = &args.echo_server {
        return echo_server(s, &args.zenoh.options());
    }
    let session_id = fresh_session_id();
    std::fs::create_dir_all(&args.out)?;
    let out = std::fs::canonicalize(&args.out)?;
    // A benchmark model with the SPEC architecture (untrained: solve cost does not depend on training).
    let store = out.join("models");
    let model_name = "bench-pendulum";
    let arch = koopman::model::arch::Arch::new(2, 1, &[256, 256, 256], 16)?;
    koopman::model::koopman::KoopmanModel::init(arch, 17382)?.save(&store.join(model_name))?;
    let opts = RunOptions {
        exe: std::env::current_exe()?,
        out_dir: out.clone(),
        zenoh: args.zenoh.options(),
        session: Some(session_id.clone()),
        ready_timeout: Duration::from_secs(60),
        attach_existing: false,
    };
    let mut cluster = Cluster::start(
        &opts,
        &session_id,
        &[("pend".into(), "damped-pendulum".into())],
        &["mpc", "models"],
    )?;
    let echo_args: Vec<String> = [
        "bench",
        "bridge",
        "--echo-server",
        &session_id,
        "--connect",
        &cluster.endpoint,
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    cluster.children.push(ChildProc::spawn(
        "echo server",
        &opts.exe,
        &echo_args,
        &out.join("logs/echo.log"),
    )?);
    cluster.wait_ready(&[(Role::Sim, "echo".into())], Duration::from_secs(60))?;
    let client: &Client = &cluster.client;
    let live = &cluster.live;
    let mut sim = SimClient::connect(client, "pend", Duration::from_secs(30))?;
    let echo_key = client.keys.under(&["bench", "echo"]);
    // Wait until the echo queryable answers.
    let t = Instant::now();
    while client
        .query(&echo_key, vec![1], Duration::from_secs(1), "echo server")
        .is_err()
    {
        anyhow::ensure!(
            t.elapsed() < Duration::from_secs(30),
            "the echo server never answered"
        );
    }
    let n = args.iterations;
    let warm = 200;
    // Interleave the two measurements in blocks so that load changes hit both alike.
    let mut bare = Vec::with_capacity(n);
    let mut lock = Vec::with_capacity(n);
    sim.reset(&ResetRequest {
        seed: Some(1),
        x0: None,
        perturbation: None,
    })?;
    let payload = bridge::codec::StepRequest { k: 0, u: vec![0.5] }.encode();
    let mut i = 0;
    while bare.len() < n || lock.len() < n {
        for _ in 0..50 {
            let t = Instant::now();
            client.query(
                &echo_key,
                payload.clone(),
                Duration::from_secs(10),
                "echo server",
            )?;
            if i >= warm {
                bare.push(t.elapsed().as_secs_f64() * 1e6);
            }
            if sim.k >= 500 {
                sim.reset(&ResetRequest {
                    seed: Some(i as u64),
                    x0: None,
                    perturbation: None,
                })?;
            }
            let t = Instant::now();
            sim.step(&[0.5], Some(live))?;
            if i >= warm {
                lock.push(t.elapsed().as_secs_f64() * 1e6);
            }
            i += 1;
        }
    }
    bare.truncate(n);
    lock.truncate(n);
    let bare_med = line(args.json, "bare_query", bare, serde_json::json!({}));
    let lock_med = stats(lock.clone()).0;
    line(
        args.json,
        "lockstep_step",
        lock,
        serde_json::json!({"ratio_to_bare": lock_med / bare_med}),
    );

    // MPC solve round trip.
    let configure = bridge::services::mpc::ConfigureRequest {
        model: model_name.into(),
        mpc: Some(koopman::mpc::MpcConfig::with_bounds(vec![-8.0], vec![8.0])),
        offset_free: None,
    };
    bridge::services::mpc::configure(client, SERVICES_ID, &configure, Duration::from_secs(60))?;
    let key = client.keys.mpc_solve(SERVICES_ID)?;
    let mut rt = Vec::with_capacity(n);
    let mut inside = Vec::with_capacity(n);
    let mut rng = koopman::rng::Rng::new(5);
    for j in 0..n + warm {
        let req = SolveRequest {
            model: model_name.into(),
            x: vec![rng.uniform(-3.0, 3.0), rng.uniform(-3.0, 3.0)],
            reference: vec![0.0, 0.0],
            feedforward: Vec::new(),
        }
        .encode();
        let t = Instant::now();
        let b = client.query(&key, req, Duration::from_secs(10), "MPC service")?;
        let e = t.elapsed().as_secs_f64() * 1e6;
        let r = SolveReply::decode(&b)?;
        if j >= warm {
            rt.push(e);
            inside.push(r.solve_time_ns as f64 / 1e3);
        }
    }
    let (in_med, _) = stats(inside);
    let rt_med = stats(rt.clone()).0;
    line(
        args.json,
        "mpc_solve",
        rt,
        serde_json::json!({"solve_median_us": in_med, "transport_overhead_to_bare": (rt_med - in_med) / bare_med}),
    );

    if args.free_run_seconds > 0.0 {
        free_run(&args, &opts, &cluster, &session_id)?;
    }
    drop(cluster);
    Ok(())
}

fn free_run(
    args: &BenchBridgeArgs,
    opts: &RunOptions,
    cluster: &Cluster,
    session_id: &str,
) -> anyhow::Result<()> {
    let steps = (args.free_run_seconds * args.rate).round() as u64;
    let keys = &cluster.client.keys;
    let (tx, rx) = std::sync::mpsc::channel::<(Instant, Vec<u8>)>();
    let _sub = cluster
        .client
        .session
        .declare_subscriber(keys.sim("fr", bridge::keyexpr::SimLeaf::State)?)
        .callback(move |s| {
            let _ = tx.send((Instant::now(), s.payload().to_bytes().into_owned()));
        })
        .wait()
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let a: Vec<String> = [
        "sim",
        "--env",
        "damped-pendulum",
        "--id",
        "fr",
        "--session",
        session_id,
        "--free-run",
        "--rate",
        &args.rate.to_string(),
        "--steps",
        &steps.to_string(),
        "--wait-subscriber",
        "30",
        "--stdin-lifeline",
        "--connect",
        &cluster.endpoint,
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let mut child = ChildProc::spawn(
        "free-run simulator",
        &opts.exe,
        &a,
        &opts.out_dir.join("logs/free-run.log"),
    )?;
    let done = AtomicBool::new(false);
    let (mut received, mut gaps, mut last_seq, mut first_seq) =
        (0u64, 0u64, None::<u64>, None::<u64>);
    let mut intervals = Vec::new();
    let mut last_t: Option<Instant> = None;
    let deadline = Instant::now() + Duration::from_secs_f64(args.free_run_seconds + 60.0);
    while !done.load(Ordering::Relaxed) && Instant::now() < deadline {
        match rx.recv_timeout(Duration::from_millis(200)) {
            Ok((t, b)) => {
                let s = StateMsg::decode(&b)?;
                received += 1;
                first_seq.get_or_insert(s.seq);
                if let Some(l) = last_seq {
                    if s.seq > l + 1 {
                        gaps += s.seq - l - 1;
                    }
                }
                last_seq = Some(s.seq);
                if let Some(lt) = last_t {
                    intervals.push((t - lt).as_secs_f64() * 1e6);
                }
                last_t = Some(t);
                if s.k >= steps {
                    done.store(true, Ordering::Relaxed);
                }
            }
            Err(_) => {
                if child.exited().is_some() && rx.try_recv().is_err() {
                    break;
                }
            }
        }
    }
    std::thread::sleep(Duration::from_millis(300));
    let stats_line = std::fs::read_to_string(&child.log).unwrap_or_default();
    let adapter: serde_json::Value = stats_line
        .lines()
        .rev()
        .find_map(|l| serde_json::from_str(l).ok())
        .unwrap_or(serde_json::Value::Null);
    child.kill();
    let extra = serde_json::json!({
        "rate_hz": args.rate, "seconds": args.free_run_seconds, "published": steps + 1,
        "received": received, "first_seq": first_seq, "gaps": gaps, "adapter": adapter,
    });
    line(args.json, "free_run_interval", intervals, extra);
    Ok(())
}
