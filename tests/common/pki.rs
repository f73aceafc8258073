//! Secure links for the integration tests: test certificate authorities made at test time with
//! the `openssl` CLI, the example configs of `config/` pointed at them, and routers, simulators
//! and clients on a TLS or a QUIC link ([`Link`]), so one test body covers both links.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use bridge::procs::ChildProc;
use bridge::session::{free_loopback_endpoint, open_session, Mode, ZenohOptions};
use bridge::zenoh::Session;

/// The certificate names every test uses: the router's, and one per client identity.
pub const NAMES: [&str; 5] = ["router", "operator", "sim-host", "trainer-host", "stranger"];

/// A secure Zenoh link: TLS over TCP (`zenoh-link-tls`) or QUIC over UDP (`zenoh-link-quic`,
/// quinn). Both take their certificates from the `transport.link.tls` section of a config.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Link {
    /// `tls/…` endpoints, `config/*-tls*.json5`.
    Tls,
    /// `quic/…` endpoints, `config/*-quic*.json5`.
    Quic,
}

impl Link {
    /// `tls` or `quic`: the endpoint scheme and the middle of the config file names.
    pub fn name(self) -> &'static str {
        match self {
            Link::Tls => "tls",
            Link::Quic => "quic",
        }
    }

    /// `config/router-{link}.json5`: the router without an access-control list.
    pub fn router_config(self) -> String {
        format!("router-{}.json5", self.name())
    }

    /// `config/router-{link}-acl.json5`: the router with the access-control list.
    pub fn router_acl_config(self) -> String {
        format!("router-{}-acl.json5", self.name())
    }

    /// `config/client-{link}.json5`: a participant with its own certificate.
    pub fn client_config(self) -> String {
        format!("client-{}.json5", self.name())
    }

    /// A free loopback port as an endpoint of this link on `localhost` (the name in the
    /// router's certificate): a free TCP port for TLS, a free UDP port for QUIC.
    pub fn endpoint(self) -> String {
        let port = match self {
            Link::Tls => free_loopback_endpoint()
                .unwrap()
                .rsplit(':')
                .next()
                .unwrap()
                .to_string(),
            Link::Quic => std::net::UdpSocket::bind("127.0.0.1:0")
                .unwrap()
                .local_addr()
                .unwrap()
                .port()
                .to_string(),
        };
        format!("{}/localhost:{port}", self.name())
    }
}

/// A test CA and certificates signed by it for every one of [`NAMES`] (EC P-256, SAN
/// `localhost`, 127.0.0.1), made with the `openssl` CLI in `dir` (created); `None` when
/// `openssl` is not installed. Nothing of it is committed: every test makes its own.
pub fn make_pki(dir: &Path) -> Option<PathBuf> {
    std::fs::create_dir_all(dir).unwrap();
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

/// `config/{example}` with its CA path pointing into `pki` and its own certificate and key being
/// `pki/{identity}.pem`/`.key` (`identity` may be a path relative to `pki`, e.g.
/// `../other/operator` for a certificate of another CA); lines containing any of `drop` are
/// left out. Written to `out`.
pub fn config(example: &str, pki: &Path, identity: &str, drop: &[&str], out: &Path) -> PathBuf {
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
    // Every certificate and key named exists: a refusal in a test is the handshake's, never a
    // missing file's.
    for f in text
        .split('"')
        .filter(|w| w.ends_with(".pem") || w.ends_with(".key"))
    {
        assert!(Path::new(f).is_file(), "{example}: {f} does not exist");
    }
    let tag = format!(
        "{}-{}",
        pki.file_name().unwrap().to_str().unwrap(),
        identity
    )
    .replace(['/', '.'], "_");
    let path = out.join(format!(
        "{}-{tag}.json5",
        example.trim_end_matches(".json5")
    ));
    std::fs::write(&path, text).unwrap();
    path
}

fn args(v: &[&str]) -> Vec<String> {
    v.iter().map(|s| s.to_string()).collect()
}

/// A Zenoh client of `endpoint` with config file `cfg` (None: the default config).
pub fn client_opts(endpoint: &str, cfg: Option<&Path>) -> ZenohOptions {
    ZenohOptions {
        connect: vec![endpoint.to_string()],
        mode: Some(Mode::Client),
        zenoh_config: cfg.map(Path::to_path_buf),
        ..Default::default()
    }
}

/// Opens a client session, retrying while the router starts (up to `common::READY`).
pub fn open_retrying(z: &ZenohOptions) -> Session {
    let deadline = Instant::now() + super::READY;
    loop {
        match open_session(z) {
            Ok(s) => return s,
            Err(_) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(200)),
            Err(e) => panic!("could not reach the router: {e}"),
        }
    }
}

/// `koopbridge serve {services} --mode router` on `endpoint` (config `cfg` if any), its model
/// store in `dir/models`, its state (and the trainer's data root) in `dir/state`.
pub fn serving_router(
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
    ChildProc::spawn("router", &super::exe(), &a, &dir.join("router.log")).unwrap()
}

/// `koopbridge router --listen {endpoint} --zenoh-config {cfg}`: a router and nothing else.
pub fn plain_router(dir: &Path, endpoint: &str, cfg: &Path) -> ChildProc {
    let a = args(&[
        "router",
        "--listen",
        endpoint,
        "--zenoh-config",
        cfg.to_str().unwrap(),
        "--stdin-lifeline",
    ]);
    ChildProc::spawn("router", &super::exe(), &a, &dir.join("router.log")).unwrap()
}

/// `koopbridge serve {services}` as a Zenoh client of `endpoint` with config `cfg`, its model
/// store in `dir/models`, its state (and the trainer's data root) in `dir/state`.
pub fn client_services(
    dir: &Path,
    session: &str,
    endpoint: &str,
    services: &[&str],
    cfg: &Path,
) -> ChildProc {
    let mut a = args(&["serve"]);
    a.extend(args(services));
    a.extend(args(&["--session", session, "--mode", "client"]));
    a.extend(args(&["--connect", endpoint]));
    a.extend(args(&["--zenoh-config", cfg.to_str().unwrap()]));
    a.extend(args(&["--store", dir.join("models").to_str().unwrap()]));
    a.extend(args(&["--state-dir", dir.join("state").to_str().unwrap()]));
    a.push("--stdin-lifeline".into());
    ChildProc::spawn("services", &super::exe(), &a, &dir.join("services.log")).unwrap()
}

/// `koopbridge sim` (damped pendulum) as simulator `id`, a Zenoh client of `endpoint`.
pub fn sim(dir: &Path, session: &str, id: &str, endpoint: &str, cfg: Option<&Path>) -> ChildProc {
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
    ChildProc::spawn("sim", &super::exe(), &a, &dir.join(format!("sim-{id}.log"))).unwrap()
}
