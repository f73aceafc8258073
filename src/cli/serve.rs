//! `koopbridge serve` (being built; see its issue).

/// Arguments of `koopbridge serve`.
#[derive(clap::Args)]
pub struct ServeArgs {}

/// Runs `koopbridge serve`.
pub fn run(_args: ServeArgs) -> anyhow::Result<()> {
    anyhow::bail!("'koopbridge serve' is not built yet")
}
