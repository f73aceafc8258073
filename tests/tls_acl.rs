//! TLS and access control with the example configs of `config/`: a TLS-only router refuses plain
//! TCP and clients without a certificate, and its access-control list lets only `CN=operator`
//! step simulators and submit jobs (a peer outside the list gets no reply). Certificates are made
//! here with the `openssl` CLI; the lockstep round trip over TLS against plain TCP is an ignored
//! measurement (`tls_round_trip_cost_against_tcp`).

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use bridge::client::{Client, SimClient};
use bridge::keyexpr::{fresh_session_id, Keys, SimLeaf};
use bridge::messages::ResetRequest;
use bridge::procs::ChildProc;
use bridge::session::{free_loopback_endpoint, open_session, Mode, ZenohOptions};
use bridge::zenoh::Session;
use bridge::Error;

/// The certificate names every test uses: the router's, and one per client identity.
const NAMES: [&str; 4] = ["router", "operator", "sim-host", "stranger"];

/// A test CA and certificates signed by it (EC P-256, SAN `localhost`, 127.0.0.1), made with
/// the `openssl` CLI in `dir`; `None` when `openssl` is not installed.
fn make_pki(dir: &Path) -> Option<PathBuf> {
    let ok = |args: &[&str]| {
        let out = Command::new("openssl").args(args).current_dir(dir).output();
        match out {
            Ok(o) if o.status.success() => Some(()),
            Ok(o) => panic!(
                "openssl {args:?} failed: {}",
                String::from_utf8_lossy(&o.stderr)
            ),
            Err(_) => None,
        }
    };
    let ec = [
        "-newkey",
        "ec",
        "-pkeyopt",
        "ec_paramgen_curve:P-256",
        "-nodes",
    ];
    let mut ca = vec![
        "req",
        "-x509",
        "-days",
        "2",
        "-subj",
        "/CN=koopbridge-test-ca",
    ];
    ca.extend(ec);
    ca.extend(["-keyout", "ca.key", "-out", "ca.pem"]);
    ok(&ca)?;
    std::fs::write(
        dir.join("leaf.ext"),
        "subjectAltName=DNS:localhost,IP:127.0.0.1\nbasicConstraints=CA:FALSE\n\
         keyUsage=digitalSignature\nextendedKeyUsage=serverAuth,clientAuth\n",
    )
    .unwrap();
    for cn in NAMES {
        let (key, csr, pem, subj) = (
            format!("{cn}.key"),
            format!("{cn}.csr"),
            format!("{cn}.pem"),
            format!("/CN={cn}"),
        );
        let mut req = vec!["req", "-subj", &subj];
        req.extend(ec);
        req.extend(["-keyout", &key, "-out", &csr]);
        ok(&req)?;
        ok(&[
            "x509",
            "-req",
            "-in",
            &csr,
            "-CA",
            "ca.pem",
            "-CAkey",
            "ca.key",
            "-CAcreateserial",
            "-days",
            "2",
            "-extfile",
            "leaf.ext",
            "-out",
            &pem,
        ])?;
    }
    Some(dir.to_path_buf())
}

/// `config/{example}` with its certificate paths pointing into `pki` (the client's certificate
/// being `{identity}.pem`); lines containing any of `drop` are left out. Written to `out`.
fn config(example: &str, pki: &Path, identity: &str, drop: &[&str], out: &Path) -> PathBuf {
    let src = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("config")
        .join(example);
    let text = std::fs::read_to_string(&src).unwrap();
    let dir = pki.to_str().unwrap();
    let text: String = text
        .lines()
        .filter(|l| !drop.iter().any(|d| l.contains(d)))
        .map(|l| {
            l.replace("/etc/koopbridge/tls/client.", &format!("{dir}/{identity}."))
                .replace("/etc/koopbridge/tls", dir)
                + "\n"
        })
        .collect();
    assert!(!text.contains("/etc/koopbridge"), "{example}: a path left");
    let path = out.join(format!(
        "{}-{identity}.json5",
        example.trim_end_matches(".json5")
    ));
    std::fs::write(&path, text).unwrap();
    path
}

fn args(v: &[&str]) -> Vec<String> {
    v.iter().map(|s| s.to_string()).collect()
}

