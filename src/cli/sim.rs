//! `koopbridge sim` (being built; see its issue).

/// Arguments of `koopbridge sim`.
#[derive(clap::Args)]
pub struct SimArgs {}

/// Runs `koopbridge sim`.
pub fn run(_args: SimArgs) -> anyhow::Result<()> {
    anyhow::bail!("'koopbridge sim' is not built yet")
}
