//! `koopbridge run SCENARIO.toml`: starts the scenario's simulators and services over Zenoh,
//! collects data in lockstep, trains through the trainer service, controls through the MPC
//! service and writes `results/{scenario}/report.json` (plus plots).

use std::path::PathBuf;
use std::time::Duration;

use bridge::orchestrator::control_summary::time_to_goal_text;
use bridge::orchestrator::viewer::{ViewMode, ViewOptions};
use bridge::orchestrator::{run_scenario_with, Event, RunExtras, RunOptions};
use bridge::scenario::Scenario;

/// Arguments of `koopbridge run`.
#[derive(clap::Args)]
#[command(
    after_help = "Example:\n  koopbridge run scenarios/damped-pendulum.toml\n\n\
    Nothing has to be started by hand: the simulators (`koopbridge sim`) and services\n\
    (`koopbridge serve`) are started from this executable, connect to this process on a free\n\
    loopback port, and exit with it. Logs: results/{scenario}/logs/.\n\n\
    The whole scenario ([train].config, [control].mpc, x0 and reference lengths) is checked\n\
    against the simulators' info before collection. A simulator that dies ends the run at once,\n\
    naming it. Running the same scenario again into the same output folder needs no cleaning:\n\
    data and models whose sections are unchanged are reused (and it says so), and an\n\
    interrupted training resumes from its checkpoint (results/{scenario}/state/trainer/jobs/).\n\
    External simulator commands run in the repository of the scenario file.\n\n\
    [train] model = [\"koopman\", \"edmd\"] (kinds: koopman, bilinear, edmd, nndm) trains one model\n\
    of each kind per simulator and controls with each; the models are printed side by side\n\
    (test prediction error, final error, tracking RMS, time to goal; report.json's `models`).\n\n\
    Warnings (on stderr, and in report.json's `warnings`): an MPC that did not solve every\n\
    step (`not_solved`, by status: suboptimal, inaccurate, fallback), an aggregation round that\n\
    made control worse. They do not change the exit code unless --fail-on-warning is given."
)]
pub struct RunArgs {
    /// The scenario file (TOML, see scenarios/).
    pub scenario: PathBuf,
    /// Use the scenario's `[full]` budget (the SPEC settings: its windows, `train_config` and,
    /// where it has them, the `control_defaults` for the larger model; hours on 2 cores).
    #[arg(long)]
    pub full: bool,
    /// Output folder (default: results/{scenario name}).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Session id (default: a fresh one).
    #[arg(long)]
    pub session: Option<String>,
    /// Use the simulators and services already in the session (e.g. started by hand behind a
    /// router given with --connect), found by their liveliness tokens, and start only the
    /// missing ones. Without it the run refuses to start while a participant with the same role
    /// and id is there.
    #[arg(long)]
    pub attach_existing: bool,
    /// Seconds to wait for every participant to be ready.
    #[arg(long, default_value_t = 60.0)]
    pub ready_timeout: f64,
    /// After the control loop of all controlled simulators, run each of them alone in the same
    /// loop and report the loop's slowdown against the slowest one alone
    /// (`control_loop.slowdown_vs_slowest_alone` in report.json).
    #[arg(long)]
    pub loop_baseline: bool,
    /// On-policy aggregation: after the first control run, ROUNDS times retrain every
    /// controlled simulator's model on the collected data plus the closed-loop rollouts the
    /// recorder recorded so far, and control again (`aggregation` in report.json, plot
    /// aggregation.png). Each round's control result is printed beside the previous round's,
    /// and a round that made it worse (final error or tracking RMS up by more than 10% and
    /// 0.001, the goal lost, more unsolved MPC steps) is a warning. With tracking tasks marked
    /// `aggregate = true` (scenarios/README.md), their closed loops' windows are the added data
    /// and every tracking task runs again each round (`tracking_aggregation` in report.json).
    #[arg(long, value_name = "ROUNDS", default_value_t = 0)]
    pub aggregate: usize,
    /// Exit with an error (code 1) when the run ends with warnings (an MPC that did not solve
    /// every step, an aggregation round that made control worse); report.json is written
    /// either way.
    #[arg(long)]
    pub fail_on_warning: bool,
    /// Watch the run live in Rerun: every state against its reference, the inputs, the MPC's
    /// solve time and plan, collection and training progress (python -m koopbridge.view).
    /// `native`: Rerun's desktop viewer (needs a display); `web`: its web viewer on a local port
    /// (the address is printed); without a value: native where there is a display, else web.
    /// The view is also recorded into OUT/view.rrd (`koopbridge view --open OUT/view.rrd`).
    /// A viewer that cannot start or dies is a warning: the run goes on.
    #[arg(long, value_enum, num_args = 0..=1, default_missing_value = "auto", value_name = "WHERE")]
    pub view: Option<ViewArg>,
    /// The web viewer's port with `--view web` (default: a free one).
    #[arg(long, value_name = "PORT")]
    pub view_port: Option<u16>,
    /// Record the view into OUT/view.rrd without showing it (no display needed).
    #[arg(long, conflicts_with = "view")]
    pub record_view: bool,
    /// MP4s of these references' closed loops (comma-separated indices of a tracking task's
    /// references; a `[control]` loop is 0) for MuJoCo simulators, into OUT/videos/: the robot
    /// beside its reference, rendered offscreen (EGL, no GPU needed), the step and the tracking
    /// error in the frame. Records the view as --record-view does unless --view is given. The
    /// frames are rendered beside the run at low priority; the run waits for the last ones.
    #[arg(long, value_name = "REFS", value_parser = parse_refs)]
    pub video: Option<String>,
    #[command(flatten)]
    pub zenoh: super::ZenohArgs,
}

