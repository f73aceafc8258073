//! `koopbridge control`: closed-loop control of a reference system with a lifted model or an
//! NNDM — prints the SPEC metrics, writes them as JSON and draws states, references and inputs.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use koopman::model::bilinear::BilinearModel;
use koopman::model::nndm::NndmModel;
use koopman::model::LiftedModel;
use koopman::mpc::metrics::GoalSpec;
use koopman::mpc::{
    run_closed_loop, Action, BilinearMpc, ClosedLoopMetrics, ConstantPolicy, Lqr, LqrPolicy,
    MpcConfig, MpcController, OffsetFreeConfig, OffsetMode, OneStepModel, Policy, RandomShooting,
    ScpOptions, ShootingPolicy, SolverKind, SystemAsModel, Task, TaskKind, Trajectory,
};
use koopman::systems::System;

use super::control_diagnostics::{diagnose, linearised_at};
use super::control_plot::plot_trajectory;

/// Controller choices of `--solver`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum ControllerChoice {
    /// Koopman MPC, dedicated box-QP solver (input bounds).
    Dedicated,
    /// Koopman MPC solved by Clarabel (also rate and state bounds).
    Clarabel,
    /// Unconstrained closed-form MPC, clamped (the reference code's baseline).
    ClosedForm,
    /// LQR on the lifted model with feed-forward, clamped.
    Lqr,
    /// Random-shooting MPC (1000 samples) on the NNDM (--model of kind nndm, or --nndm).
    Shooting,
    /// Random-shooting MPC (1000 samples) on the true system as its own one-step model (oracle).
    ShootingOracle,
    /// Sequential convex MPC on a bilinear model (--model of kind bilinear, or --bilinear DIR).
    Bilinear,
    /// The bilinear MPC with the offset-free correction of --offset-free near the target.
    BilinearOffsetFree,
    /// Koopman MPC (dedicated solver) on the EDMD model of --edmd.
    Edmd,
    /// u = 0 throughout: the free response every controller must beat.
    ZeroInput,
    /// Every controller above that the given models allow, one after the other, as one table.
    All,
}

