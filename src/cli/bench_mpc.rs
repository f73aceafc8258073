//! `koopbridge bench mpc`: solve times of the dedicated box-QP solver and Clarabel on random
//! stable lifted models along receding-horizon closed loops, with the inputs compared per step.

use std::time::Instant;

use anyhow::Context;
use koopman::model::matrix::MatrixModel;
use koopman::model::LiftedModel;
use koopman::mpc::{MpcConfig, MpcController, SolveStatus, SolverKind};
use serde::Serialize;

/// Arguments of `koopbridge bench mpc`.
#[derive(clap::Args, Debug)]
#[command(
    about = "MPC solve times: dedicated box-QP solver vs Clarabel on random stable lifted models"
)]
pub struct BenchMpcArgs {
    /// Latent sizes N to test (nx = N / 17, as for n_mult = 16).
    #[arg(long, value_delimiter = ',', default_value = "34,238,1088")]
    pub latent: Vec<usize>,
    /// Input dimensions nu to test.
    #[arg(long, value_delimiter = ',', default_value = "1,7,23")]
    pub inputs: Vec<usize>,
    /// Horizons H to test.
    #[arg(long, value_delimiter = ',', default_value = "10,20")]
    pub horizon: Vec<usize>,
    /// Receding-horizon steps per case (each timed for both solvers).
    #[arg(long, default_value_t = 200)]
    pub steps: usize,
    /// Diagonal input weight R (R = 0 makes H singular when H·nu > H·nx; see BENCHMARKS.md).
    #[arg(long, default_value_t = 1e-3)]
    pub r: f64,
    /// Random seed of the models and initial states.
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// One JSON object per line instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// One line of the report.
#[derive(Serialize, Debug)]
struct CaseResult {
    solver: &'static str,
    latent: usize,
    states: usize,
    inputs: usize,
    horizon: usize,
    steps: usize,
    median_ms: f64,
    p99_ms: f64,
    mean_iterations: f64,
    /// Largest |u_dedicated − u_clarabel| over all steps and plan entries.
    max_abs_input_diff: f64,
    /// Fraction of plan entries on a bound (dedicated solver).
    active_fraction: f64,
    /// Clarabel median / dedicated median, on the dedicated line.
    #[serde(skip_serializing_if = "Option::is_none")]
    speedup_vs_clarabel: Option<f64>,
    not_solved: usize,
}

/// Runs `koopbridge bench mpc`.
pub fn run(args: BenchMpcArgs) -> anyhow::Result<()> {
    if args.steps == 0 {
        anyhow::bail!("--steps must be at least 1");
    }
    if !(args.r.is_finite() && args.r >= 0.0) {
        anyhow::bail!("--r must be finite and ≥ 0, got {}", args.r);
    }
    if !args.json {
        println!(
            "{:>10} {:>5} {:>3} {:>3} {:>3} {:>10} {:>10} {:>6} {:>10} {:>7} {:>8}",
            "solver",
            "N",
            "nx",
            "nu",
            "H",
            "median ms",
            "p99 ms",
            "iters",
            "max|Δu|",
            "active",
            "speedup"
        );
    }
    for &latent in &args.latent {
        for &nu in &args.inputs {
            for &h in &args.horizon {
                let [ded, cla] = bench_case(&args, latent, nu, h)
                    .with_context(|| format!("case N={latent} nu={nu} H={h}"))?;
                for c in [&ded, &cla] {
                    if args.json {
                        println!("{}", serde_json::to_string(c)?);
                    } else {
                        println!(
                            "{:>10} {:>5} {:>3} {:>3} {:>3} {:>10.4} {:>10.4} {:>6.1} {:>10.2e} {:>7.2} {:>8}",
                            c.solver,
                            c.latent,
                            c.states,
                            c.inputs,
                            c.horizon,
                            c.median_ms,
                            c.p99_ms,
                            c.mean_iterations,
                            c.max_abs_input_diff,
                            c.active_fraction,
                            c.speedup_vs_clarabel.map(|s| format!("{s:.1}x")).unwrap_or_default()
                        );
                    }
                }
            }
        }
    }
    Ok(())
}

fn quantile_ms(times: &mut [f64], p: f64) -> f64 {
    times.sort_by(|a, b| a.total_cmp(b));
    let idx = ((times.len() as f64 - 1.0) * p).round() as usize;
    times[idx] * 1e3
}

/// Runs one case: both controllers see the same sequence of states (the closed loop driven
/// by the dedicated solver's first input on the model itself, tracking a moving reference).
fn bench_case(
    args: &BenchMpcArgs,
    latent: usize,
    nu: usize,
    horizon: usize,
) -> anyhow::Result<[CaseResult; 2]> {
    let nx = (latent / 17).max(1);
    let seed = args.seed ^ ((latent as u64) << 20) ^ ((nu as u64) << 8) ^ horizon as u64;
    let model = MatrixModel::random_stable(nx, latent, nu, 0.995, seed)?;
    let mut rng = koopman::rng::Rng::new(seed);
    let x0: Vec<f64> = (0..nx).map(|_| rng.uniform(-2.0, 2.0)).collect();
    // Bound calibration: half the largest unconstrained input at the start, so that bounds
    // are active at first and the active set changes along the loop.
    let free_cfg = MpcConfig {
        horizon,
        r: Some(vec![args.r; nu]),
        ..MpcConfig::default()
    };
    let mut free = MpcController::new(&model, &free_cfg)?;
    let u_free = free.solve(&x0, &vec![0.0; nx])?.u;
    let bound = 0.5 * u_free.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-6);
    let cfg = MpcConfig {
        u_min: Some(vec![-bound; nu]),
        u_max: Some(vec![bound; nu]),
        ..free_cfg
    };
    let mut ded = MpcController::new(&model, &cfg)?;
    let mut cla = MpcController::new(
        &model,
        &MpcConfig {
            solver: SolverKind::Clarabel,
            ..cfg.clone()
        },
    )?;
    let phases: Vec<f64> = (0..nx)
        .map(|_| rng.uniform(0.0, std::f64::consts::TAU))
        .collect();
    let (mut t_ded, mut t_cla) = (Vec::new(), Vec::new());
    let (mut it_ded, mut it_cla, mut diff, mut active, mut bad_d, mut bad_c) =
        (0usize, 0usize, 0.0f64, 0usize, 0, 0);
    let mut x = x0;
    let a = model.a();
    let b = model.b();
    for k in 0..args.steps {
        let reference: Vec<f64> = (0..horizon * nx)
            .map(|i| {
                let (tau, j) = (i / nx, i % nx);
                0.5 * (0.05 * (k + tau + 1) as f64 + phases[j]).sin()
            })
            .collect();
        let t0 = Instant::now();
        let sd = ded.solve(&x, &reference)?;
        t_ded.push(t0.elapsed().as_secs_f64());
        let t1 = Instant::now();
        let sc = cla.solve(&x, &reference)?;
        t_cla.push(t1.elapsed().as_secs_f64());
        it_ded += sd.iterations;
        it_cla += sc.iterations;
        bad_d += usize::from(sd.status != SolveStatus::Solved);
        bad_c += usize::from(sc.status != SolveStatus::Solved);
        diff = diff.max(
            sd.u.iter()
                .zip(&sc.u)
                .map(|(p, q)| (p - q).abs())
                .fold(0.0, f64::max),
        );
        active +=
            sd.u.iter()
                .filter(|v| v.abs() >= bound * (1.0 - 1e-12))
                .count();
        // Advance the lifted model with the applied input, then read x = P z.
        let z = model.lift(&x);
        x = (0..nx)
            .map(|i| {
                (0..latent).map(|j| a[(i, j)] * z[j]).sum::<f64>()
                    + (0..nu).map(|j| b[(i, j)] * sd.u[j]).sum::<f64>()
            })
            .collect();
    }
    let n = args.steps.max(1) as f64;
    let (md, mc) = (quantile_ms(&mut t_ded, 0.5), quantile_ms(&mut t_cla, 0.5));
    let mk = |solver, times: &mut Vec<f64>, median, iters: usize, bad, speed| CaseResult {
        solver,
        latent,
        states: nx,
        inputs: nu,
        horizon,
        steps: args.steps,
        median_ms: median,
        p99_ms: quantile_ms(times, 0.99),
        mean_iterations: iters as f64 / n,
        max_abs_input_diff: diff,
        active_fraction: active as f64 / (n * (horizon * nu) as f64),
        speedup_vs_clarabel: speed,
        not_solved: bad,
    };
    Ok([
        mk("dedicated", &mut t_ded, md, it_ded, bad_d, Some(mc / md)),
        mk("clarabel", &mut t_cla, mc, it_cla, bad_c, None),
    ])
}
