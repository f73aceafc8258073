//! `koopbridge train` (being built; see its issue).

/// Arguments of `koopbridge train`.
#[derive(clap::Args)]
pub struct TrainArgs {}

/// Runs `koopbridge train`.
pub fn run(_args: TrainArgs) -> anyhow::Result<()> {
    anyhow::bail!("'koopbridge train' is not built yet")
}
