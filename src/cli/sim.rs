//! `koopbridge sim`: serves a built-in reference system as a Zenoh simulator adapter (lockstep
//! `info`/`reset`/`step`, or free-run `state`/`command`).

use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use bridge::adapter::{serve, AdapterOptions, FreeRunOptions, ResetRequest, SystemBackend};
use bridge::session::open_session;

/// Arguments of `koopbridge sim`.
#[derive(clap::Args)]
#[command(after_help = "Examples:\n  \
    koopbridge sim --env damped-pendulum --id pend --session demo --listen tcp/127.0.0.1:7501\n  \
    koopbridge sim --env double --id dp --session demo --connect tcp/127.0.0.1:7501 --free-run --rate 1000 --steps 60000\n\n\
    Keys served: koopbridge/{session}/sim/{id}/{info,reset,step} (lockstep) or\n\
    koopbridge/{session}/sim/{id}/state (published) and .../command (subscribed) with --free-run.\n\
    See PROTOCOL.md.")]
pub struct SimArgs {
    /// Built-in system: damped-pendulum, double-pendulum or polynomial (aliases damped, double).
    #[arg(long, default_value = "damped-pendulum")]
    pub env: String,
    /// Simulator id: the `{id}` chunk of its keys ([a-z0-9_-]).
    #[arg(long, default_value = "sim0")]
    pub id: String,
    /// koopbridge session id: the `{session}` chunk of every key ([a-z0-9_-]).
    #[arg(long, default_value = "default")]
    pub session: String,
    /// Free-run mode: step in real time (or at --rate), publish `state`, apply the latest `command`.
    #[arg(long)]
    pub free_run: bool,
    /// Free-run: steps per wall-clock second (default: real time, 1/dt).
    #[arg(long, value_name = "HZ", requires = "free_run")]
    pub rate: Option<f64>,
    /// Free-run: stop after this many steps and print the adapter's counters as JSON.
    #[arg(long, requires = "free_run")]
    pub steps: Option<u64>,
    /// Free-run: wait up to this many seconds for a subscriber of `state` before starting.
    #[arg(long, value_name = "SECONDS", requires = "free_run")]
    pub wait_subscriber: Option<f64>,
    /// Free-run: seed of the initial-state draw.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Exit when standard input closes (used by `koopbridge run` so that children never outlive it).
    #[arg(long)]
    pub stdin_lifeline: bool,
    #[command(flatten)]
    pub zenoh: super::ZenohArgs,
}

/// Sets the returned flag when standard input reaches end of file.
pub fn stdin_lifeline() -> Arc<AtomicBool> {
    let stop = Arc::new(AtomicBool::new(false));
    let s = stop.clone();
    std::thread::spawn(move || {
        use std::io::Read;
        let mut buf = [0u8; 256];
        let mut stdin = std::io::stdin();
        while matches!(stdin.read(&mut buf), Ok(n) if n > 0) {}
        s.store(true, std::sync::atomic::Ordering::Relaxed);
    });
    stop
}

/// Runs `koopbridge sim`.
pub fn run(args: SimArgs) -> anyhow::Result<()> {
    let system = koopman::systems::by_name(&args.env)?;
    let mut opts = AdapterOptions::new(&args.session, &args.id)?;
    if args.free_run {
        opts.free_run = Some(FreeRunOptions {
            rate_hz: args.rate,
            steps: args.steps,
            reset: ResetRequest {
                seed: Some(args.seed),
                x0: None,
                perturbation: None,
            },
        });
        opts.wait_subscriber = args.wait_subscriber.map(std::time::Duration::from_secs_f64);
    }
    let stop = if args.stdin_lifeline {
        stdin_lifeline()
    } else {
        Arc::new(AtomicBool::new(false))
    };
    let session = open_session(&args.zenoh.options())?;
    tracing::info!(
        "simulator '{}' ({}) serving in session '{}'{}",
        args.id,
        system.name(),
        args.session,
        if args.free_run { " (free-run)" } else { "" }
    );
    let mut backend = SystemBackend::new(system);
    let stats = serve(&session, &mut backend, &opts, &stop)?;
    println!("{}", serde_json::to_string(&stats)?);
    let _ = bridge::zenoh::Wait::wait(session.close());
    Ok(())
}