/// Arguments of `koopbridge control`.
#[derive(clap::Args, Debug)]
#[command(
    about = "Closed-loop control of a reference system with a lifted (Koopman/EDMD) model or an NNDM",
    long_about = "Runs the SPEC control task (regulation: damped pendulum from [-2.5, 0.1] to 0, \
double pendulum from 0 to [1.2, -0.8, 0, 0]; tracking: a smooth sine reference) for 200 steps \
with the chosen controller, prints the metrics (final error with wrapped angles, time to goal, \
tracking RMS/Frobenius, solve time, input-bound violations), writes metrics.json and plot.png \
under --out.\n\nThe lifted-model controllers (dedicated, clarabel, closed-form, lqr) need a Koopman or EDMD \
model; --solver shooting is random-shooting MPC (1000 samples) on an NNDM (--model DIR of kind nndm, or \
--nndm DIR next to a lifted --model); --solver shooting-oracle uses the true system as its model. \
--solver all runs every controller the given models allow.\n\nExamples:\n  koopbridge control --model models/damped --env damped-pendulum --task regulate --solver all\n  \
koopbridge control --model models/damped --nndm models/damped-nndm --env damped-pendulum --solver all\n  \
koopbridge control --model models/damped-nndm --env damped-pendulum --solver shooting\n  \
koopbridge control --model models/damped-linear --bilinear models/damped-bilinear --edmd models/damped-edmd \
--env damped-pendulum --solver all --offset-free integral"
)]
pub struct ControlArgs {
    /// Model directory (config.json with "kind": koopman | edmd | nndm). A lifted model
    /// (koopman, edmd) or --fit/--train is needed for every controller except the shooting ones.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// NNDM model directory (kind nndm) for --solver shooting/all next to a lifted --model.
    #[arg(long, value_name = "DIR")]
    pub nndm: Option<PathBuf>,
    /// Bilinear model directory (kind bilinear) for --solver bilinear/all next to --model.
    #[arg(long, value_name = "DIR")]
    pub bilinear: Option<PathBuf>,
    /// EDMD model directory (kind edmd) for --solver edmd/all next to --model: one more row,
    /// the Koopman MPC (dedicated solver) on it.
    #[arg(long, value_name = "DIR")]
    pub edmd: Option<PathBuf>,
    /// Offset-free correction of the bilinear MPC near the target (--solver
    /// bilinear-offset-free; with --solver all, a row next to the plain bilinear MPC):
    /// `integral` shifts the reference by the integrated error, `disturbance` adds a low-pass
    /// estimate of the one-step prediction error to the predictions.
    #[arg(long, value_enum, value_name = "MODE")]
    pub offset_free: Option<OffsetArg>,
    /// The correction is on while the wrapped error ‖x − r‖ is at most this.
    #[arg(long, default_value_t = 0.3, value_name = "R")]
    pub offset_radius: f64,
    /// Per-state gains of the correction (nx values; integral: k per step, disturbance: the
    /// filter constant in [0, 1]; default 0.1 on angles, 0 elsewhere).
    #[arg(long, value_delimiter = ',', value_name = "G")]
    pub offset_gain: Option<Vec<f64>>,
    /// Fit an in-process stand-in model instead (least squares on random tanh features, this
    /// many features, 2000 windows of aligned data, seed 42).
    #[arg(long, value_name = "FEATURES", conflicts_with = "model")]
    pub fit: Option<usize>,
    /// Train a neural Koopman model in-process instead (SPEC settings except this many
    /// iterations, 16000 aligned training windows, 2000 validation windows, data seed 42) and
    /// save it under OUT/model: a quick stand-in when no trained model exists yet.
    #[arg(long, value_name = "ITERATIONS", conflicts_with_all = ["model", "fit"])]
    pub train: Option<usize>,
    /// Environment: damped-pendulum or double-pendulum.
    #[arg(long)]
    pub env: String,
    /// Task.
    #[arg(long, value_enum, default_value_t = TaskArg::Regulate)]
    pub task: TaskArg,
    /// Controller.
    #[arg(long, value_enum, default_value_t = ControllerChoice::Dedicated)]
    pub solver: ControllerChoice,
    /// MPC horizon H (SPEC: 15).
    #[arg(long, default_value_t = 15)]
    pub horizon: usize,
    /// Control steps (SPEC: 200).
    #[arg(long, default_value_t = 200)]
    pub steps: usize,
    /// Diagonal input weight R (SPEC: 0; LQR uses max(R, 1e-6)).
    #[arg(long, default_value_t = 0.0)]
    pub r: f64,
    /// Initial state overriding the task's (comma separated, nx values), e.g. `-1.0,0.1`.
    #[arg(
        long,
        value_delimiter = ',',
        allow_hyphen_values = true,
        value_name = "X0"
    )]
    pub x0: Option<Vec<f64>>,
    /// Symmetric input bound |u| ≤ B overriding the system's data-collection bounds.
    #[arg(long, value_name = "B")]
    pub u_bound: Option<f64>,
    /// Output directory for metrics.json and plot.png (default results/control/ENV-TASK).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print the metrics as one JSON object per controller instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// `--offset-free` values.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum OffsetArg {
    /// Integral action on the tracking error.
    Integral,
    /// Constant disturbance estimate from the one-step prediction error.
    Disturbance,
}

/// `--task` values.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum TaskArg {
    /// Reach the SPEC target and hold it.
    Regulate,
    /// Follow a smooth reference.
    Track,
}

