//! `koopbridge control`: closed-loop control of a reference system with a lifted model or an
//! NNDM — prints the SPEC metrics, writes them as JSON and draws states, references and inputs.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use koopman::model::bilinear::BilinearModel;
use koopman::model::nndm::NndmModel;
use koopman::model::LiftedModel;
use koopman::mpc::controllers::{self, ControllerKind, ControllerSettings, ModelNeed, Models};
use koopman::mpc::metrics::GoalSpec;
use koopman::mpc::{
    run_closed_loop, ClosedLoopMetrics, OffsetFreeConfig, OffsetMode, OneStepModel, Task, TaskKind,
    Trajectory,
};
use koopman::systems::System;
use koopman::train::stand_in::{self, StandIn, StandInModel};

use super::control_diagnostics::{diagnose, linearised_at};
use super::control_plot::plot_trajectory;
use super::control_table::{print_header, print_row};

/// `--solver`: one controller of the library's factory, or every one the given models allow.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ControllerChoice {
    /// One controller.
    One(ControllerKind),
    /// Every controller the given models allow, one after the other, as one table.
    All,
}

/// The `--solver` values: every controller in report order, then `all`.
const CHOICES: [ControllerChoice; ControllerKind::ALL.len() + 1] = {
    let mut v = [ControllerChoice::All; ControllerKind::ALL.len() + 1];
    let mut i = 0;
    while i < ControllerKind::ALL.len() {
        v[i] = ControllerChoice::One(ControllerKind::ALL[i]);
        i += 1;
    }
    v
};

impl clap::ValueEnum for ControllerChoice {
    fn value_variants<'a>() -> &'a [Self] {
        &CHOICES
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        let (name, help) = match *self {
            ControllerChoice::One(kind) => (kind.name(), solver_help(kind)),
            ControllerChoice::All => (
                "all",
                "Every controller above that the given models allow, one after the other, as one table",
            ),
        };
        Some(clap::builder::PossibleValue::new(name).help(help))
    }
}

impl ControllerChoice {
    /// The library's controller of this choice; `None` for `all`.
    fn kind(self) -> Option<ControllerKind> {
        match self {
            ControllerChoice::One(kind) => Some(kind),
            ControllerChoice::All => None,
        }
    }
}

