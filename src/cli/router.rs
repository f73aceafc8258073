//! `koopbridge router`: a plain Zenoh router (what `zenohd` is) for scale-out setups, with the
//! same endpoint and configuration flags as every other command.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use bridge::session::{open_session, Mode, ZenohOptions};

/// Arguments of `koopbridge router`.
#[derive(clap::Args)]
#[command(after_help = "Example:\n  \
    koopbridge router --listen tcp/127.0.0.1:7447\n  \
    koopbridge serve --session demo --connect tcp/127.0.0.1:7447\n  \
    koopbridge sim --session demo --id pend --connect tcp/127.0.0.1:7447\n\n\
    Peers that connect to the router find each other through it and then connect directly, so\n\
    the router is not in their data path; processes started with --mode client talk through it.")]
pub struct RouterArgs {
    /// Endpoint to listen on. Repeatable. Default: `tcp/127.0.0.1:7447` (or what the
    /// --zenoh-config file says).
    #[arg(long = "listen", value_name = "ENDPOINT")]
    pub listen: Vec<String>,
    /// Another router or peer to connect to. Repeatable.
    #[arg(long = "connect", value_name = "ENDPOINT")]
    pub connect: Vec<String>,
    /// A Zenoh JSON5 configuration file (TLS, access control); the mode is always `router`.
    #[arg(long = "zenoh-config", value_name = "FILE")]
    pub zenoh_config: Option<PathBuf>,
    /// Exit when standard input closes (for a parent process that starts the router).
    #[arg(long)]
    pub stdin_lifeline: bool,
}

/// Runs `koopbridge router` until interrupted (or until standard input closes with
/// `--stdin-lifeline`).
pub fn run(args: RouterArgs) -> anyhow::Result<()> {
    let opts = ZenohOptions {
        connect: args.connect,
        listen: args.listen,
        mode: Some(Mode::Router),
        zenoh_config: args.zenoh_config,
    };
    let stop = if args.stdin_lifeline {
        super::sim::stdin_lifeline()
    } else {
        Arc::new(AtomicBool::new(false))
    };
    let listening = opts
        .config()?
        .get_json("listen/endpoints")
        .unwrap_or_else(|_| "?".into());
    let session = open_session(&opts)?;
    // Printed (not logged) so that a parent or a user always sees where it listens.
    println!("router {} listening on {listening}", session.zid());
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(Duration::from_millis(100));
    }
    let _ = bridge::zenoh::Wait::wait(session.close());
    Ok(())
}
