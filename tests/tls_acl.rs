//! Secure links and access control with the example configs of `config/`, each test run once over
//! TLS (`router-tls*.json5`) and once over QUIC (`router-quic*.json5`) by the same body: a secure
//! router refuses plain TCP, clients without a certificate and certificates of another CA (and
//! a client that trusts another CA refuses the router); its access-control list lets only
//! `CN=operator` step simulators and submit jobs (a peer outside the list gets no reply).
//! Certificates are made here with the `openssl` CLI (`common::pki`); the lockstep round trip
//! over TLS and QUIC against plain TCP is an ignored measurement (`tls_round_trip_cost_against_tcp`).

mod common;

use std::path::PathBuf;
use std::time::{Duration, Instant};

use bridge::client::{Client, SimClient};
use bridge::keyexpr::{fresh_session_id, Keys, SimLeaf};
use bridge::messages::ResetRequest;
use bridge::procs::ChildProc;
use bridge::session::{free_loopback_endpoint, open_session};
use bridge::Error;
use common::pki::{client_opts, config, make_pki, open_retrying, serving_router, sim, Link};

/// Median and 99th percentile (µs) of `n` lockstep round trips of `sim` after a reset.
fn step_timing(sim: &mut SimClient, n: usize) -> (f64, f64) {
    sim.reset(&ResetRequest {
        seed: Some(1),
        x0: None,
        perturbation: None,
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

/// A secure router (`router-{link}.json5`, a model store) and the operator's client of it.
struct SecureRouter {
    dir: PathBuf,
    pki: PathBuf,
    session: String,
    endpoint: String,
    client: Client,
    _router: ChildProc,
}

/// Starts a [`SecureRouter`] on `link` in a scratch folder named `tag`; `None` (with a SKIPPED
/// line) when the `openssl` CLI is not installed.
fn secure_router(link: Link, tag: &str) -> Option<SecureRouter> {
    let dir = common::scratch(tag);
    let Some(pki) = make_pki(&dir.join("pki")) else {
        eprintln!("SKIPPED: the openssl CLI is not installed (needed to make test certificates)");
        return None;
    };
    let session = fresh_session_id();
    let endpoint = link.endpoint();
    let router_cfg = config(&link.router_config(), &pki, "router", &[], &dir);
    let router = serving_router(&dir, &session, &endpoint, &["models"], Some(&router_cfg));
    let op_cfg = config(&link.client_config(), &pki, "operator", &[], &dir);
    let client = Client::new(
        open_retrying(&client_opts(&endpoint, Some(&op_cfg))),
        Keys::new(&session).unwrap(),
    );
    Some(SecureRouter {
        dir,
        pki,
        session,
        endpoint,
        client,
        _router: router,
    })
}

/// Who gets a session with the secure router of `link`: the operator does (it has a client);
/// plain TCP, a client without a certificate, a certificate of another CA and a client that
/// trusts another CA do not. Then a simulator behind the router steps exactly for the operator.
fn refuses_the_unauthenticated(link: Link) {
    let name = link.name();
    let Some(SecureRouter {
        dir,
        pki,
        session,
        endpoint: ep,
        client,
        _router,
    }) = secure_router(link, name)
    else {
        return;
    };
    eprintln!("{name}: the operator has a session");
    let refused = |what: &str, cfg: Option<&std::path::Path>, ep: &str| match open_session(
        &client_opts(ep, cfg),
    ) {
        Ok(_) => panic!("{name}: {what} got a session with the router"),
        Err(e) => eprintln!("{name}: {what} refused: {e}"),
    };
    // Plain TCP to the same port (for TLS the TCP connection opens, the Zenoh session does not).
    let port = ep.rsplit(':').next().unwrap();
    refused("plain TCP", None, &format!("tcp/127.0.0.1:{port}"));
    // The secure link without a client certificate: refused by mutual authentication.
    let no_cert = config(
        &link.client_config(),
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
    refused("a client without a certificate", Some(&no_cert), &ep);
    // A second CA with the same names: its certificates are not the router's CA's.
    let other = make_pki(&dir.join("other")).unwrap();
    let foreign_cert = config(&link.client_config(), &pki, "../other/operator", &[], &dir);
    refused("CN=operator signed by another CA", Some(&foreign_cert), &ep);
    let foreign_ca = config(&link.client_config(), &other, "../pki/operator", &[], &dir);
    refused(
        "a client that trusts another CA (not the router's)",
        Some(&foreign_ca),
        &ep,
    );
    // A simulator behind the router steps for the operator: a few exact steps (the timing
    // against plain TCP is the ignored `tls_round_trip_cost_against_tcp`).
    let host_cfg = config(&link.client_config(), &pki, "sim-host", &[], &dir);
    let _sim = sim(&dir, &session, "pend", &ep, Some(&host_cfg));
    let mut s = SimClient::connect(&client, "pend", common::READY).unwrap();
    steps_exactly(&mut s, 20);
}

#[test]
fn tls_router_refuses_plain_tcp_clients_without_a_certificate_and_other_cas() {
    refuses_the_unauthenticated(Link::Tls);
}

#[test]
fn quic_router_refuses_plain_tcp_clients_without_a_certificate_and_other_cas() {
    refuses_the_unauthenticated(Link::Quic);
}

/// Resets `sim` and steps it `n` times, checking each step's index.
fn steps_exactly(sim: &mut SimClient, n: u64) {
    sim.reset(&ResetRequest {
        seed: Some(1),
        x0: None,
        perturbation: None,
    })
    .unwrap();
    for k in 1..=n {
        assert_eq!(sim.step(&[0.1], None).unwrap().k, k);
    }
}

/// The cost of TLS and of QUIC on the lockstep round trip through a router: 1000 steps over
/// each, then the same topology over plain TCP (BENCHMARKS.md, "Reliability"). A measurement,
/// not a check, and kept out of CI: zenoh-link-tls 1.10.2 reads and writes one TLS stream from
/// two tasks at once through an `UnsafeCell` (upstream eclipse-zenoh/zenoh#2557, open), which
/// under sustained two-way traffic has aborted this process with a corrupted `rustls` error
/// (seen in session 7) and lost replies (sessions 5–6); QUIC's reliability under load is the
/// soak of `tests/quic_soak.rs`. Run with
/// `cargo test --release --workspace --test tls_acl -- --ignored --nocapture`.
#[test]
#[ignore]
fn tls_round_trip_cost_against_tcp() {
    let mut line = Vec::new();
    for link in [Link::Tls, Link::Quic] {
        let Some(SecureRouter {
            dir,
            pki,
            session,
            endpoint: ep,
            client,
            _router,
        }) = secure_router(link, &format!("{}-timing", link.name()))
        else {
            return;
        };
        let host_cfg = config(&link.client_config(), &pki, "sim-host", &[], &dir);
        let _sim = sim(&dir, &session, "pend", &ep, Some(&host_cfg));
        let mut s = SimClient::connect(&client, "pend", common::READY).unwrap();
        let (med, p99) = step_timing(&mut s, 1000);
        line.push((link.name().to_uppercase(), med, p99));
    }
    let tcp_dir = common::scratch("tcp-timing");
    let tcp_session = fresh_session_id();
    let tcp_ep = free_loopback_endpoint().unwrap();
    let _tcp_router = serving_router(&tcp_dir, &tcp_session, &tcp_ep, &["models"], None);
    let tcp_client = Client::new(
        open_retrying(&client_opts(&tcp_ep, None)),
        Keys::new(&tcp_session).unwrap(),
    );
    let _tcp_sim = sim(&tcp_dir, &tcp_session, "pend", &tcp_ep, None);
    let mut t = SimClient::connect(&tcp_client, "pend", common::READY).unwrap();
    let (tcp_med, tcp_p99) = step_timing(&mut t, 1000);
    for (name, med, p99) in line {
        eprintln!(
            "lockstep round trip via a router, 1000 steps: {name} median {med:.0} µs p99 {p99:.0} µs; \
             TCP median {tcp_med:.0} µs p99 {tcp_p99:.0} µs; ratio {:.2}",
            med / tcp_med
        );
    }
}

/// The router of `link` with the access-control list: the operator steps the simulator and
/// reaches the trainer; a certificate outside the list (and the serving `CN=sim-host`) reads
/// `info` but gets no reply to a step, a reset, a wildcard query or a job.
fn acl_lets_only_the_operator_act(link: Link) {
    let dir = common::scratch(&format!("acl-{}", link.name()));
    let Some(pki) = make_pki(&dir.join("pki")) else {
        eprintln!("SKIPPED: the openssl CLI is not installed (needed to make test certificates)");
        return;
    };
    let session = fresh_session_id();
    let keys = Keys::new(&session).unwrap();
    let ep = link.endpoint();
    let router_cfg = config(&link.router_acl_config(), &pki, "router", &[], &dir);
    let _router = serving_router(
        &dir,
        &session,
        &ep,
        &["trainer", "models"],
        Some(&router_cfg),
    );
    let cfg = |who: &str| config(&link.client_config(), &pki, who, &[], &dir);
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
            perturbation: None,
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

#[test]
fn acl_lets_only_the_operator_step_and_submit_jobs() {
    acl_lets_only_the_operator_act(Link::Tls);
}

#[test]
fn quic_acl_lets_only_the_operator_step_and_submit_jobs() {
    acl_lets_only_the_operator_act(Link::Quic);
}