/// What `--solver KIND` runs, for `--help`.
fn solver_help(kind: ControllerKind) -> &'static str {
    match kind {
        ControllerKind::Dedicated => "Koopman MPC, dedicated box-QP solver (input bounds)",
        ControllerKind::OffsetFree => {
            "Koopman MPC (dedicated solver) with the offset-free correction of --offset-free"
        }
        ControllerKind::Clarabel => "Koopman MPC solved by Clarabel (also rate and state bounds)",
        ControllerKind::ClosedForm => {
            "Unconstrained closed-form MPC, clamped (the reference code's baseline)"
        }
        ControllerKind::Lqr => "LQR on the lifted model with feed-forward, clamped",
        ControllerKind::Shooting => {
            "Random-shooting MPC (1000 samples) on the NNDM (--model of kind nndm, or --nndm)"
        }
        ControllerKind::ShootingOracle => {
            "Random-shooting MPC (1000 samples) on the true system as its own one-step model (oracle)"
        }
        ControllerKind::Bilinear => {
            "Sequential convex MPC on a bilinear model (--model of kind bilinear, or --bilinear DIR)"
        }
        ControllerKind::BilinearOffsetFree => {
            "The bilinear MPC with the offset-free correction of --offset-free near the target"
        }
        ControllerKind::Edmd => "Koopman MPC (dedicated solver) on the EDMD model of --edmd",
        ControllerKind::ZeroInput => "u = 0 throughout: the free response every controller must beat",
    }
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
koopbridge control --model models/damped --env damped-pendulum --solver offset-free --offset-free disturbance\n  \
koopbridge control --model models/damped-linear --bilinear models/damped-bilinear --edmd models/damped-edmd \
--env damped-pendulum --solver all --offset-free integral\n  \
koopbridge control --model models/double-task-linear --bilinear models/double-task-bilinear \
--env double-pendulum --u-bound 40 --q 1,1,0.01,0.01 --solver all   # the ±40 N·m task"
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
    /// Offset-free correction of the MPC near the target (--solver offset-free on a lifted
    /// model, bilinear-offset-free on a bilinear one; with --solver all, a row next to each
    /// plain MPC):
    /// `integral` shifts the reference by the integrated error, `disturbance` adds a low-pass
    /// estimate of the one-step prediction error to the predictions, `trajectory` adds the
    /// filtered error of each τ-step prediction to horizon step τ (the one that regulates the
    /// damped pendulum: use it with --r 0.1).
    #[arg(long, value_enum, value_name = "MODE")]
    pub offset_free: Option<OffsetArg>,
    /// The correction is on while the wrapped error ‖x − r‖ is at most this (default 1.0 for
    /// trajectory, 0.3 otherwise).
    #[arg(long, value_name = "R")]
    pub offset_radius: Option<f64>,
    /// Per-state gains of the correction (nx values; integral: k per step, disturbance and
    /// trajectory: the filter constant in [0, 1]; default 0.5 everywhere for trajectory, else
    /// 0.1 on angles and 0 elsewhere).
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
    #[arg(long, value_enum, default_value_t = ControllerChoice::One(ControllerKind::Dedicated))]
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
    /// Diagonal state weight Q of every planner (nx values, comma separated; SPEC: identity),
    /// e.g. `--q 1,1,0.01,0.01` to weigh the double pendulum's rates less than its angles.
    #[arg(long, value_delimiter = ',', value_name = "Q")]
    pub q: Option<Vec<f64>>,
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
    /// The filtered error of each τ-step prediction added to horizon step τ.
    Trajectory,
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
    let at_hand: Vec<ModelNeed> = [
        lifted_given.then_some(ModelNeed::Lifted),
        (lifted_given && args.offset_free.is_some()).then_some(ModelNeed::LiftedOffsetFree),
        nndm.is_some().then_some(ModelNeed::Nndm),
        bilinear.is_some().then_some(ModelNeed::Bilinear),
        (bilinear.is_some() && args.offset_free.is_some()).then_some(ModelNeed::BilinearOffsetFree),
        edmd.is_some().then_some(ModelNeed::Edmd),
    ]
    .into_iter()
    .flatten()
    .collect();
    let choices = match args.solver.kind() {
        None => ControllerKind::available(&at_hand),
        Some(kind) => match kind.needs() {
            Some(need) if !at_hand.contains(&need) => {
                bail!("{}", missing_model(kind, model_is_nndm))
            }
            _ => vec![kind],
        },
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
    let models = Models {
        system: system.as_ref(),
        lifted: model.as_deref(),
        nndm: nndm.as_ref().map(|m| m as &dyn OneStepModel),
        bilinear: bilinear.as_ref(),
        edmd: edmd.as_deref(),
    };
    let settings = ControllerSettings {
        horizon: args.horizon,
        r: args.r,
        q: args.q.clone(),
        u_min: lo.clone(),
        u_max: hi.clone(),
        offset_free: match args.offset_free {
            Some(mode) => Some(offset_config(mode, &args, system.as_ref())?),
            None => None,
        },
    };
    for choice in choices {
        let run = run_one(choice, models, &settings, &task);
        let (metrics, traj) = match run {
            Ok(r) => r,
            // In a comparison one controller that cannot be built (e.g. LQR on a model with
            // unstabilisable modes) is a row of the report, not the end of it.
            Err(e) if several => {
                eprintln!("{}: failed: {e:#}", choice.name());
                continue;
            }
            Err(e) => return Err(e),
        };
        let stem = choice.name();
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

/// What to give on the command line for the model `kind` plans on (not at hand).
fn missing_model(kind: ControllerKind, model_is_nndm: bool) -> String {
    match kind.needs() {
        Some(ModelNeed::Nndm) => "--solver shooting plans on an NNDM: give --model DIR of kind nndm or \
             --nndm DIR (random shooting on the true system is --solver shooting-oracle)"
            .into(),
        Some(ModelNeed::Bilinear) => "--solver bilinear needs a bilinear model: --model DIR of kind \
             bilinear or --bilinear DIR"
            .into(),
        Some(ModelNeed::BilinearOffsetFree) => "--solver bilinear-offset-free needs a bilinear \
             model (--model DIR of kind bilinear or --bilinear DIR) and --offset-free \
             integral|disturbance"
            .into(),
        Some(ModelNeed::LiftedOffsetFree) => "--solver offset-free needs a lifted model (--model \
             DIR of kind koopman or edmd, --fit or --train) and --offset-free \
             integral|disturbance|trajectory"
            .into(),
        Some(ModelNeed::Edmd) => "--solver edmd needs --edmd DIR (a model of kind edmd)".into(),
        _ => format!(
            "--solver {} needs a lifted model: --model DIR of kind koopman or edmd, --fit or --train{}",
            kind.name(),
            if model_is_nndm {
                " (the given model is an NNDM: use --solver shooting)"
            } else {
                ""
            }
        ),
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
            eprintln!(
                "fitting a stand-in model ({features} random tanh features, {} windows)…",
                stand_in::FIT_WINDOWS
            );
            Ok(stand_in::build(StandIn::Fit { system, features })?.into_lifted())
        }
        (None, None) => {
            bail!("give --model DIR (a trained model) or --fit FEATURES (an in-process stand-in)")
        }
    }
}

/// Trains the `--train` stand-in with a progress bar and saves it under `dir`.
fn train_stand_in(
    system: &dyn System,
    iterations: usize,
    dir: &Path,
) -> anyhow::Result<Box<dyn LiftedModel>> {
    use std::ops::ControlFlow;
    eprintln!(
        "generating {} aligned windows of {} (seed {})…",
        stand_in::TRAIN_WINDOWS + stand_in::VALIDATION_WINDOWS,
        system.name(),
        stand_in::DATA_SEED
    );
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
    let made = stand_in::build(StandIn::Train {
        system,
        iterations,
        observer: &mut observer,
    })?;
    bar.finish_and_clear();
    if let StandInModel::Trained(outcome) = &made {
        eprintln!(
            "trained: best validation prediction error {:?} at iteration {:?}",
            outcome.metrics.best_validation_prediction_error, outcome.metrics.best_iteration
        );
        outcome
            .model
            .save(dir)
            .with_context(|| format!("saving the model to {}", dir.display()))?;
        eprintln!("saved the model to {}", dir.display());
    }
    Ok(made.into_lifted())
}

/// The offset-free settings of `--offset-free`, `--offset-radius`, `--offset-gain`.
fn offset_config(
    mode: OffsetArg,
    args: &ControlArgs,
    system: &dyn System,
) -> anyhow::Result<OffsetFreeConfig> {
    let mode = match mode {
        OffsetArg::Integral => OffsetMode::Integral,
        OffsetArg::Disturbance => OffsetMode::Disturbance,
        OffsetArg::Trajectory => OffsetMode::Trajectory,
    };
    let mut cfg = OffsetFreeConfig::defaults(mode, system.nx(), system.angle_indices());
    if let Some(g) = &args.offset_gain {
        cfg.gain = g.clone();
    }
    if let Some(r) = args.offset_radius {
        cfg.radius = r;
    }
    cfg.check(system.nx())?;
    Ok(cfg)
}

/// Runs one controller of the library's factory in closed loop, with a progress bar.
fn run_one(
    kind: ControllerKind,
    models: Models<'_>,
    settings: &ControllerSettings,
    task: &Task,
) -> anyhow::Result<(ClosedLoopMetrics, Trajectory)> {
    let bar = indicatif::ProgressBar::new(task.steps as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg:>24} [{bar:30}] {pos}/{len} steps {elapsed}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_message(kind.name());
    let progress = |k: usize, _n: usize| bar.set_position(k as u64);
    let mut built = controllers::build(kind, models, settings)?;
    if let Some(w) = &built.warning {
        eprintln!("warning: {w}");
    }
    let (lo, hi) = (&settings.u_min, &settings.u_max);
    let result = run_closed_loop(
        models.system,
        built.policy.as_mut(),
        task,
        lo,
        hi,
        &GoalSpec::default(),
        progress,
    );
    bar.finish_and_clear();
    Ok(result?)
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
