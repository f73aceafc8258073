//! `koopbridge bench`: benchmarks that live apart from the tests; figures go to BENCHMARKS.md.

/// Arguments of `koopbridge bench`.
#[derive(clap::Args)]
pub struct BenchArgs {
    #[command(subcommand)]
    what: BenchWhat,
}

#[derive(clap::Subcommand)]
enum BenchWhat {
    /// Zenoh round trips: bare query, lockstep step, MPC solve (and free-run stream gaps).
    Bridge(super::bench_bridge::BenchBridgeArgs),
    /// EDMD-with-control fit time (140k pairs, ~240 features) and its prediction error.
    Edmd(super::bench_edmd::BenchEdmdArgs),
    /// MPC solve times: dedicated box-QP solver vs Clarabel (N, nu, H sweep).
    Mpc(super::bench_mpc::BenchMpcArgs),
    /// Training speed (iterations/second) of the neural Koopman trainer.
    Train(super::bench_train::BenchTrainArgs),
    /// What the live view costs a run: step and solve round trips without and with `--view`.
    View(super::bench_view::BenchViewArgs),
}

/// Runs `koopbridge bench`.
pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    match args.what {
        BenchWhat::Bridge(a) => super::bench_bridge::run(a),
        BenchWhat::Edmd(a) => super::bench_edmd::run(a),
        BenchWhat::Mpc(a) => super::bench_mpc::run(a),
        BenchWhat::Train(a) => super::bench_train::run(a),
        BenchWhat::View(a) => super::bench_view::run(a),
    }
}