/// Runs `koopbridge control`.
pub fn run(args: ControlArgs) -> anyhow::Result<()> {
    let system = koopman::systems::by_name(&args.env)?;
    if system.nu() == 0 {
        bail!("{} has no inputs: nothing to control", system.name());
    }
    let task_name = match args.task {
        TaskArg::Regulate => "regulate",
        TaskArg::Track => "track",
    };
    let out = args.out.clone().unwrap_or_else(|| {
        PathBuf::from("results/control").join(format!("{}-{task_name}", system.name()))
    });
    let model_kind = match &args.model {
        Some(dir) => Some(koopman::model::store::read_kind(dir)?),
        None => None,
    };
    let model_is_nndm = model_kind.as_deref() == Some("nndm");
    let model_is_bilinear = model_kind.as_deref() == Some("bilinear");
    let bilinear = extra_model(
        model_is_bilinear,
        &args.model,
        &args.bilinear,
        ("a", "bilinear model", "--bilinear"),
        BilinearModel::load,
    )?;
    let nndm = extra_model(
        model_is_nndm,
        &args.model,
        &args.nndm,
        ("an", "NNDM", "--nndm"),
        NndmModel::load,
    )?;
    let edmd = match &args.edmd {
        Some(dir) => {
            let kind = koopman::model::store::read_kind(dir)?;
            if kind != "edmd" {
                bail!(
                    "--edmd {} is a model of kind {kind}, not edmd",
                    dir.display()
                );
            }
            Some(
                koopman::model::load_lifted(dir)
                    .with_context(|| format!("loading the EDMD model in {}", dir.display()))?,
            )
        }
        None => None,
    };
    let lifted_given = !model_is_nndm
        && !model_is_bilinear
        && (args.model.is_some() || args.fit.is_some() || args.train.is_some());
    let choices = match args.solver {
        ControllerChoice::All => {
            let mut c = Vec::new();
            if lifted_given {
                c.extend([
                    ControllerChoice::Dedicated,
                    ControllerChoice::Clarabel,
                    ControllerChoice::ClosedForm,
                    ControllerChoice::Lqr,
                ]);
            }
            if bilinear.is_some() {
                c.insert(0, ControllerChoice::Bilinear);
                if args.offset_free.is_some() {
                    c.insert(0, ControllerChoice::BilinearOffsetFree);
                }
            }
            if edmd.is_some() {
                c.push(ControllerChoice::Edmd);
            }
            c.push(ControllerChoice::ShootingOracle);
            if nndm.is_some() {
                c.push(ControllerChoice::Shooting);
            }
            c.push(ControllerChoice::ZeroInput);
            c
        }
        ControllerChoice::Shooting if nndm.is_none() => bail!(
            "--solver shooting plans on an NNDM: give --model DIR of kind nndm or --nndm DIR \
             (random shooting on the true system is --solver shooting-oracle)"
        ),
        ControllerChoice::Bilinear | ControllerChoice::BilinearOffsetFree
            if bilinear.is_none() =>
        {
            bail!(
                "--solver {} needs a bilinear model: --model DIR of kind bilinear or --bilinear DIR",
                controller_stem(args.solver)
            )
        }
        ControllerChoice::BilinearOffsetFree if args.offset_free.is_none() => bail!(
            "--solver bilinear-offset-free needs --offset-free integral|disturbance"
        ),
        ControllerChoice::Edmd if edmd.is_none() => {
            bail!("--solver edmd needs --edmd DIR (a model of kind edmd)")
        }
        ControllerChoice::ShootingOracle
        | ControllerChoice::Shooting
        | ControllerChoice::Bilinear
        | ControllerChoice::BilinearOffsetFree
        | ControllerChoice::Edmd
        | ControllerChoice::ZeroInput => vec![args.solver],
        c if !lifted_given => bail!(
            "--solver {} needs a lifted model: --model DIR of kind koopman or edmd, --fit or --train{}",
            controller_stem(c),
            if model_is_nndm {
                " (the given model is an NNDM: use --solver shooting)"
            } else {
                ""
            }
        ),
        c => vec![c],
    };
    let model = if lifted_given {
        Some(load_model(&args, system.as_ref(), &out)?)
    } else {
        None
    };
    let dims = [
        model.as_ref().map(|m| ("model", m.nx(), m.nu())),
        nndm.as_ref().map(|m| ("NNDM", m.arch().nx, m.arch().nu)),
        bilinear
            .as_ref()
            .map(|m| ("bilinear model", m.nx(), m.nu())),
        edmd.as_ref().map(|m| ("EDMD model", m.nx(), m.nu())),
    ];
    for (what, nx, nu) in dims.into_iter().flatten() {
        if nx != system.nx() || nu != system.nu() {
            bail!(
                "{what} has nx = {nx}, nu = {nu} but {} has nx = {}, nu = {}",
                system.name(),
                system.nx(),
                system.nu()
            );
        }
    }
    let kind = match args.task {
        TaskArg::Regulate => TaskKind::Regulate,
        TaskArg::Track => TaskKind::Track,
    };
    let mut task = Task::standard(system.as_ref(), kind)?;
    task.steps = args.steps;
    if let Some(x0) = &args.x0 {
        if x0.len() != system.nx() || x0.iter().any(|v| !v.is_finite()) {
            bail!(
                "--x0 needs {} finite values for {}, got {x0:?}",
                system.nx(),
                system.name()
            );
        }
        task.x0 = x0.clone();
    }
    let (lo, hi) = match args.u_bound {
        Some(b) if b.is_finite() && b > 0.0 => (vec![-b; system.nu()], vec![b; system.nu()]),
        Some(b) => bail!("--u-bound must be a positive number, got {b}"),
        None => system.input_bounds(),
    };
    let target = task.reference(task.steps);
    // Without a linear model, the bilinear one linearised at the target is diagnosed.
    let at_target = match (&model, &bilinear) {
        (None, Some(b)) => Some(linearised_at(system.as_ref(), b, &target, &lo, &hi)?),
        _ => None,
    };
    let diagnostics = diagnose(
        system.as_ref(),
        model
            .as_deref()
            .or(at_target.as_ref().map(|m| m as &dyn LiftedModel)),
        &task.reference(task.steps),
        kind == TaskKind::Regulate,
        (&lo, &hi),
        args.horizon,
    );
    diagnostics.print();
    write_json_atomic(&out.join("diagnostics.json"), &diagnostics)?;
    let mut all = Vec::new();
    if !args.json {
        print_header();
    }
    let several = choices.len() > 1;
    for choice in choices {
        let run = run_one(
            &args,
            choice,
            system.as_ref(),
            Models {
                lifted: model.as_deref(),
                nndm: nndm.as_ref().map(|m| m as &dyn OneStepModel),
                bilinear: bilinear.as_ref(),
                edmd: edmd.as_deref(),
            },
            &task,
            &lo,
            &hi,
        );
        let (metrics, traj) = match run {
            Ok(r) => r,
            // In a comparison one controller that cannot be built (e.g. LQR on a model with
            // unstabilisable modes) is a row of the report, not the end of it.
            Err(e) if several => {
                eprintln!("{}: failed: {e:#}", controller_stem(choice));
                continue;
            }
            Err(e) => return Err(e),
        };
        let stem = controller_stem(choice);
        write_json_atomic(&out.join(format!("metrics-{stem}.json")), &metrics)?;
        let png = out.join(format!("plot-{stem}.png"));
        plot_trajectory(&png, system.as_ref(), &metrics, &traj, &lo, &hi)?;
        if args.json {
            println!("{}", serde_json::to_string(&metrics)?);
        } else {
            print_row(&metrics);
        }
        all.push(metrics);
    }
    write_json_atomic(&out.join("metrics.json"), &all)?;
    if !args.json {
        eprintln!("wrote {}/metrics.json and plot-*.png", out.display());
    }
    Ok(())
}

