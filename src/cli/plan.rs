//! `koopbridge plan`: the paper's data-budget heuristic — how many training windows a rank-N
//! embedding needs (m ≳ 40 · N · ln N) — for a latent size or an environment's n_mult range.

use bridge::sweep::data_budget;

/// Arguments of `koopbridge plan`.
#[derive(clap::Args, Debug)]
#[command(
    about = "Print the paper's data budget m ≳ 40·N·ln N for a latent dimension N",
    long_about = "Print the paper's data-budget heuristic for a rank-N embedding: below m ≈ 40·N·ln N training \
        windows a model of latent dimension N is over-parameterised and its error is dominated by the data, \
        not the model. Give --latent N, or --nx with --n-mult to get N = nx·(1 + n_mult) (the encoder of SPEC: \
        n_enc = n_mult·nx). `koopbridge sweep` warns on points below the budget.",
    after_help = "Examples:\n  koopbridge plan --latent 34\n  koopbridge plan --nx 2 --n-mult 1,2,4,8,16   # damped pendulum"
)]
pub struct PlanArgs {
    /// Latent dimension N (repeatable or comma-separated).
    #[arg(long, value_delimiter = ',')]
    pub latent: Vec<usize>,
    /// State dimension nx (with --n-mult).
    #[arg(long)]
    pub nx: Option<usize>,
    /// Encoder width multipliers (with --nx).
    #[arg(long = "n-mult", value_delimiter = ',')]
    pub n_mult: Vec<usize>,
}

/// The latent dimensions the arguments name, in order.
fn latents(args: &PlanArgs) -> anyhow::Result<Vec<usize>> {
    let mut v = args.latent.clone();
    match (args.nx, args.n_mult.is_empty()) {
        (Some(nx), false) => v.extend(args.n_mult.iter().map(|k| nx * (1 + k))),
        (Some(_), true) => anyhow::bail!("--nx needs --n-mult"),
        (None, false) => anyhow::bail!("--n-mult needs --nx"),
        (None, true) => {}
    }
    if v.is_empty() {
        anyhow::bail!("give --latent N, or --nx with --n-mult");
    }
    if v.contains(&0) {
        anyhow::bail!("a latent dimension must be at least 1");
    }
    Ok(v)
}

/// Runs `koopbridge plan`.
pub fn run(args: PlanArgs) -> anyhow::Result<()> {
    println!("{:>8} {:>14}", "N", "m ≳ 40·N·ln N");
    for n in latents(&args)? {
        println!("{n:>8} {:>14.0}", data_budget(n).ceil());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn latents_from_nx_and_n_mult() {
        let a = PlanArgs {
            latent: vec![],
            nx: Some(2),
            n_mult: vec![1, 16],
        };
        assert_eq!(latents(&a).unwrap(), vec![4, 34]);
        let b = PlanArgs {
            latent: vec![],
            nx: Some(2),
            n_mult: vec![],
        };
        assert!(latents(&b).is_err());
    }
}