/// A free loopback port as a TLS endpoint on `localhost` (the name in the router's certificate).
fn tls_endpoint() -> String {
    free_loopback_endpoint()
        .unwrap()
        .replace("tcp/127.0.0.1", "tls/localhost")
}

/// A Zenoh client of `endpoint` with config file `cfg` (None: the default config).
fn client_opts(endpoint: &str, cfg: Option<&Path>) -> ZenohOptions {
    ZenohOptions {
        connect: vec![endpoint.to_string()],
        mode: Some(Mode::Client),
        zenoh_config: cfg.map(Path::to_path_buf),
        ..Default::default()
    }
}

/// Opens a client session, retrying while the router starts (up to `common::READY`).
fn open_retrying(z: &ZenohOptions) -> Session {
    let deadline = Instant::now() + common::READY;
    loop {
        match open_session(z) {
            Ok(s) => return s,
            Err(_) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(200)),
            Err(e) => panic!("could not reach the router: {e}"),
        }
    }
}

/// `koopbridge serve {services} --mode router` on `endpoint` (config `cfg` if any).
fn router(
    dir: &Path,
    session: &str,
    endpoint: &str,
    services: &[&str],
    cfg: Option<&Path>,
) -> ChildProc {
    let mut a = args(&["serve"]);
    a.extend(args(services));
    a.extend(args(&[
        "--session",
        session,
        "--mode",
        "router",
        "--listen",
        endpoint,
    ]));
    a.extend(args(&["--store", dir.join("models").to_str().unwrap()]));
    a.extend(args(&["--state-dir", dir.join("state").to_str().unwrap()]));
    a.push("--stdin-lifeline".into());
    if let Some(c) = cfg {
        a.extend(args(&["--zenoh-config", c.to_str().unwrap()]));
    }
    ChildProc::spawn("router", &common::exe(), &a, &dir.join("router.log")).unwrap()
}

/// `koopbridge sim` (damped pendulum) as simulator `id`, a Zenoh client of `endpoint`.
fn sim(dir: &Path, session: &str, id: &str, endpoint: &str, cfg: Option<&Path>) -> ChildProc {
    let mut a = args(&[
        "sim",
        "--env",
        "damped-pendulum",
        "--id",
        id,
        "--session",
        session,
    ]);
    a.extend(args(&[
        "--mode",
        "client",
        "--connect",
        endpoint,
        "--stdin-lifeline",
    ]));
    if let Some(c) = cfg {
        a.extend(args(&["--zenoh-config", c.to_str().unwrap()]));
    }
    ChildProc::spawn(
        "sim",
        &common::exe(),
        &a,
        &dir.join(format!("sim-{id}.log")),
    )
    .unwrap()
}

/// Median and 99th percentile (µs) of `n` lockstep round trips of `sim` after a reset.
fn step_timing(sim: &mut SimClient, n: usize) -> (f64, f64) {
    sim.reset(&ResetRequest {
        seed: Some(1),
        x0: None,
    })
    .unwrap();
    let mut us = Vec::with_capacity(n);
    for _ in 0..n {
        let t = Instant::now();
        sim.step(&[0.1], None).unwrap();
        us.push(t.elapsed().as_secs_f64() * 1e6);
    }
    us.sort_by(f64::total_cmp);
    (us[n / 2], us[(n * 99) / 100])
}

/// A step or job query that must get no reply: the client's own timeout, nothing else.
fn assert_no_reply<T: std::fmt::Debug>(what: &str, r: bridge::Result<T>) {
    match r {
        Err(Error::Timeout { .. }) => {}
        other => panic!("{what}: expected no reply (timeout), got {other:?}"),
    }
}

/// A TLS-only router (`router-tls.json5`, a model store) and the operator's client of it.
struct TlsRouter {
    dir: PathBuf,
    pki: PathBuf,
    session: String,
    endpoint: String,
    client: Client,
    _router: ChildProc,
}