/// Where `--view` shows the run.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum ViewArg {
    /// The desktop viewer where there is a display, else the web viewer.
    Auto,
    /// Rerun's desktop viewer.
    Native,
    /// Rerun's web viewer on a local port.
    Web,
}

/// The run's view from `--view`, `--view-port` and `--record-view`.
fn view_options(args: &RunArgs) -> Option<ViewOptions> {
    let mode = match (args.view, args.record_view || args.video.is_some()) {
        (Some(ViewArg::Auto), _) => ViewMode::auto(),
        (Some(ViewArg::Native), _) => ViewMode::Native,
        (Some(ViewArg::Web), _) => ViewMode::Web,
        (None, true) => ViewMode::Record,
        (None, false) => return None,
    };
    Some(ViewOptions {
        mode,
        web_port: args.view_port,
        video: args.video.clone(),
    })
}

/// `--video 0,3,17`: reference indices, each a non-negative integer.
fn parse_refs(text: &str) -> Result<String, String> {
    for part in text.split(',') {
        if part.trim().parse::<usize>().is_err() {
            return Err(format!(
                "{part:?} is not a reference index (a non-negative integer); e.g. --video 0,3"
            ));
        }
    }
    Ok(text.replace(' ', ""))
}

/// Runs `koopbridge run`.
pub fn run(args: RunArgs) -> anyhow::Result<()> {
    let mut sc = Scenario::load(&args.scenario)?;
    if args.full {
        sc.apply_full();
    }
    let out_dir = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("results").join(&sc.name));
    std::fs::create_dir_all(&out_dir)?;
    let opts = RunOptions {
        exe: std::env::current_exe()?,
        out_dir: out_dir.clone(),
        zenoh: args.zenoh.options(),
        session: args.session.clone(),
        ready_timeout: Duration::from_secs_f64(args.ready_timeout),
        attach_existing: args.attach_existing,
    };
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{msg:40} [{bar:30}] {pos}/{len} {per_sec} eta {eta}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let mut last_phase = String::new();
    // Without a terminal (a log file, CI) the bar is hidden: a progress line every 30 s instead.
    let mut last_line = std::time::Instant::now();
    let mut log_progress = |what: &str, done: u64, total: u64| {
        if bar.is_hidden() && last_line.elapsed() >= std::time::Duration::from_secs(30) {
            last_line = std::time::Instant::now();
            eprintln!("   {what}: {done}/{total}");
        }
    };
    let extras = RunExtras {
        loop_baseline: args.loop_baseline,
        aggregate: args.aggregate,
        view: view_options(&args),
    };
    let report = run_scenario_with(&sc, &opts, &extras, &mut |e| match e {
        Event::Phase(p) => {
            if bar.is_hidden() {
                eprintln!("== {p}");
            } else {
                bar.println(format!("== {p}"));
            }
            last_phase = p.to_string();
        }
        Event::Collect(split, done, total) => {
            if bar.length() != Some(total as u64) || bar.message() != split {
                bar.set_length(total as u64);
                bar.set_message(format!("collect {split}"));
            }
            bar.set_position(done as u64);
            log_progress(
                &format!("collect {split} (windows)"),
                done as u64,
                total as u64,
            );
        }
        Event::Train(p) => {
            let it = p.get("iteration").and_then(|v| v.as_u64()).unwrap_or(0);
            let total = p.get("total").and_then(|v| v.as_u64()).unwrap_or(0);
            if bar.length() != Some(total) {
                bar.set_length(total);
                bar.set_message("train");
            }
            bar.set_position(it);
            log_progress("train (iterations)", it, total);
        }
        Event::Control(k, n) => {
            if bar.length() != Some(n as u64) {
                bar.set_length(n as u64);
                bar.set_message("control");
            }
            bar.set_position(k as u64);
            log_progress("control (steps)", k as u64, n as u64);
        }
        Event::Warning(w) => {
            if bar.is_hidden() {
                eprintln!("warning: {w}");
            } else {
                bar.println(format!("warning: {w}"));
            }
        }
    })?;
    bar.finish_and_clear();
    let path = out_dir.join("report.json");
    println!(
        "scenario '{}' done in {:.1} s (session {})",
        report.scenario, report.wall_seconds, report.session
    );
    let reused = |r: bool| {
        if r {
            " (reused from the previous run)"
        } else {
            ""
        }
    };
    match &report.collect {
        Some(c) => println!(
            "  collected {:?} windows × {} steps from {:?} at {:.0} macro steps/s{}",
            c.windows,
            c.steps,
            c.sims,
            c.macro_steps_per_second,
            reused(c.reused)
        ),
        None => println!("  collected nothing (no [collect]: models trained elsewhere)"),
    }
    for t in &report.train {
        println!(
            "  model '{}' (job {}){}: {}",
            t.model,
            t.job,
            reused(t.reused),
            t.metrics
        );
    }
    // With several model kinds, each control run is named by its model (`{scenario}-{sim}-{kind}`).
    for v in &report.videos {
        println!("  video: {}", v.display());
    }
    if let Some(v) = &report.view {
        println!(
            "  view: {} (open it with: koopbridge view --open {})",
            v.display(),
            v.display()
        );
    }
    let kinds = report
        .models
        .iter()
        .filter(|m| report.models[0].sim == m.sim)
        .count();
    // Several simulators in the control loop (each kind has its own loop of them).
    let several = report.controls.len() > kinds.max(1);
    for (i, c) in report.controls.iter().enumerate() {
        // The first entry's plot keeps the name of a one-simulator run.
        let png = if i == 0 {
            out_dir.join("control.png")
        } else if let Some(label) = &c.label {
            out_dir.join(format!("control-{label}.png"))
        } else if kinds > 1 {
            out_dir.join(format!("control-{}.png", c.model))
        } else {
            out_dir.join(format!("control-{}.png", c.sim))
        };
        match plot_control(c, &png) {
            Ok(()) => println!("  plot: {}", png.display()),
            Err(e) => eprintln!("warning: could not draw {}: {e:#}", png.display()),
        }
        println!("  {}", c.summary_line(kinds > 1));
    }
    if let (true, Some(l)) = (several, &report.control_loop) {
        println!(
            "  control loop of {:?}: {} macro steps at {:.0} macro steps/s (median {:.0} µs){}{}",
            l.sims,
            l.macro_steps,
            l.macro_steps_per_second,
            l.macro_step_median_us,
            l.slowdown_vs_slowest_alone
                .map_or(String::new(), |r| format!(
                    ", {r:.2}x the slowest simulator alone"
                )),
            l.critical_path.as_ref().map_or(String::new(), |c| format!(
                "; critical path '{c}', {} others at lower CPU priority",
                l.deprioritised.len()
            ))
        );
    }
    if kinds > 1 {
        println!("  the models side by side:");
        for line in bridge::orchestrator::compare::table(&report.models).lines() {
            println!("    {line}");
        }
    }
    if !report.aggregation.is_empty() {
        for r in &report.aggregation {
            for a in &r.sims {
                println!(
                    "  aggregation round {} '{}': {} training windows ({} recorded); previous round -> this round: tracking RMS {:.4} -> {:.4}, final error {:.4} -> {:.4}, time to goal {} -> {}, not solved {} -> {}{}",
                    r.round,
                    a.sim,
                    a.train_windows,
                    a.recorded.windows,
                    a.error_before,
                    a.error_after,
                    a.final_error_before,
                    a.final_error_after,
                    time_to_goal_text(a.time_to_goal_before),
                    time_to_goal_text(a.time_to_goal_after),
                    a.not_solved_before,
                    a.not_solved_after,
                    if a.regression.is_some() { "  [WORSE]" } else { "" }
                );
            }
        }
        let png = out_dir.join("aggregation.png");
        match plot_aggregation(&report.aggregation, &png) {
            Ok(()) => println!("  plot: {}", png.display()),
            Err(e) => eprintln!("warning: could not draw {}: {e:#}", png.display()),
        }
    }
    if !report.tracking.is_empty() {
        for line in bridge::orchestrator::tracking::table(&report.tracking).lines() {
            println!("  {line}");
        }
        if !report.tracking_aggregation.is_empty() {
            println!(
                "  aggregation rounds of the tracking tasks (mean survival of each model row):"
            );
            let table = bridge::orchestrator::track_aggregate::rounds_table(
                &report.tracking,
                &report.tracking_aggregation,
            );
            for line in table.lines() {
                println!("    {line}");
            }
        }
        let png = out_dir.join("tracking").join("survival.png");
        if report.tracking.iter().any(|t| t.survival.is_some()) {
            match plot_survival(&report.tracking, &png) {
                Ok(()) => println!("  plot: {}", png.display()),
                Err(e) => eprintln!("warning: could not draw {}: {e:#}", png.display()),
            }
        }
        let png = out_dir.join("tracking").join("error.png");
        match plot_first_errors(&report.tracking, &png) {
            Ok(()) => println!("  plot: {}", png.display()),
            Err(e) => eprintln!("warning: could not draw {}: {e:#}", png.display()),
        }
    }
    println!("  report: {}", path.display());
    // Repeated at the end, where they are not lost among the progress lines.
    for w in &report.warnings {
        eprintln!("warning: {w}");
    }
    if args.fail_on_warning && !report.warnings.is_empty() {
        anyhow::bail!(
            "{} warning(s) and --fail-on-warning (the report is in {})",
            report.warnings.len(),
            path.display()
        );
    }
    Ok(())
}

