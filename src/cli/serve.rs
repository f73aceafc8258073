//! `koopbridge serve`: runs any subset of the Zenoh services (trainer, MPC, recorder, model
//! store) in one process, each on its own thread.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use bridge::keyexpr::Keys;
use bridge::session::open_session;

/// A service that `koopbridge serve` can run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Service {
    /// Training jobs (`…/trainer/{id}/jobs`).
    Trainer,
    /// Model predictive control (`…/mpc/{id}/{configure,solve,attach}`).
    Mpc,
    /// Stream recording (`…/recorder/{id}/record`, `…/data/{name}`).
    Recorder,
    /// The model store (`…/models/{name}`).
    Models,
}

/// Arguments of `koopbridge serve`.
#[derive(clap::Args)]
#[command(after_help = "Examples:\n  \
    koopbridge serve mpc models --session demo --store models --listen tcp/127.0.0.1:7502\n  \
    koopbridge serve --session demo --connect tcp/127.0.0.1:7447 --mode client\n\n\
    Every service holds a liveliness token koopbridge/{session}/alive/{role}/{id}. See PROTOCOL.md.")]
pub struct ServeArgs {
    /// Services to run (default: all of them).
    #[arg(value_enum)]
    pub services: Vec<Service>,
    /// koopbridge session id ([a-z0-9_-]).
    #[arg(long, default_value = "default")]
    pub session: String,
    /// Id of the services (the `{id}` chunk of their keys).
    #[arg(long, default_value = "main")]
    pub id: String,
    /// Model store folder: finished models are written here and served from here.
    #[arg(long, default_value = "models")]
    pub store: PathBuf,
    /// Folder of the services' own state (trainer job specs, recordings).
    #[arg(long, default_value = ".koopbridge")]
    pub state_dir: PathBuf,
    /// Trainer: the folder that every `{"path": …}` dataset of a job must lie inside (symlinks
    /// followed; relative paths are taken relative to it). Default: `{state-dir}/data` (where
    /// the recorder writes). Jobs naming anything else are refused with `forbidden`.
    #[arg(long)]
    pub data_root: Option<PathBuf>,
    /// Trainer: how many jobs run at the same time.
    #[arg(long, default_value_t = 1)]
    pub max_jobs: usize,
    /// Trainer: threads of a job whose config does not set `threads`. The gradient is summed
    /// over one row part per thread, so a model's bits depend on this number: keeping it fixed
    /// (rather than "all cores") makes the same job give the same model on every machine.
    #[arg(long, default_value_t = bridge::services::koopman_trainer::DEFAULT_TRAIN_THREADS,
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..))]
    pub train_threads: usize,
    /// Exit when standard input closes (used by `koopbridge run`).
    #[arg(long)]
    pub stdin_lifeline: bool,
    #[command(flatten)]
    pub zenoh: super::ZenohArgs,
}

/// Runs `koopbridge serve`.
pub fn run(args: ServeArgs) -> anyhow::Result<()> {
    let keys = Keys::new(&args.session)?;
    bridge::keyexpr::validate_chunk("service id", &args.id)?;
    let services = if args.services.is_empty() {
        vec![
            Service::Trainer,
            Service::Mpc,
            Service::Recorder,
            Service::Models,
        ]
    } else {
        args.services.clone()
    };
    let stop = if args.stdin_lifeline {
        super::sim::stdin_lifeline()
    } else {
        Arc::new(AtomicBool::new(false))
    };
    std::fs::create_dir_all(&args.store)?;
    std::fs::create_dir_all(&args.state_dir)?;
    let data_root = bridge::fsutil::DataRoot::new(
        &args
            .data_root
            .clone()
            .unwrap_or_else(|| args.state_dir.join("data")),
    )?;
    let session = open_session(&args.zenoh.options())?;
    let mut threads = Vec::new();
    for s in services {
        let (session, keys, id, store, state, stop, root) = (
            session.clone(),
            keys.clone(),
            args.id.clone(),
            args.store.clone(),
            args.state_dir.clone(),
            stop.clone(),
            data_root.clone(),
        );
        let (max_jobs, train_threads) = (args.max_jobs, args.train_threads);
        threads.push((
            s,
            std::thread::spawn(move || -> bridge::Result<()> {
                match s {
                    Service::Mpc => {
                        bridge::services::mpc::serve(&session, &keys, &id, &store, &stop)
                    }
                    Service::Models => {
                        bridge::services::models::serve(&session, &keys, &id, &store, &stop)
                    }
                    Service::Trainer => bridge::services::koopman_trainer::serve(
                        &session,
                        &keys,
                        &id,
                        &store,
                        &state.join("trainer"),
                        &root,
                        max_jobs,
                        train_threads,
                        &stop,
                    ),
                    Service::Recorder => bridge::services::recorder::serve(
                        &session,
                        &keys,
                        &id,
                        &state.join("data"),
                        &stop,
                    ),
                }
            }),
        ));
    }
    let mut failed = None;
    for (s, t) in threads {
        match t.join() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                stop.store(true, Ordering::Relaxed);
                failed = Some(anyhow::anyhow!("{s:?} service failed: {e}"));
            }
            Err(_) => failed = Some(anyhow::anyhow!("{s:?} service panicked")),
        }
    }
    let _ = bridge::zenoh::Wait::wait(session.close());
    failed.map_or(Ok(()), Err)
}
