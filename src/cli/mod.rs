//! Subcommands of the `koopbridge` binary, one file each.

pub mod bench;
pub mod bench_bridge;
pub mod bench_edmd;
pub mod bench_mpc;
pub mod bench_train;
pub mod bench_view;
pub mod control;
pub mod control_diagnostics;
pub mod control_plot;
pub mod control_table;
pub mod data;
pub mod eval;
pub mod export_fmu;
pub mod learning_curve;
pub mod natural_order;
pub mod plan;
pub mod router;
pub mod run;
pub mod scaling;
pub mod serve;
pub mod sim;
pub mod sweep;
pub mod sweep_local;
pub mod train;
pub mod view;

use std::path::PathBuf;

use bridge::session::{Mode, ZenohOptions};

/// Zenoh's role for this process (the `--mode` flag).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ModeArg {
    /// A peer: connects directly to other peers (the embedded default).
    Peer,
    /// A client: talks through the router or peer it connects to.
    Client,
    /// A router: forwards for clients and peers (what `zenohd` is).
    Router,
}

impl From<ModeArg> for Mode {
    fn from(m: ModeArg) -> Self {
        match m {
            ModeArg::Peer => Mode::Peer,
            ModeArg::Client => Mode::Client,
            ModeArg::Router => Mode::Router,
        }
    }
}

/// The Zenoh flags shared by every koopbridge command that talks over Zenoh.
#[derive(Clone, Debug, Default, clap::Args)]
pub struct ZenohArgs {
    /// Endpoint to connect to, e.g. `tcp/127.0.0.1:7447` (a router or another koopbridge
    /// process). Repeatable.
    #[arg(long = "connect", value_name = "ENDPOINT")]
    pub connect: Vec<String>,
    /// Endpoint to listen on. Repeatable. Default: `tcp/127.0.0.1:0` (a free loopback port) for a
    /// peer, `tcp/127.0.0.1:7447` for a router, nothing for a client.
    #[arg(long = "listen", value_name = "ENDPOINT")]
    pub listen: Vec<String>,
    /// Zenoh mode of this process [default: peer, or the --zenoh-config file's `mode`].
    #[arg(long = "mode", value_enum)]
    pub mode: Option<ModeArg>,
    /// A Zenoh JSON5 configuration file (routers, TLS, access control). The flags above that are
    /// given are applied on top of it; multicast scouting is then left as the file says.
    #[arg(long = "zenoh-config", value_name = "FILE")]
    pub zenoh_config: Option<PathBuf>,
}

impl ZenohArgs {
    /// The library's options from these flags.
    pub fn options(&self) -> ZenohOptions {
        ZenohOptions {
            connect: self.connect.clone(),
            listen: self.listen.clone(),
            mode: self.mode.map(Mode::from),
            zenoh_config: self.zenoh_config.clone(),
        }
    }
}

/// Logs to stderr; `RUST_LOG` selects the level (default `info` for koopbridge, `warn` for others).
pub fn init_tracing() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn,koopbridge=info,bridge=info"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_writer(std::io::stderr)
        .try_init();
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        z: ZenohArgs,
    }

    #[test]
    fn zenoh_flags_parse_and_round_trip_through_args() {
        let cli = Cli::parse_from(["x", "--connect", "tcp/127.0.0.1:7447", "--mode", "client"]);
        let z = cli.z.options();
        assert_eq!(z.mode, Some(Mode::Client));
        assert_eq!(z.connect, vec!["tcp/127.0.0.1:7447"]);
        let again = Cli::parse_from(std::iter::once("x".to_string()).chain(z.to_args()));
        assert_eq!(again.z.options(), z);
        assert!(Cli::try_parse_from(["x", "--mode", "bogus"]).is_err());
        // A --mode not given stays unset (the config file's mode is kept).
        assert_eq!(Cli::parse_from(["x"]).z.options().mode, None);
    }
}