/// States against their references, then inputs, of a closed-loop run.
fn plot_control(
    c: &bridge::orchestrator::ControlReport,
    path: &std::path::Path,
) -> anyhow::Result<()> {
    use crate::plot::{time_series_png, Panel, Series};
    let t: Vec<f64> = (0..c.x.len()).map(|k| k as f64 * c.dt).collect();
    let mut panels = Vec::new();
    for (i, name) in c.state_names.iter().enumerate() {
        let y: Vec<f64> = c.x.iter().map(|x| x[i]).collect();
        let r: Vec<f64> = match &c.reference_trajectory {
            Some(rows) => rows.iter().map(|r| r[i]).collect(),
            None => vec![c.reference.get(i).copied().unwrap_or(f64::NAN); t.len()],
        };
        panels.push(Panel {
            title: name.clone(),
            y_label: name.clone(),
            series: vec![
                Series::new(name.clone(), &t, &y),
                Series::new("reference", &t, &r).dashed(),
            ],
        });
    }
    if c.error.len() == t.len() {
        panels.push(Panel {
            title: "error ‖x − r‖ (angles wrapped)".into(),
            y_label: "error".into(),
            series: vec![Series::new("error", &t, &c.error)],
        });
    }
    for (j, name) in c.input_names.iter().enumerate() {
        let y: Vec<f64> = c.u.iter().map(|u| u[j]).collect();
        panels.push(Panel {
            title: name.clone(),
            y_label: name.clone(),
            series: vec![Series::new(name.clone(), &t[..y.len()], &y)],
        });
    }
    time_series_png(
        path,
        &format!("{}: MPC over Zenoh ({})", c.sim, c.model),
        "t [s]",
        &panels,
        900,
    )
}

