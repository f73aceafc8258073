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
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
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
    /// The name Zenoh and the command line use (`peer`, `client`, `router`).
    pub fn as_str(self) -> &'static str {
        match self {
            Mode::Peer => "peer",
            Mode::Client => "client",
            Mode::Router => "router",
        }
    }
}

impl std::str::FromStr for Mode {
    type Err = Error;

    fn from_str(s: &str) -> Result<Self> {
        match s {
            "peer" => Ok(Mode::Peer),
            "client" => Ok(Mode::Client),
            "router" => Ok(Mode::Router),
            other => Err(Error::Config(format!(
                "zenoh mode '{other}': expected peer, client or router"
            ))),
        }
    }
}

/// Zenoh options shared by every koopbridge command that talks over Zenoh (the binary's
/// command-line flags `--connect`, `--listen`, `--mode`, `--zenoh-config` fill it).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ZenohOptions {
    /// Endpoints to connect to, e.g. `tcp/127.0.0.1:7447` (a router or another koopbridge
    /// process).
    pub connect: Vec<String>,
    /// Endpoints to listen on. Empty: `tcp/127.0.0.1:0` (a free loopback port) for a peer,
    /// `tcp/127.0.0.1:7447` for a router, nothing for a client — or what the config file says.
    pub listen: Vec<String>,
    /// Zenoh mode. `None`: the config file's `mode` if there is a file, else [`Mode::Peer`]. A
    /// mode that is not given never overrides the file.
    pub mode: Option<Mode>,
    /// A Zenoh JSON5 configuration file (routers, TLS, access control). The options above are
    /// applied on top of it; multicast scouting is then left as the file says.
    pub zenoh_config: Option<PathBuf>,
}

impl ZenohOptions {
    /// Options for a peer that listens on `listen` and connects to `connect`.
    pub fn peer(listen: Vec<String>, connect: Vec<String>) -> Self {
        ZenohOptions {
            connect,
            listen,
            mode: Some(Mode::Peer),
            zenoh_config: None,
        }
    }

    /// The command-line arguments that reproduce these options (for spawning children); a mode
    /// that is not set is not passed.
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
        if let Some(m) = self.mode {
            a.push("--mode".into());
            a.push(m.as_str().into());
        }
        if let Some(p) = &self.zenoh_config {
            a.push("--zenoh-config".into());
            a.push(p.display().to_string());
        }
        a
    }

    /// The mode a session opened with these options has, if known without reading the file:
    /// the given mode, else peer when there is no file; `None` = the file decides.
    pub fn effective_mode(&self) -> Option<Mode> {
        match (self.mode, &self.zenoh_config) {
            (Some(m), _) => Some(m),
            (None, None) => Some(Mode::Peer),
            (None, Some(_)) => None,
        }
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
        let mode = self.effective_mode();
        if let Some(m) = mode {
            c.insert_json5("mode", &json_str(m.as_str()))
                .map_err(|e| cfg_err("mode", &e))?;
        }
        let listen = if !self.listen.is_empty() {
            self.listen.clone()
        } else if self.zenoh_config.is_some() {
            Vec::new()
        } else {
            match mode.unwrap_or_default() {
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
    zenoh::open(cfg).wait().map_err(|e| {
        let mode = opts.effective_mode().map_or("configured", Mode::as_str);
        Error::Zenoh(format!("cannot open session ({mode} mode): {e}"))
    })
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

    #[test]
    fn options_round_trip_through_args() {
        let z = ZenohOptions {
            connect: vec!["tcp/127.0.0.1:7447".into()],
            mode: Some(Mode::Client),
            ..Default::default()
        };
        assert_eq!(
            z.to_args(),
            ["--connect", "tcp/127.0.0.1:7447", "--mode", "client"]
        );
        let c = z.config().unwrap();
        let s = format!("{c:?}");
        assert!(s.contains("7447"), "{s}");
        assert!("bogus".parse::<Mode>().is_err());
        assert_eq!("router".parse::<Mode>().unwrap(), Mode::Router);
        let bad = ZenohOptions {
            zenoh_config: Some("/nonexistent/z.json5".into()),
            ..Default::default()
        };
        assert!(matches!(bad.config(), Err(Error::Config(_))));
        // No mode given: nothing passed on, so a child's config file keeps its own mode.
        assert!(!ZenohOptions::default().to_args().contains(&"--mode".into()));
    }

    /// The mode of a `--zenoh-config` file survives when no mode is given, and a given mode
    /// wins over it (issue 15: the flag's default used to overwrite the file).
    #[test]
    fn a_mode_not_given_leaves_the_files_mode() {
        let dir = std::env::temp_dir().join(format!("kb-zcfg-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("client.json5");
        std::fs::write(&file, "{ mode: \"client\" }").unwrap();
        let from_file = ZenohOptions {
            zenoh_config: Some(file.clone()),
            ..Default::default()
        };
        let mode_of = |c: &zenoh::Config| c.get_json("mode").unwrap();
        assert_eq!(mode_of(&from_file.config().unwrap()), "\"client\"");
        assert_eq!(from_file.effective_mode(), None);
        let given = ZenohOptions {
            mode: Some(Mode::Peer),
            ..from_file
        };
        assert_eq!(mode_of(&given.config().unwrap()), "\"peer\"");
        assert_eq!(
            mode_of(&ZenohOptions::default().config().unwrap()),
            "\"peer\""
        );
        std::fs::remove_dir_all(&dir).ok();
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