fn controller_stem(c: ControllerChoice) -> &'static str {
    match c {
        ControllerChoice::Dedicated => "dedicated",
        ControllerChoice::Clarabel => "clarabel",
        ControllerChoice::ClosedForm => "closed-form",
        ControllerChoice::Lqr => "lqr",
        ControllerChoice::Shooting => "shooting",
        ControllerChoice::ShootingOracle => "shooting-oracle",
        ControllerChoice::Bilinear => "bilinear",
        ControllerChoice::BilinearOffsetFree => "bilinear-offset-free",
        ControllerChoice::Edmd => "edmd",
        ControllerChoice::ZeroInput => "zero-input",
        ControllerChoice::All => "all",
    }
}

fn load_model(
    args: &ControlArgs,
    system: &dyn System,
    out: &Path,
) -> anyhow::Result<Box<dyn LiftedModel>> {
    if let Some(iterations) = args.train {
        return train_stand_in(system, iterations, &out.join("model"));
    }
    match (&args.model, args.fit) {
        (Some(dir), _) => koopman::model::load_lifted(dir)
            .with_context(|| format!("loading the model in {}", dir.display())),
        (None, Some(features)) => {
            eprintln!("fitting a stand-in model ({features} random tanh features, 2000 windows)…");
            let data = koopman::data::generate(
                system,
                2000,
                system.window_steps(),
                42,
                koopman::data::Pairing::Aligned,
            )?;
            Ok(Box::new(koopman::mpc::fit::fit_random_features(
                &data, features, 1e-8, 1,
            )?))
        }
        (None, None) => {
            bail!("give --model DIR (a trained model) or --fit FEATURES (an in-process stand-in)")
        }
    }
}

