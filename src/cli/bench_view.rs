//! `koopbridge bench view`: what watching a run costs it — the same scenario (its data and models
//! reused) run in turn without and with the live view, paired round by round.

use std::path::PathBuf;

use bridge::orchestrator::viewer::{ViewMode, ViewOptions};
use bridge::orchestrator::{run_scenario_with, Report, RunExtras, RunOptions};
use bridge::scenario::Scenario;
use koopman::mpc::metrics::quantile;

/// Arguments of `koopbridge bench view`.
#[derive(clap::Args)]
#[command(after_help = "Example:\n  \
    koopbridge bench view scenarios/gym-inverted-double-pendulum.toml --pairs 5\n\n\
    A first run collects and trains (into --out); then PAIRS times the scenario runs without a\n\
    viewer and with `--view web` (nobody looking at the page), and each control run's median\n\
    step round trip, solve round trip and their sum are compared pair by pair. Take the figure\n\
    on a quiet machine.")]
pub struct BenchViewArgs {
    /// The scenario (with `[control]`).
    pub scenario: PathBuf,
    /// Pairs of runs (without, with the view).
    #[arg(long, default_value_t = 5)]
    pub pairs: usize,
    /// Output folder (reused by every run).
    #[arg(long, default_value = "results/bench-view")]
    pub out: PathBuf,
}

/// The medians of one run's control runs: (model, step round trip µs, solve round trip µs).
fn medians(r: &Report) -> Vec<(String, f64, f64)> {
    r.controls
        .iter()
        .map(|c| {
            (
                c.model.clone(),
                c.step_round_trip_median_us,
                c.solve_round_trip_median_us,
            )
        })
        .collect()
}

/// Runs `koopbridge bench view`.
pub fn run(args: BenchViewArgs) -> anyhow::Result<()> {
    let sc = Scenario::load(&args.scenario)?;
    anyhow::ensure!(
        !sc.control.is_empty(),
        "{} has no [control]: nothing to time",
        args.scenario.display()
    );
    let opts = RunOptions {
        exe: std::env::current_exe()?,
        out_dir: args.out.clone(),
        zenoh: Default::default(),
        session: None,
        ready_timeout: std::time::Duration::from_secs(60),
        attach_existing: false,
    };
    let once = |view: bool| -> anyhow::Result<Report> {
        let extras = RunExtras {
            view: view.then_some(ViewOptions {
                mode: ViewMode::Web,
                web_port: None,
                video: None,
            }),
            ..Default::default()
        };
        Ok(run_scenario_with(&sc, &opts, &extras, &mut |_| {})?)
    };
    eprintln!("collecting and training once (reused by every timed run) ...");
    once(false)?;
    let mut ratios: Vec<Vec<(f64, f64, f64)>> = Vec::new();
    println!("pair  model  step µs (without → with)  solve µs (without → with)  step+solve ratio");
    for pair in 1..=args.pairs {
        let (a, b) = (medians(&once(false)?), medians(&once(true)?));
        for (i, ((m, s0, q0), (_, s1, q1))) in a.iter().zip(&b).enumerate() {
            let sum = (s1 + q1) / (s0 + q0);
            println!("{pair:>4}  {m}  {s0:.0} → {s1:.0}  {q0:.0} → {q1:.0}  {sum:.3}");
            if ratios.len() <= i {
                ratios.push(Vec::new());
            }
            ratios[i].push((s1 / s0, q1 / q0, sum));
        }
    }
    for (i, r) in ratios.iter().enumerate() {
        let pick =
            |f: fn(&(f64, f64, f64)) -> f64| quantile(&r.iter().map(f).collect::<Vec<_>>(), 0.5);
        println!(
            "control run {}: median ratio with/without the view: step round trip {:.3}, solve round trip {:.3}, step + solve {:.3}",
            i + 1,
            pick(|t| t.0),
            pick(|t| t.1),
            pick(|t| t.2)
        );
    }
    Ok(())
}