/// Starts a [`TlsRouter`] in a scratch folder named `tag`; `None` (with a SKIPPED line) when
/// the `openssl` CLI is not installed.
fn tls_router(tag: &str) -> Option<TlsRouter> {
    let dir = common::scratch(tag);
    let Some(pki) = make_pki(&dir) else {
        eprintln!("SKIPPED: the openssl CLI is not installed (needed to make test certificates)");
        return None;
    };
    let session = fresh_session_id();
    let endpoint = tls_endpoint();
    let router_cfg = config("router-tls.json5", &pki, "router", &[], &dir);
    let router = router(&dir, &session, &endpoint, &["models"], Some(&router_cfg));
    let op_cfg = config("client-tls.json5", &pki, "operator", &[], &dir);
    let client = Client::new(
        open_retrying(&client_opts(&endpoint, Some(&op_cfg))),
        Keys::new(&session).unwrap(),
    );
    Some(TlsRouter {
        dir,
        pki,
        session,
        endpoint,
        client,
        _router: router,
    })
}

#[test]
fn tls_router_refuses_plain_tcp_and_clients_without_a_certificate() {
    let Some(TlsRouter {
        dir,
        pki,
        session,
        endpoint: ep,
        client,
        _router,
    }) = tls_router("tls")
    else {
        return;
    };

    eprintln!("tls: the operator has a session");
    // Plain TCP to the same port: the TCP connection opens, the Zenoh session does not.
    let plain = ep.replace("tls/localhost", "tcp/127.0.0.1");
    let r = open_session(&client_opts(&plain, None));
    assert!(
        r.is_err(),
        "a plain-TCP client got a session with the TLS-only router"
    );
    eprintln!("tls: plain TCP refused");
    // TLS without a client certificate: refused by mutual TLS.
    let no_cert = config(
        "client-tls.json5",
        &pki,
        "nocert",
        &[
            "connect_certificate",
            "connect_private_key",
            "enable_mtls",
            "Present the",
        ],
        &dir,
    );
    let r = open_session(&client_opts(&ep, Some(&no_cert)));
    assert!(
        r.is_err(),
        "a TLS client without a certificate got a session"
    );

    eprintln!("tls: a client without a certificate refused");
    // A simulator behind the TLS router steps for the TLS client: a few exact steps (the
    // timing against plain TCP is the ignored `tls_round_trip_cost_against_tcp`).
    let host_cfg = config("client-tls.json5", &pki, "sim-host", &[], &dir);
    let _sim = sim(&dir, &session, "pend", &ep, Some(&host_cfg));
    let mut s = SimClient::connect(&client, "pend", common::READY).unwrap();
    steps_exactly(&mut s, 20);
}

/// Resets `sim` and steps it `n` times, checking each step's index.
fn steps_exactly(sim: &mut SimClient, n: u64) {
    sim.reset(&ResetRequest {
        seed: Some(1),
        x0: None,
    })
    .unwrap();
    for k in 1..=n {
        assert_eq!(sim.step(&[0.1], None).unwrap().k, k);
    }
}

/// The cost of TLS on the lockstep round trip through a router: 1000 steps over TLS, then the
/// same topology over plain TCP (BENCHMARKS.md, "Reliability"). A measurement, not
/// a check, and kept out of CI: zenoh-link-tls 1.10.2 reads and writes one TLS stream from two
/// tasks at once through an `UnsafeCell` (upstream eclipse-zenoh/zenoh#2557, open), which under
/// sustained two-way traffic has aborted this process with a corrupted `rustls` error (seen in
/// session 7) and lost replies (sessions 5–6). Run with
/// `cargo test --release --workspace --test tls_acl -- --ignored --nocapture`.
#[test]
#[ignore]
fn tls_round_trip_cost_against_tcp() {
    let Some(TlsRouter {
        dir,
        pki,
        session,
        endpoint: ep,
        client,
        _router,
    }) = tls_router("tls-timing")
    else {
        return;
    };
    let host_cfg = config("client-tls.json5", &pki, "sim-host", &[], &dir);
    let _sim = sim(&dir, &session, "pend", &ep, Some(&host_cfg));
    let mut s = SimClient::connect(&client, "pend", common::READY).unwrap();
    let (tls_med, tls_p99) = step_timing(&mut s, 1000);

    let tcp_dir = dir.join("tcp");
    std::fs::create_dir_all(&tcp_dir).unwrap();
    let tcp_session = fresh_session_id();
    let tcp_ep = free_loopback_endpoint().unwrap();
    let _tcp_router = router(&tcp_dir, &tcp_session, &tcp_ep, &["models"], None);
    let tcp_client = Client::new(
        open_retrying(&client_opts(&tcp_ep, None)),
        Keys::new(&tcp_session).unwrap(),
    );
    let _tcp_sim = sim(&tcp_dir, &tcp_session, "pend", &tcp_ep, None);
    let mut t = SimClient::connect(&tcp_client, "pend", common::READY).unwrap();
    let (tcp_med, tcp_p99) = step_timing(&mut t, 1000);
    eprintln!(
        "lockstep round trip via a router, 1000 steps: TLS median {tls_med:.0} µs p99 {tls_p99:.0} µs; \
         TCP median {tcp_med:.0} µs p99 {tcp_p99:.0} µs; ratio {:.2}",
        tls_med / tcp_med
    );
}

