//! `koopbridge eval`: the prediction error and diagnostics of a saved model on a dataset file.

use anyhow::Context;
use koopman::data::Dataset;
use koopman::model::koopman::KoopmanModel;
use koopman::model::nndm::NndmModel;
use koopman::model::{load_lifted, store, LiftedModel};
use serde::Serialize;
use std::path::PathBuf;

/// Arguments of `koopbridge eval`.
#[derive(clap::Args, Debug)]
#[command(
    about = "Evaluate a saved model on a dataset: prediction error, conditioning, spectrum of A",
    long_about = "Evaluate a saved model (a folder written by 'koopbridge train') on a dataset file (.npz from \
        'koopbridge data gen'): SPEC's prediction error (discounted multi-step L_pred, every window encoded once \
        at its first state), the condition numbers κ(G) of the latent Gram matrix on the data and κ(BᵀB), and the \
        spectral radius of A. For an NNDM (kind nndm) only the prediction error, by rolling the \
        one-step model out from every window's first state with the window's inputs (same γ and normalisation). \
        With --per-state (Koopman and EDMD models) also each state's RMS error over every window and step of the \
        same rollout, in the data's raw units (a z-scored model's error scaled back by its σ): which states a model \
        gets wrong.\n\nExample: koopbridge eval --model models/damped --data data/damped/test.npz --per-state"
)]
pub struct EvalArgs {
    /// Model folder (config.json + weights).
    #[arg(long)]
    pub model: PathBuf,
    /// Dataset file (.npz).
    #[arg(long)]
    pub data: PathBuf,
    /// Discount γ of the prediction error.
    #[arg(long, default_value_t = 0.8)]
    pub gamma: f64,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
    /// Also each state's RMS error of the rollout (raw units, undiscounted); Koopman and EDMD.
    #[arg(long)]
    pub per_state: bool,
}

/// What `eval` reports; the lifted-model diagnostics are `None` for an NNDM, whose
/// `latent_dim` is nx (it predicts the state itself).
#[derive(Serialize)]
struct EvalReport {
    kind: String,
    windows: usize,
    pairing: koopman::data::Pairing,
    prediction_error: f64,
    gram_condition: Option<f64>,
    bbt_condition: Option<f64>,
    spectral_radius: Option<f64>,
    latent_dim: usize,
    /// With `--per-state`: each state's RMS error of the rollout, raw units.
    #[serde(skip_serializing_if = "Option::is_none")]
    per_state: Option<Vec<StateError>>,
}

/// One state's RMS error of the multi-step rollout.
#[derive(Serialize)]
struct StateError {
    name: String,
    rms: f64,
}

/// Runs `koopbridge eval`.
pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    let data = Dataset::load_npz(&args.data)
        .with_context(|| format!("loading {}", args.data.display()))?;
    let kind = store::read_kind(&args.model)?;
    if args.per_state && (kind == "nndm" || kind == "bilinear") {
        anyhow::bail!(
            "--per-state is for Koopman and EDMD models; {} is a {kind} model",
            args.model.display()
        );
    }
    if kind == "nndm" {
        return eval_nndm(&args, &data);
    }
    if kind == "bilinear" {
        // The diagnostics are those of the linear part (encoder, A, B); the prediction error
        // is the bilinear rollout's.
        let bil = koopman::model::bilinear::BilinearModel::load(&args.model)?;
        check_dims(&args, &data, bil.nx(), bil.nu())?;
        let err = koopman::train::bilinear_prediction_error(&bil, &data, args.gamma)?;
        let rep = lifted_report(kind, bil.linear(), err, &data);
        return print_report(&args, &rep);
    }
    if kind == "koopman" {
        // In the model's own coordinates: a model trained on z-scored data is evaluated on the
        // test windows z-scored with its statistics, as its training reported.
        let km = KoopmanModel::load(&args.model)?;
        check_dims(&args, &data, km.nx(), km.nu())?;
        let data = match km.normalisation() {
            Some(norm) => norm.apply(&data)?,
            None => data,
        };
        let err = koopman::train::prediction_error(&km, &data, args.gamma)?;
        let mut rep = lifted_report(kind, &km, err, &data);
        if args.per_state {
            let std = km.normalisation().map(|n| n.x_std.as_slice());
            rep.per_state = Some(state_errors(&km, &data, std)?);
        }
        return print_report(&args, &rep);
    }
    let model: Box<dyn LiftedModel> = load_lifted(&args.model)?;
    check_dims(&args, &data, model.nx(), model.nu())?;
    let prediction_error =
        { koopman::analysis::prediction_error(model.as_ref(), &data, args.gamma)? };
    let mut rep = lifted_report(kind, model.as_ref(), prediction_error, &data);
    if args.per_state {
        rep.per_state = Some(state_errors(model.as_ref(), &data, None)?);
    }
    print_report(&args, &rep)
}

