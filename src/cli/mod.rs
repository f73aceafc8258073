//! Subcommands of the `koopbridge` binary, one file each.

pub mod bench;
pub mod bench_bridge;
pub mod bench_edmd;
pub mod bench_mpc;
pub mod bench_train;
pub mod control;
pub mod control_diagnostics;
pub mod control_plot;
pub mod data;
pub mod eval;
pub mod learning_curve;
pub mod run;
pub mod scaling;
pub mod serve;
pub mod sim;
pub mod train;

/// Logs to stderr; `RUST_LOG` selects the level (default `info` for koopbridge, `warn` for others).
pub fn init_tracing() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn,koopbridge=info,bridge=info"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .try_init();
}
