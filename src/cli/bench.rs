//! `koopbridge bench`: benchmarks that live apart from the tests; figures go to BENCHMARKS.md.

/// Arguments of `koopbridge bench`.
#[derive(clap::Args)]
pub struct BenchArgs {
    #[command(subcommand)]
    what: BenchWhat,
}

#[derive(clap::Subcommand)]
enum BenchWhat {}

/// Runs `koopbridge bench`.
pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    match args.what {}
}
