//! Opening a Zenoh session from command-line options: embedded peer on loopback by default,
//! multicast scouting off, `--connect`/`--listen`/`--mode`/`--zenoh-config` for everything else.
//!
//! Discovery without multicast: a process started by `koopbridge run` (or any parent) listens on
//! a free loopback port and passes `--connect tcp/127.0.0.1:PORT` to the processes it spawns;
//! each of those listens on its own loopback port (`tcp/127.0.0.1:0`) and gossip scouting (on by
//! default) tells the peers about each other, so they also connect directly.

use std::path::PathBuf;

use zenoh::{Session, Wait};

use crate::error::{Error, Result};

/// Zenoh's role for this process.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Mode {
    /// A peer: connects directly to other peers (the embedded default).
    #[default]
    Peer,
    /// A client: talks through the router or peer it connects to.
    Client,
    /// A router: forwards for clients and peers (what `zenohd` is).
    Router,
}

impl Mode {
    fn as_str(self) -> &'static str {
        match self {
            Mode::Peer => "peer",
            Mode::Client => "client",
            Mode::Router => "router",
        }
    }
}

/// Zenoh options shared by every koopbridge command that talks over Zenoh.
#[derive(Clone, Debug, Default, clap::Args)]
pub struct ZenohOptions {
    /// Endpoint to connect to, e.g. `tcp/127.0.0.1:7447` (a router or another koopbridge
    /// process). Repeatable.
    #[arg(long = "connect", value_name = "ENDPOINT")]
    pub connect: Vec<String>,
    /// Endpoint to listen on. Repeatable. Default: `tcp/127.0.0.1:0` (a free loopback port) for a
    /// peer, `tcp/127.0.0.1:7447` for a router, nothing for a client.
    #[arg(long = "listen", value_name = "ENDPOINT")]
    pub listen: Vec<String>,
    /// Zenoh mode of this process.
    #[arg(long = "mode", value_enum, default_value_t = Mode::Peer)]
    pub mode: Mode,
    /// A Zenoh JSON5 configuration file (routers, TLS, access control). The flags above are
    /// applied on top of it; multicast scouting is then left as the file says.
    #[arg(long = "zenoh-config", value_name = "FILE")]
    pub zenoh_config: Option<PathBuf>,
}

impl ZenohOptions {
    /// Options for a peer that listens on `listen` and connects to `connect`.
    pub fn peer(listen: Vec<String>, connect: Vec<String>) -> Self {
        ZenohOptions {
            connect,
            listen,
            mode: Mode::Peer,
            zenoh_config: None,
        }
    }

    /// The command-line arguments that reproduce these options (for spawning children).
    pub fn to_args(&self) -> Vec<String> {
        let mut a = Vec::new();
        for c in &self.connect {
            a.push("--connect".into());
            a.push(c.clone());
        }
        for l in &self.listen {
            a.push("--listen".into());
            a.push(l.clone());
        }
        a.push("--mode".into());
        a.push(self.mode.as_str().into());
        if let Some(p) = &self.zenoh_config {
            a.push("--zenoh-config".into());
            a.push(p.display().to_string());
        }
        a
    }

