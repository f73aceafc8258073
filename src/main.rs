//! The `koopbridge` command line: one binary for data, training, control, services and scenarios.

mod cli;
mod plot;

use clap::{Parser, Subcommand};

/// koopbridge — neural Koopman models and linear MPC as Zenoh services, simulators as adapters.
#[derive(Parser)]
#[command(name = "koopbridge", version, about, long_about = None, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Generate and inspect datasets of state/input windows.
    Data(cli::data::DataArgs),
    /// Train a model (neural Koopman, EDMD or NNDM) on a dataset.
    Train(cli::train::TrainArgs),
    /// Evaluate a trained model on a dataset (prediction error, diagnostics).
    Eval(cli::eval::EvalArgs),
    // No doc comments here: one on the variant would replace the command's own about and
    // long_about (its --help page) with a single line.
    Scaling(cli::scaling::ScalingArgs),
    Sweep(cli::sweep::SweepArgs),
    /// Print the paper's data budget m ≳ 40·N·ln N for a latent dimension.
    Plan(cli::plan::PlanArgs),
    /// Closed-loop control of a reference system with a trained model.
    Control(cli::control::ControlArgs),
    /// Benchmarks (training speed, MPC solvers, bridge round trips).
    Bench(cli::bench::BenchArgs),
    /// Serve a built-in reference system as a Zenoh simulator adapter.
    Sim(cli::sim::SimArgs),
    /// Run koopbridge services (trainer, MPC, recorder, model store) over Zenoh.
    Serve(cli::serve::ServeArgs),
    /// Run a scenario file: collection → training → control → report.
    Run(cli::run::RunArgs),
    /// Watch a running session (or open a recorded view.rrd) in Rerun's viewer.
    View(cli::view::ViewArgs),
    /// Run a plain Zenoh router (scale-out: services and simulators on several hosts).
    Router(cli::router::RouterArgs),
    /// Export a trained model and its MPC as an FMI 3.0 / 2.0 co-simulation FMU (controller.fmu).
    ExportFmu(cli::export_fmu::ExportFmuArgs),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    cli::init_tracing();
    let result = match cli.command {
        Command::Data(a) => cli::data::run(a),
        Command::Train(a) => cli::train::run(a),
        Command::Eval(a) => cli::eval::run(a),
        Command::Scaling(a) => cli::scaling::run(a),
        Command::Sweep(a) => cli::sweep::run(a),
        Command::Plan(a) => cli::plan::run(a),
        Command::Control(a) => cli::control::run(a),
        Command::Bench(a) => cli::bench::run(a),
        Command::Sim(a) => cli::sim::run(a),
        Command::Serve(a) => cli::serve::run(a),
        Command::Run(a) => cli::run::run(a),
        Command::Router(a) => cli::router::run(a),
        Command::View(a) => cli::view::run(a),
        Command::ExportFmu(a) => cli::export_fmu::run(a),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