/// Tracking RMS and final error of every controlled simulator against the aggregation round
/// (round 0: the model trained on the collected data only).
fn plot_aggregation(
    rounds: &[bridge::orchestrator::aggregate::AggregationRound],
    path: &std::path::Path,
) -> anyhow::Result<()> {
    use crate::plot::{time_series_png, Panel, Series};
    let Some(first) = rounds.first() else {
        anyhow::bail!("no rounds");
    };
    let t: Vec<f64> = (0..=rounds.len()).map(|r| r as f64).collect();
    let mut panels = Vec::new();
    for (j, s) in first.sims.iter().enumerate() {
        let pick = |f: &dyn Fn(&bridge::orchestrator::aggregate::AggregatedSim) -> f64,
                    before: f64| {
            std::iter::once(before)
                .chain(rounds.iter().map(|r| f(&r.sims[j])))
                .collect::<Vec<f64>>()
        };
        let rms = pick(&|a| a.error_after, s.error_before);
        let fin = pick(&|a| a.final_error_after, s.final_error_before);
        panels.push(Panel {
            title: format!("{}: error against the aggregation round", s.sim),
            y_label: "error".into(),
            series: vec![
                Series::new("tracking RMS", &t, &rms),
                Series::new("final error", &t, &fin).dashed(),
            ],
        });
    }
    time_series_png(path, "on-policy aggregation", "round", &panels, 900)
}

