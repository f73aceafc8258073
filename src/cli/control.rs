//! `koopbridge control` (being built; see its issue).

/// Arguments of `koopbridge control`.
#[derive(clap::Args)]
pub struct ControlArgs {}

/// Runs `koopbridge control`.
pub fn run(_args: ControlArgs) -> anyhow::Result<()> {
    anyhow::bail!("'koopbridge control' is not built yet")
}
