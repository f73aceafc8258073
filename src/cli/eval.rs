//! `koopbridge eval` (being built; see its issue).

/// Arguments of `koopbridge eval`.
#[derive(clap::Args)]
pub struct EvalArgs {}

/// Runs `koopbridge eval`.
pub fn run(_args: EvalArgs) -> anyhow::Result<()> {
    anyhow::bail!("'koopbridge eval' is not built yet")
}