    /// The Zenoh configuration these options describe.
    pub fn config(&self) -> Result<zenoh::Config> {
        let cfg_err = |what: &str, e: &dyn std::fmt::Display| Error::Config(format!("{what}: {e}"));
        let mut c = match &self.zenoh_config {
            Some(p) => zenoh::Config::from_file(p)
                .map_err(|e| cfg_err(&format!("zenoh config {}", p.display()), &e))?,
            None => {
                let mut c = zenoh::Config::default();
                c.insert_json5("scouting/multicast/enabled", "false")
                    .map_err(|e| cfg_err("scouting", &e))?;
                c
            }
        };
        c.insert_json5("mode", &json_str(self.mode.as_str()))
            .map_err(|e| cfg_err("mode", &e))?;
        let listen = if !self.listen.is_empty() {
            self.listen.clone()
        } else if self.zenoh_config.is_some() {
            Vec::new()
        } else {
            match self.mode {
                Mode::Peer => vec!["tcp/127.0.0.1:0".to_string()],
                Mode::Router => vec!["tcp/127.0.0.1:7447".to_string()],
                Mode::Client => Vec::new(),
            }
        };
        if !listen.is_empty() || self.zenoh_config.is_none() {
            c.insert_json5("listen/endpoints", &json_list(&listen))
                .map_err(|e| cfg_err("--listen", &e))?;
        }
        if !self.connect.is_empty() {
            c.insert_json5("connect/endpoints", &json_list(&self.connect))
                .map_err(|e| cfg_err("--connect", &e))?;
        }
        Ok(c)
    }
}

fn json_str(s: &str) -> String {
    serde_json::to_string(s).unwrap_or_else(|_| "\"\"".into())
}

fn json_list(v: &[String]) -> String {
    serde_json::to_string(v).unwrap_or_else(|_| "[]".into())
}

/// Opens a Zenoh session (blocking; usable from any thread, inside or outside a tokio runtime).
pub fn open_session(opts: &ZenohOptions) -> Result<Session> {
    let cfg = opts.config()?;
    zenoh::open(cfg)
        .wait()
        .map_err(|e| Error::Zenoh(format!("cannot open session ({:?} mode): {e}", opts.mode)))
}

/// A free TCP port on 127.0.0.1, as an endpoint `tcp/127.0.0.1:PORT` (the OS picks it; it is
/// released before returning, so another process could in principle take it first).
pub fn free_loopback_endpoint() -> Result<String> {
    let l = std::net::TcpListener::bind("127.0.0.1:0").map_err(|e| Error::Io {
        path: "127.0.0.1:0".into(),
        source: e,
    })?;
    let port = l
        .local_addr()
        .map_err(|e| Error::Io {
            path: "127.0.0.1:0".into(),
            source: e,
        })?
        .port();
    Ok(format!("tcp/127.0.0.1:{port}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        z: ZenohOptions,
    }

    #[test]
    fn options_parse_and_round_trip_through_args() {
        let cli = Cli::parse_from(["x", "--connect", "tcp/127.0.0.1:7447", "--mode", "client"]);
        assert_eq!(cli.z.mode, Mode::Client);
        assert_eq!(cli.z.connect, vec!["tcp/127.0.0.1:7447"]);
        let again = Cli::parse_from(std::iter::once("x".to_string()).chain(cli.z.to_args()));
        assert_eq!(again.z.to_args(), cli.z.to_args());
        let c = cli.z.config().unwrap();
        let s = format!("{c:?}");
        assert!(s.contains("7447"), "{s}");
        assert!(Cli::try_parse_from(["x", "--mode", "bogus"]).is_err());
        let bad = ZenohOptions {
            zenoh_config: Some("/nonexistent/z.json5".into()),
            ..Default::default()
        };
        assert!(matches!(bad.config(), Err(Error::Config(_))));
    }

    #[test]
    fn two_sessions_on_loopback_exchange_a_put() {
        let ep = free_loopback_endpoint().unwrap();
        let a = open_session(&ZenohOptions::peer(vec![ep.clone()], vec![])).unwrap();
        let b = open_session(&ZenohOptions::peer(vec![], vec![ep])).unwrap();
        let sub = a.declare_subscriber("koopbridge/t/put").wait().unwrap();
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(20);
        let mut got = None;
        while got.is_none() && std::time::Instant::now() < deadline {
            b.put("koopbridge/t/put", vec![1u8, 2, 3]).wait().unwrap();
            got = sub
                .recv_timeout(std::time::Duration::from_millis(200))
                .unwrap();
        }
        let s = got.expect("no sample within 20 s");
        assert_eq!(s.payload().to_bytes().as_ref(), &[1, 2, 3]);
    }
}