fn train_stand_in(
    system: &dyn System,
    iterations: usize,
    dir: &Path,
) -> anyhow::Result<Box<dyn LiftedModel>> {
    use std::ops::ControlFlow;
    eprintln!(
        "generating 18000 aligned windows of {} (seed 42)…",
        system.name()
    );
    let data = koopman::data::generate(
        system,
        18_000,
        system.window_steps(),
        42,
        koopman::data::Pairing::Aligned,
    )?;
    let train = data.head(16_000)?;
    let val = data.select(&(16_000..18_000).collect::<Vec<_>>())?;
    let cfg = koopman::train::TrainConfig {
        iterations,
        validate_every: (iterations / 5).max(1),
        ..koopman::train::TrainConfig::default()
    };
    let bar = indicatif::ProgressBar::new(iterations as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "training [{bar:30}] {pos}/{len} it {per_sec} {msg}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let mut observer = |p: &koopman::train::Progress| {
        bar.set_position(p.iteration as u64);
        if let Some(v) = p.validation {
            bar.set_message(format!("val {v:.4}"));
        }
        ControlFlow::Continue(())
    };
    let outcome = koopman::train::train(&cfg, &train, &val, None, &mut observer)?;
    bar.finish_and_clear();
    eprintln!(
        "trained: best validation prediction error {:?} at iteration {:?}",
        outcome.metrics.best_validation_prediction_error, outcome.metrics.best_iteration
    );
    outcome
        .model
        .save(dir)
        .with_context(|| format!("saving the model to {}", dir.display()))?;
    eprintln!("saved the model to {}", dir.display());
    Ok(Box::new(outcome.model))
}

/// The models a controller may plan on: a lifted model (Koopman MPC, LQR), an NNDM (random
/// shooting), a bilinear model (sequential convex MPC) and an EDMD model (Koopman MPC).
#[derive(Clone, Copy)]
struct Models<'m> {
    lifted: Option<&'m dyn LiftedModel>,
    nndm: Option<&'m dyn OneStepModel>,
    bilinear: Option<&'m BilinearModel>,
    edmd: Option<&'m dyn LiftedModel>,
}

fn run_one(
    args: &ControlArgs,
    choice: ControllerChoice,
    system: &dyn System,
    models: Models<'_>,
    task: &Task,
    lo: &[f64],
    hi: &[f64],
) -> anyhow::Result<(ClosedLoopMetrics, Trajectory)> {
    let Models {
        lifted: model,
        nndm,
        bilinear,
        edmd,
    } = models;
    let lifted = || model.context("this controller needs a lifted model (koopman or edmd)");
    let nu = system.nu();
    let bar = indicatif::ProgressBar::new(task.steps as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg:>24} [{bar:30}] {pos}/{len} steps {elapsed}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_message(controller_stem(choice));
    let progress = |k: usize, _n: usize| bar.set_position(k as u64);
    let goal = GoalSpec::default();
    let oracle = SystemAsModel(system);
    let mut policy: Box<dyn Policy + '_> = match choice {
        ControllerChoice::Edmd => {
            let cfg = MpcConfig {
                horizon: args.horizon,
                r: Some(vec![args.r; nu]),
                ..MpcConfig::with_bounds(lo.to_vec(), hi.to_vec())
            };
            let model = edmd.context("--solver edmd needs --edmd DIR")?;
            Box::new(Named(
                MpcController::new(model, &cfg)?,
                "edmd-mpc/dedicated",
            ))
        }
        ControllerChoice::Dedicated | ControllerChoice::Clarabel | ControllerChoice::ClosedForm => {
            let solver = match choice {
                ControllerChoice::Dedicated => SolverKind::Dedicated,
                ControllerChoice::Clarabel => SolverKind::Clarabel,
                _ => SolverKind::ClosedForm,
            };
            let cfg = MpcConfig {
                horizon: args.horizon,
                r: Some(vec![args.r; nu]),
                solver,
                ..MpcConfig::with_bounds(lo.to_vec(), hi.to_vec())
            };
            Box::new(MpcController::new(lifted()?, &cfg)?)
        }
        ControllerChoice::Lqr => {
            let model = lifted()?;
            let lqr = Lqr::new(
                model,
                &vec![1.0; system.nx()],
                &vec![args.r.max(1e-6); nu],
                20_000,
                1e-10,
            )?;
            if !lqr.converged {
                eprintln!(
                    "warning: the Riccati iteration did not converge in {} iterations",
                    lqr.iterations
                );
            }
            Box::new(LqrPolicy::new(lqr, model, lo.to_vec(), hi.to_vec())?)
        }
        ControllerChoice::Shooting | ControllerChoice::ShootingOracle => {
            let planner = RandomShooting::new(
                1000,
                args.horizon,
                vec![1.0; system.nx()],
                lo.to_vec(),
                hi.to_vec(),
                1,
            )?;
            if choice == ControllerChoice::Shooting {
                let nndm = nndm.context("--solver shooting needs an NNDM model")?;
                Box::new(ShootingPolicy::new(planner, nndm, "nndm"))
            } else {
                Box::new(ShootingPolicy::new(planner, &oracle, "true-system"))
            }
        }
        ControllerChoice::Bilinear | ControllerChoice::BilinearOffsetFree => {
            let cfg = MpcConfig {
                horizon: args.horizon,
                r: Some(vec![args.r; nu]),
                ..MpcConfig::with_bounds(lo.to_vec(), hi.to_vec())
            };
            let model = bilinear.context("--solver bilinear needs a bilinear model")?;
            let mut mpc = BilinearMpc::new(model, &cfg, ScpOptions::default())?;
            if choice == ControllerChoice::BilinearOffsetFree {
                mpc.set_offset_free(Some(offset_config(args, system)?))?;
            }
            Box::new(mpc)
        }
        ControllerChoice::ZeroInput => Box::new(ConstantPolicy::zero(nu)),
        ControllerChoice::All => unreachable!("expanded by the caller"),
    };
    let result = run_closed_loop(system, policy.as_mut(), task, lo, hi, &goal, progress);
    bar.finish_and_clear();
    Ok(result?)
}

