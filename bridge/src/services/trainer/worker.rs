//! A trainer worker thread: takes the next queued job, trains it with the service's
//! [`Trainer`] into a temporary folder beside its model, publishes its progress, stores the
//! model (whole or not at all) and records how the job ended.

use std::collections::HashMap;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use zenoh::{Session, Wait};

use super::jobs::{JobEnded, JobProgress, JobSpec, Jobs, TrainProgress};
use crate::error::{Error, ErrorReply, Result};
use crate::fsutil::DataRoot;
use crate::keyexpr::Keys;
use crate::services::lock;

/// What actually trains: loads the data, trains, writes the model into `out_dir`, returns metrics.
pub trait Trainer: Send + Sync {
    /// Checks a job before it is queued (e.g. its settings); an error refuses the submission
    /// with that reply. The default accepts every job.
    fn validate(&self, _spec: &JobSpec) -> std::result::Result<(), ErrorReply> {
        Ok(())
    }

    /// Runs one job. `checkpoint` is the job's checkpoint file: continue from it if it exists
    /// and fits the job, and (re)write it atomically as training goes; the service deletes it
    /// when the job ends. `progress` receives each iteration's progress and may cancel with
    /// `Break`.
    fn train(
        &self,
        spec: &JobSpec,
        out_dir: &Path,
        checkpoint: &Path,
        progress: &mut dyn FnMut(&TrainProgress) -> ControlFlow<()>,
    ) -> Result<serde_json::Value>;
}

/// What the service and its workers share.
pub struct Shared {
    /// The jobs (records, queue, persistence).
    pub jobs: Mutex<Jobs>,
    /// Signalled when a job is queued or the service stops.
    pub wake: Condvar,
    /// The cancel flags of the running jobs.
    pub cancel: Mutex<HashMap<String, Arc<AtomicBool>>>,
    /// Set when the service stops.
    pub done: AtomicBool,
}

impl Shared {
    /// Raises the cancel flag of `job` if it is running. Call it holding the `jobs` lock (the
    /// lock order is `jobs`, then `cancel`), see [`next_job`].
    pub fn cancel_running(&self, job: &str) {
        if let Some(f) = lock(&self.cancel).get(job) {
            f.store(true, Ordering::Relaxed);
        }
    }
}

/// Where a worker publishes and stores.
pub struct WorkerContext {
    /// The session progress is published on.
    pub session: Session,
    /// The session's keys.
    pub keys: Keys,
    /// The trainer id.
    pub id: String,
    /// The model store.
    pub store: PathBuf,
    /// The folder dataset paths must lie in.
    pub data_root: DataRoot,
}

/// Progress is published at most this often (and at every validation and the last iteration).
const PROGRESS_EVERY: Duration = Duration::from_millis(200);

/// Runs jobs until the service stops.
pub fn run(shared: &Shared, trainer: &dyn Trainer, cx: &WorkerContext) {
    while let Some((rec, flag)) = next_job(shared) {
        let job = rec.job.clone();
        let checkpoint = lock(&shared.jobs).dir().join(format!("{job}.ckpt"));
        let progress_key = cx.keys.trainer_progress(&cx.id, &job).ok();
        let ended = run_job(shared, trainer, cx, &rec.spec, &job, &checkpoint, &flag);
        lock(&shared.cancel).remove(&job);
        let Some(ended) = ended else {
            // The service is stopping: the job stays `running` on disk, so a restart resumes it.
            return;
        };
        let Some(r) = lock(&shared.jobs).finish(&job, ended) else {
            continue;
        };
        // The job has ended (done, failed or cancelled): its checkpoint is of no more use.
        let _ = std::fs::remove_file(&checkpoint);
        tracing::info!("trainer '{}': job {} {:?}", cx.id, r.job, r.state);
        if let Some(k) = &progress_key {
            let msg = JobEnded {
                job: &r.job,
                state: r.state,
                error: &r.error,
            };
            let _ = cx
                .session
                .put(k, serde_json::to_vec(&msg).unwrap_or_default())
                .wait();
        }
    }
}

/// How a job ended: its metrics, or (cancelled?, message).
type Ended = std::result::Result<serde_json::Value, (bool, String)>;

/// Trains one job and stores its model; `None` if the service stopped it. `flag` is the job's
/// cancel flag.
fn run_job(
    shared: &Shared,
    trainer: &dyn Trainer,
    cx: &WorkerContext,
    spec: &JobSpec,
    job: &str,
    checkpoint: &Path,
    flag: &AtomicBool,
) -> Option<Ended> {
    let final_dir = cx.store.join(&spec.model);
    // Removed on every way out (error, stop, panic) unless committed to `final_dir`.
    let tmp = match koopman::fsutil::TempDir::beside(&final_dir) {
        Ok(t) => t,
        Err(e) => return Some(Err((false, e.to_string()))),
    };
    let progress_key = cx.keys.trainer_progress(&cx.id, job).ok();
    let mut last_put = Instant::now() - PROGRESS_EVERY * 2;
    let mut on_progress = |p: &TrainProgress| {
        if last_put.elapsed() > PROGRESS_EVERY || p.is_last() || p.train.validation.is_some() {
            last_put = Instant::now();
            if let Some(k) = &progress_key {
                let msg = JobProgress { job, progress: p };
                let _ = cx
                    .session
                    .put(k, serde_json::to_vec(&msg).unwrap_or_default())
                    .wait();
            }
            lock(&shared.jobs).progress(job, p);
        }
        if flag.load(Ordering::Relaxed) {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    };
    // Checked again: a job persisted earlier (or a path changed since) must not escape the data
    // root either.
    let outcome = super::confine(&cx.data_root, spec.clone())
        .map_err(|e| Error::Protocol {
            code: e.code,
            message: e.message,
        })
        .and_then(|spec| trainer.train(&spec, tmp.path(), checkpoint, &mut on_progress));
    if shared.done.load(Ordering::Relaxed) && flag.load(Ordering::Relaxed) {
        return None;
    }
    let ended = match outcome {
        Ok(metrics) => koopman::fsutil::write_atomic(
            &tmp.path().join("metrics.json"),
            &serde_json::to_vec_pretty(&metrics).unwrap_or_default(),
        )
        .and_then(|()| tmp.commit())
        .map(|_| metrics)
        .map_err(|e| {
            (
                false,
                format!("could not store the model in {}: {e}", final_dir.display()),
            )
        }),
        Err(e) => Err((
            matches!(
                e,
                Error::Koopman(koopman::Error::Cancelled) | Error::Stopped
            ),
            e.to_string(),
        )),
    };
    Some(ended)
}

/// Waits for the next queued job (now `running`) and registers its cancel flag under the same
/// lock, so that a cancel or a superseding submission (which hold that lock too) either finds
/// the job still queued or finds its flag; `None` when the service stops.
fn next_job(shared: &Shared) -> Option<(super::jobs::JobRecord, Arc<AtomicBool>)> {
    let mut jobs = lock(&shared.jobs);
    loop {
        if shared.done.load(Ordering::Relaxed) {
            return None;
        }
        if let Some(r) = jobs.start_next() {
            let flag = Arc::new(AtomicBool::new(false));
            lock(&shared.cancel).insert(r.job.clone(), flag.clone());
            return Some((r, flag));
        }
        jobs = shared
            .wake
            .wait_timeout(jobs, Duration::from_millis(200))
            .map(|(g, _)| g)
            .unwrap_or_else(|e| e.into_inner().0);
    }
}