/// Each state's RMS rollout error, named; `x_std` scales a z-scored model's errors to raw units.
fn state_errors(
    model: &dyn LiftedModel,
    data: &Dataset,
    x_std: Option<&[f64]>,
) -> anyhow::Result<Vec<StateError>> {
    let rms = koopman::analysis::state_rms_errors(model, data)?;
    Ok(rms
        .iter()
        .enumerate()
        .map(|(s, r)| StateError {
            name: data
                .meta
                .state_names
                .get(s)
                .cloned()
                .unwrap_or_else(|| format!("x{s}")),
            rms: r * x_std.map_or(1.0, |sd| sd[s]),
        })
        .collect())
}

fn check_dims(args: &EvalArgs, data: &Dataset, nx: usize, nu: usize) -> anyhow::Result<()> {
    if data.nx != nx || data.nu != nu {
        anyhow::bail!(
            "the model expects nx = {}, nu = {} but {} has nx = {}, nu = {}",
            nx,
            nu,
            args.data.display(),
            data.nx,
            data.nu
        );
    }
    Ok(())
}

/// The report of a lifted model: its prediction error and the diagnostics of its lifting, A, B.
fn lifted_report(
    kind: String,
    model: &dyn LiftedModel,
    prediction_error: f64,
    data: &Dataset,
) -> EvalReport {
    let gram_condition = koopman::analysis::gram_condition(model, data).ok();
    let bbt_condition = if model.nu() > 0 {
        koopman::analysis::bbt_condition(model).ok()
    } else {
        None
    };
    let spectral_radius = koopman::analysis::eigenvalues(model.a().as_ref())
        .ok()
        .map(|ev| {
            ev.iter()
                .map(|c| (c.re * c.re + c.im * c.im).sqrt())
                .fold(0.0, f64::max)
        });
    EvalReport {
        kind,
        windows: data.n,
        pairing: data.meta.pairing,
        prediction_error,
        gram_condition,
        bbt_condition,
        spectral_radius,
        latent_dim: model.latent_dim(),
        per_state: None,
    }
}

/// An NNDM (one-step MLP): the prediction error by rollout from every window's first state.
fn eval_nndm(args: &EvalArgs, data: &Dataset) -> anyhow::Result<()> {
    let model = NndmModel::load(&args.model)?;
    let nx = model.arch().nx;
    check_dims(args, data, nx, model.arch().nu)?;
    let rep = EvalReport {
        kind: "nndm".into(),
        windows: data.n,
        pairing: data.meta.pairing,
        prediction_error: koopman::train::nndm::prediction_error(&model, data, args.gamma)?,
        gram_condition: None,
        bbt_condition: None,
        spectral_radius: None,
        latent_dim: nx,
        per_state: None,
    };
    print_report(args, &rep)
}

fn print_report(args: &EvalArgs, rep: &EvalReport) -> anyhow::Result<()> {
    if args.json {
        println!("{}", serde_json::to_string(rep)?);
    } else {
        let f = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.4e}"));
        println!(
            "model        {} ({}; N = {})",
            args.model.display(),
            rep.kind,
            rep.latent_dim
        );
        println!(
            "data         {} ({} windows, {:?} pairing)",
            args.data.display(),
            rep.windows,
            rep.pairing
        );
        println!(
            "prediction error (γ = {}): {:.6}",
            args.gamma, rep.prediction_error
        );
        println!("κ(G) latent Gram: {}", f(rep.gram_condition));
        println!("κ(BᵀB):           {}", f(rep.bbt_condition));
        println!(
            "spectral radius of A: {}",
            rep.spectral_radius
                .map_or("-".into(), |v| format!("{v:.6}"))
        );
        if let Some(states) = &rep.per_state {
            println!("RMS error per state (raw units, every window and step):");
            for e in states {
                println!("  {:<24} {:.6}", e.name, e.rms);
            }
        }
    }
    Ok(())
}