/// The tracking tasks' survival curves: per task, the share of references each row still tracked
/// after k steps (a cumulative histogram of the survival steps; the replay row dashed).
fn plot_survival(
    tasks: &[bridge::orchestrator::tracking::TrackReport],
    path: &std::path::Path,
) -> anyhow::Result<()> {
    use crate::plot::{time_series_png, Panel, Series};
    let mut panels = Vec::new();
    for task in tasks.iter().filter(|t| t.survival.is_some()) {
        let t: Vec<f64> = (0..=task.steps).map(|k| k as f64).collect();
        let series = task
            .rows
            .iter()
            .enumerate()
            .map(|(i, row)| {
                let n = row.survivals.len().max(1) as f64;
                let share: Vec<f64> = (0..=task.steps)
                    .map(|k| row.survivals.iter().filter(|&&s| s >= k).count() as f64 / n)
                    .collect();
                let s = Series::new(&row.row, &t, &share).colored(i);
                if row.model.is_none() {
                    s.dashed()
                } else {
                    s
                }
            })
            .collect();
        panels.push(Panel {
            title: format!(
                "{}{}: share of {} references still tracked",
                task.sim,
                task.label
                    .as_ref()
                    .map_or(String::new(), |l| format!(" [{l}]")),
                task.references
            ),
            y_label: "share".into(),
            series,
        });
    }
    time_series_png(path, "survival", "step", &panels, 900)
}

/// Per tracking task, every row's error on the first reference step by step (the error the
/// survival metric scores, its threshold dashed): where a run leaves the reference.
fn plot_first_errors(
    tasks: &[bridge::orchestrator::tracking::TrackReport],
    path: &std::path::Path,
) -> anyhow::Result<()> {
    use crate::plot::{time_series_png, Panel, Series};
    let mut panels = Vec::new();
    for task in tasks {
        let mut series: Vec<Series> = task
            .rows
            .iter()
            .enumerate()
            .map(|(i, row)| {
                let t: Vec<f64> = (0..row.first_errors.len()).map(|k| k as f64).collect();
                let s = Series::new(&row.row, &t, &row.first_errors).colored(i);
                if row.model.is_none() {
                    s.dashed()
                } else {
                    s
                }
            })
            .collect();
        if let Some(m) = &task.survival {
            let ends = [0.0, task.steps as f64];
            series.push(Series::new("threshold", &ends, &[m.threshold; 2]).dashed());
        }
        panels.push(Panel {
            title: format!(
                "{}{}: reference 0, error against the step",
                task.sim,
                task.label
                    .as_ref()
                    .map_or(String::new(), |l| format!(" [{l}]"))
            ),
            y_label: if task.survival.is_some() {
                "mean |x - r| (scored states)".into()
            } else {
                "‖x - r‖".into()
            },
            series,
        });
    }
    time_series_png(
        path,
        "tracking error, first reference",
        "step",
        &panels,
        900,
    )
}