#[test]
fn acl_lets_only_the_operator_step_and_submit_jobs() {
    let dir = common::scratch("acl");
    let Some(pki) = make_pki(&dir) else {
        eprintln!("SKIPPED: the openssl CLI is not installed (needed to make test certificates)");
        return;
    };
    let session = fresh_session_id();
    let keys = Keys::new(&session).unwrap();
    let ep = tls_endpoint();
    let router_cfg = config("router-tls-acl.json5", &pki, "router", &[], &dir);
    let _router = router(
        &dir,
        &session,
        &ep,
        &["trainer", "models"],
        Some(&router_cfg),
    );
    let cfg = |who: &str| config("client-tls.json5", &pki, who, &[], &dir);
    let operator = Client::new(
        open_retrying(&client_opts(&ep, Some(&cfg("operator")))),
        keys.clone(),
    );
    let _sim = sim(&dir, &session, "pend", &ep, Some(&cfg("sim-host")));

    // The operator steps the simulator and reaches the trainer (`{}` is not a job: a typed
    // bad_request reply, which shows the query got through).
    let mut op_sim = SimClient::connect(&operator, "pend", common::READY).unwrap();
    op_sim
        .reset(&ResetRequest {
            seed: Some(3),
            x0: None,
        })
        .unwrap();
    assert_eq!(op_sim.step(&[0.5], None).unwrap().k, 1);
    let jobs = keys.trainer_jobs("main").unwrap();
    // The trainer may still be starting in the router process: ask until it answers.
    let deadline = Instant::now() + common::READY;
    loop {
        match operator.query(&jobs, b"{}".to_vec(), Duration::from_secs(5), "trainer") {
            Ok(_) | Err(Error::Remote { .. }) => break,
            Err(Error::Timeout { .. }) if Instant::now() < deadline => {
                std::thread::sleep(Duration::from_millis(200))
            }
            Err(e) => panic!("the operator's job query got no answer: {e}"),
        }
    }
    steps_exactly(&mut op_sim, 20);

    // Someone else with a certificate from the same CA: connected (it reads `info`), but a
    // step, a reset, a wildcard query over the simulator's keys and a job get no reply.
    for who in ["stranger", "sim-host"] {
        let c = Client::new(
            open_retrying(&client_opts(&ep, Some(&cfg(who)))),
            keys.clone(),
        );
        let mut s = SimClient::connect(&c, "pend", common::READY).unwrap();
        assert_eq!(s.info.sim.nx(), 2, "{who} reads info");
        s.timeout = Duration::from_secs(2);
        s.retries = 0;
        assert_no_reply(&format!("{who}: step"), s.step(&[0.5], None));
        let reset = keys.sim("pend", SimLeaf::Reset).unwrap();
        assert_no_reply(
            &format!("{who}: reset"),
            c.query(&reset, b"{}".to_vec(), Duration::from_secs(2), who),
        );
        let wild = keys.under(&["sim", "pend", "*"]);
        assert_no_reply(
            &format!("{who}: {wild}"),
            c.query(&wild, Vec::new(), Duration::from_secs(2), who),
        );
        assert_no_reply(
            &format!("{who}: jobs"),
            c.query(&jobs, b"{}".to_vec(), Duration::from_secs(2), who),
        );
    }
    // The simulator saw only the operator's steps: k is where the operator left it.
    let before = op_sim.k;
    assert_eq!(op_sim.step(&[0.0], None).unwrap().k, before + 1);
}
