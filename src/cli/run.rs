//! `koopbridge run` (being built; see its issue).

/// Arguments of `koopbridge run`.
#[derive(clap::Args)]
pub struct RunArgs {}

/// Runs `koopbridge run`.
pub fn run(_args: RunArgs) -> anyhow::Result<()> {
    anyhow::bail!("'koopbridge run' is not built yet")
}