/// The offset-free settings of `--offset-free`, `--offset-radius`, `--offset-gain`.
fn offset_config(args: &ControlArgs, system: &dyn System) -> anyhow::Result<OffsetFreeConfig> {
    let mode = match args.offset_free {
        Some(OffsetArg::Integral) => OffsetMode::Integral,
        Some(OffsetArg::Disturbance) => OffsetMode::Disturbance,
        None => bail!("--offset-free integral|disturbance is needed"),
    };
    let angles = system.angle_indices();
    let gain = args.offset_gain.clone().unwrap_or_else(|| {
        (0..system.nx())
            .map(|i| if angles.contains(&i) { 0.1 } else { 0.0 })
            .collect()
    });
    let cfg = OffsetFreeConfig {
        mode,
        radius: args.offset_radius,
        gain,
        angles,
    };
    cfg.check(system.nx())?;
    Ok(cfg)
}

/// A policy under another name in reports.
struct Named<P>(P, &'static str);

impl<P: Policy> Policy for Named<P> {
    fn name(&self) -> String {
        self.1.into()
    }
    fn horizon(&self) -> usize {
        self.0.horizon()
    }
    fn act(&mut self, x: &[f64], current: &[f64], future: &[f64]) -> koopman::Result<Action> {
        self.0.act(x, current, future)
    }
}

fn print_header() {
    println!(
        "{:<26} {:>9} {:>9} {:>8} {:>10} {:>10} {:>9} {:>9} {:>6} {:>5}",
        "controller",
        "final err",
        "angle err",
        "t_goal",
        "track rms",
        "frobenius",
        "med ms",
        "p99 ms",
        "viol",
        "fb"
    );
}

fn print_row(m: &ClosedLoopMetrics) {
    println!(
        "{:<26} {:>9.4} {:>9.4} {:>8} {:>10.4} {:>10.3} {:>9.3} {:>9.3} {:>6} {:>5}{}",
        m.controller,
        m.final_error,
        m.final_angle_error,
        m.time_to_goal_s
            .map(|s| format!("{s:.2}s"))
            .unwrap_or_else(|| "never".into()),
        m.tracking_rms,
        m.tracking_frobenius,
        m.solve_ms_median,
        m.solve_ms_p99,
        m.input_violations,
        m.fallbacks,
        if m.diverged { "  DIVERGED" } else { "" }
    );
}

/// Writes JSON atomically (see [`koopman::fsutil::write_atomic`]).
fn write_json_atomic<T: serde::Serialize>(path: &Path, value: &T) -> anyhow::Result<()> {
    Ok(koopman::fsutil::write_atomic(
        path,
        &serde_json::to_vec_pretty(value)?,
    )?)
}

/// Loads the optional extra model of one kind: `--model` itself when `model_is_kind` (then its
/// own flag must be absent), else the folder given with that flag. `(article, name, flag)` name
/// the kind in errors.
fn extra_model<M>(
    model_is_kind: bool,
    model: &Option<PathBuf>,
    given: &Option<PathBuf>,
    (article, name, flag): (&str, &str, &str),
    load: impl FnOnce(&Path) -> koopman::Result<M>,
) -> anyhow::Result<Option<M>> {
    let dir = match (model_is_kind, given) {
        (true, Some(_)) => bail!("--model is already {article} {name}: leave out {flag}"),
        (true, None) => model.clone(),
        (false, dir) => dir.clone(),
    };
    dir.map(|dir| load(&dir).with_context(|| format!("loading the {name} in {}", dir.display())))
        .transpose()
}
