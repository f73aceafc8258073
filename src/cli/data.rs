//! `koopbridge data` (being built; see its issue).

/// Arguments of `koopbridge data`.
#[derive(clap::Args)]
pub struct DataArgs {}

/// Runs `koopbridge data`.
pub fn run(_args: DataArgs) -> anyhow::Result<()> {
    anyhow::bail!("'koopbridge data' is not built yet")
}
