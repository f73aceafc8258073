//! `koopbridge bench mpc`: solve times of the dedicated box-QP solver and Clarabel on random
//! stable lifted models along receding-horizon closed loops, with the inputs compared per step;
//! `--dump-qps` records each loop's QP sequence for an external solver to replay.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use koopman::model::matrix::MatrixModel;
use koopman::model::LiftedModel;
use koopman::mpc::boxqp::{BoxQp, WarmStart};
use koopman::mpc::{MpcConfig, MpcController, QpSolver, QpStatus, SolveStatus, SolverKind};
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
    /// Diagonal input weight R (R = 0 makes H singular when H·nu > H·nx; see docs/log/2026-11.md, "MPC").
    #[arg(long, default_value_t = 1e-3)]
    pub r: f64,
    /// Random seed of the models and initial states.
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// One JSON object per line instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Skip Clarabel (only the dedicated solver's lines; no agreement column).
    #[arg(long)]
    pub no_clarabel: bool,
    /// Write each case's QP sequence to DIR/qp_N<N>_nu<nu>_H<H>.npz: `P` [n, n], `q` [S, n],
    /// `lower`, `upper` [n], the dedicated solver's plans `u` [S, n], its QP times `time_ns` [S]
    /// and whole-step times `step_ns` [S] (the format of an external QP anchor script).
    #[arg(long, value_name = "DIR")]
    pub dump_qps: Option<PathBuf>,
    /// Also time the error-state MPC (`solve_about_plan`, dedicated solver) on the same states,
    /// about a plan whose state is the reference's first row and whose feed-forward is the
    /// dedicated solver's plan of the step: an `error-state` line per case, `vs_dedicated` its
    /// median over the plain solve's (same run).
    #[arg(long)]
    pub error_state: bool,
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
    /// Whole step (lift, q, QP).
    median_ms: f64,
    p99_ms: f64,
    /// The QP alone (dedicated solver's line only).
    #[serde(skip_serializing_if = "Option::is_none")]
    qp_median_ms: Option<f64>,
    /// The same QP sequence (`P`, `q` per step) replayed through a fresh dedicated solver
    /// after the loop, warm-started from its previous working set, five passes: timed as an
    /// external anchor times its solver (no lift or linear term in between), `u*` included.
    #[serde(skip_serializing_if = "Option::is_none")]
    qp_replay_median_ms: Option<f64>,
    /// Largest |Δu| between the replayed plans and the loop's.
    #[serde(skip_serializing_if = "Option::is_none")]
    replay_max_abs_diff: Option<f64>,
    /// Replayed solves (all passes) that did not end `Solved` (e.g. the iteration limit on the
    /// first, cold solve; the loop's own count is `not_solved`).
    #[serde(skip_serializing_if = "Option::is_none")]
    replay_not_solved: Option<usize>,
    mean_iterations: f64,
    /// Largest |u_dedicated − u_clarabel| over all steps and plan entries.
    max_abs_input_diff: f64,
    /// Fraction of plan entries on a bound (dedicated solver).
    active_fraction: f64,
    /// Clarabel median / dedicated median, on the dedicated line.
    #[serde(skip_serializing_if = "Option::is_none")]
    speedup_vs_clarabel: Option<f64>,
    /// This line's median / the dedicated line's (the error-state line).
    #[serde(skip_serializing_if = "Option::is_none")]
    vs_dedicated: Option<f64>,
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
    if let Some(dir) = &args.dump_qps {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    if !args.json {
        println!(
            "{:>10} {:>5} {:>3} {:>3} {:>3} {:>10} {:>10} {:>10} {:>6} {:>10} {:>7} {:>8}",
            "solver",
            "N",
            "nx",
            "nu",
            "H",
            "median ms",
            "p99 ms",
            "QP ms",
            "iters",
            "max|Δu|",
            "active",
            "ratio"
        );
    }
    for &latent in &args.latent {
        for &nu in &args.inputs {
            for &h in &args.horizon {
                let lines = bench_case(&args, latent, nu, h)
                    .with_context(|| format!("case N={latent} nu={nu} H={h}"))?;
                for c in &lines {
                    if args.json {
                        println!("{}", serde_json::to_string(c)?);
                    } else {
                        println!(
                            "{:>10} {:>5} {:>3} {:>3} {:>3} {:>10.4} {:>10.4} {:>10} {:>6.1} {:>10.2e} {:>7.2} {:>8}",
                            c.solver,
                            c.latent,
                            c.states,
                            c.inputs,
                            c.horizon,
                            c.median_ms,
                            c.p99_ms,
                            c.qp_median_ms.map(|t| format!("{t:.4}")).unwrap_or_default(),
                            c.mean_iterations,
                            c.max_abs_input_diff,
                            c.active_fraction,
                            c.speedup_vs_clarabel
                                .or(c.vs_dedicated)
                                .map(|s| format!("{s:.2}x"))
                                .unwrap_or_default()
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

/// The QP sequence of one case, as `--dump-qps` writes it.
struct QpRecord {
    n: usize,
    hessian: Vec<f64>,
    bound: f64,
    q: Vec<f64>,
    u: Vec<f64>,
    time_ns: Vec<f64>,
    step_ns: Vec<f64>,
}

impl QpRecord {
    fn write(&self, path: &Path) -> anyhow::Result<()> {
        use koopman::data::npy::encode;
        let (n, steps) = (self.n, self.time_ns.len());
        let p = encode(&[n, n], &self.hessian);
        let q = encode(&[steps, n], &self.q);
        let lower = encode(&[n], &vec![-self.bound; n]);
        let upper = encode(&[n], &vec![self.bound; n]);
        let u = encode(&[steps, n], &self.u);
        let t = encode(&[steps], &self.time_ns);
        let st = encode(&[steps], &self.step_ns);
        koopman::data::npz::write_npz(
            path,
            &[
                ("P.npy", &p),
                ("q.npy", &q),
                ("lower.npy", &lower),
                ("upper.npy", &upper),
                ("u.npy", &u),
                ("time_ns.npy", &t),
                ("step_ns.npy", &st),
            ],
        )?;
        Ok(())
    }
}

/// Replays a recorded QP sequence through fresh dedicated solvers (five passes, warm-started
/// as the controller's is): the median solve time in ms, the largest |Δu| to the loop's plans and
/// the number of solves that did not end `Solved`.
fn replay(r: &QpRecord, ctl: &MpcController<'_>) -> anyhow::Result<(f64, f64, usize)> {
    let (n, cfg) = (r.n, ctl.config());
    let h = ctl.condensed().hessian.as_ref();
    let (lo, hi) = (vec![-r.bound; n], vec![r.bound; n]);
    let (mut times, mut diff, mut bad) = (Vec::new(), 0.0f64, 0);
    let mut u = vec![0.0; n];
    for _ in 0..5 {
        // As the controller's first solve: from the zero plan, no previous working set.
        u.fill(0.0);
        let mut s = BoxQp::new(h, &lo, &hi, cfg.max_iterations, cfg.time_limit)?;
        s.set_warm_start(WarmStart::Previous);
        for (q, want) in r.q.chunks_exact(n).zip(r.u.chunks_exact(n)) {
            let t = Instant::now();
            let out = s.solve(q, &[], &mut u);
            times.push(t.elapsed().as_secs_f64());
            bad += usize::from(out.status != QpStatus::Solved);
            diff = u
                .iter()
                .zip(want)
                .fold(diff, |m, (a, b)| m.max((a - b).abs()));
        }
    }
    Ok((quantile_ms(&mut times, 0.5), diff, bad))
}

/// Runs one case: both controllers see the same sequence of states (the closed loop driven
/// by the dedicated solver's first input on the model itself, tracking a moving reference).
fn bench_case(
    args: &BenchMpcArgs,
    latent: usize,
    nu: usize,
    horizon: usize,
) -> anyhow::Result<Vec<CaseResult>> {
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
    let mut es = if args.error_state {
        Some(MpcController::new(&model, &cfg)?)
    } else {
        None
    };
    let mut cla = if args.no_clarabel {
        None
    } else {
        Some(MpcController::new(
            &model,
            &MpcConfig {
                solver: SolverKind::Clarabel,
                ..cfg.clone()
            },
        )?)
    };
    let nv = horizon * nu;
    // The QP sequence, kept for the replay (and written with --dump-qps).
    let mut record = {
        let h = &ded.condensed().hessian;
        QpRecord {
            n: nv,
            hessian: (0..nv * nv).map(|k| h[(k / nv, k % nv)]).collect(),
            bound,
            q: Vec::with_capacity(args.steps * nv),
            u: Vec::with_capacity(args.steps * nv),
            time_ns: Vec::with_capacity(args.steps),
            step_ns: Vec::with_capacity(args.steps),
        }
    };
    let phases: Vec<f64> = (0..nx)
        .map(|_| rng.uniform(0.0, std::f64::consts::TAU))
        .collect();
    let (mut t_ded, mut t_qp, mut t_cla, mut t_es) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let (mut it_es, mut bad_e) = (0usize, 0usize);
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
        t_qp.push(sd.qp_time.as_secs_f64());
        record.q.extend_from_slice(ded.linear_term());
        record.u.extend_from_slice(&sd.u);
        record.time_ns.push(sd.qp_time.as_secs_f64() * 1e9);
        record.step_ns.push(sd.solve_time.as_secs_f64() * 1e9);
        it_ded += sd.iterations;
        bad_d += usize::from(sd.status != SolveStatus::Solved);
        if let Some(es) = es.as_mut() {
            let t1 = Instant::now();
            let se = es.solve_about_plan(&x, &reference[..nx], &sd.u)?;
            t_es.push(t1.elapsed().as_secs_f64());
            it_es += se.iterations;
            bad_e += usize::from(se.status != SolveStatus::Solved);
        }
        if let Some(cla) = cla.as_mut() {
            let t1 = Instant::now();
            let sc = cla.solve(&x, &reference)?;
            t_cla.push(t1.elapsed().as_secs_f64());
            it_cla += sc.iterations;
            bad_c += usize::from(sc.status != SolveStatus::Solved);
            diff = diff.max(
                sd.u.iter()
                    .zip(&sc.u)
                    .map(|(p, q)| (p - q).abs())
                    .fold(0.0, f64::max),
            );
        }
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
    if let Some(dir) = &args.dump_qps {
        let path = dir.join(format!("qp_N{latent}_nu{nu}_H{horizon}.npz"));
        record
            .write(&path)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    let (replay_ms, replay_diff, replay_bad) = replay(&record, &ded)?;
    let n = args.steps.max(1) as f64;
    let md = quantile_ms(&mut t_ded, 0.5);
    let mc = (!t_cla.is_empty()).then(|| quantile_ms(&mut t_cla, 0.5));
    let diff = if cla.is_some() { diff } else { f64::NAN };
    let mk = |solver, times: &mut Vec<f64>, median, qp, iters: usize, bad, speed| CaseResult {
        solver,
        latent,
        states: nx,
        inputs: nu,
        horizon,
        steps: args.steps,
        median_ms: median,
        p99_ms: quantile_ms(times, 0.99),
        qp_median_ms: qp,
        qp_replay_median_ms: qp.map(|_| replay_ms),
        replay_max_abs_diff: qp.map(|_| replay_diff),
        replay_not_solved: qp.map(|_| replay_bad),
        mean_iterations: iters as f64 / n,
        max_abs_input_diff: diff,
        active_fraction: active as f64 / (n * nv as f64),
        speedup_vs_clarabel: speed,
        vs_dedicated: None,
        not_solved: bad,
    };
    let qp = Some(quantile_ms(&mut t_qp, 0.5));
    let mut lines = vec![mk(
        "dedicated",
        &mut t_ded,
        md,
        qp,
        it_ded,
        bad_d,
        mc.map(|c| c / md),
    )];
    if let Some(mc) = mc {
        lines.push(mk("clarabel", &mut t_cla, mc, None, it_cla, bad_c, None));
    }
    if !t_es.is_empty() {
        let me = quantile_ms(&mut t_es, 0.5);
        let mut line = mk("error-st", &mut t_es, me, None, it_es, bad_e, None);
        line.vs_dedicated = Some(me / md);
        lines.push(line);
    }
    Ok(lines)
}
