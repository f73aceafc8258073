//! The trainer's Zenoh side: the `…/trainer/{id}/jobs` (submit, list) and `…/jobs/{job}`
//! (status, cancel) queryables, answered from the shared [`Jobs`], and the worker threads.

use std::collections::HashMap;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};

use serde::Deserialize;
use zenoh::Session;

use super::jobs::{JobSpec, Jobs};
use super::worker::{self, Shared, Trainer, WorkerContext};
use crate::error::{Error, ErrorCode, ErrorReply, Result};
use crate::fsutil::DataRoot;
use crate::keyexpr::{validate_chunk, Keys, Role};
use crate::services::{key_tail, lock, parse_json, serve_queries, to_json, Inbox, Reply};

/// Serves trainer `id` with any [`Trainer`]. Unfinished jobs found in `state_dir/jobs` are queued
/// again first (resumed from their checkpoint `jobs/{job}.ckpt` when there is one). Submitting a
/// spec equal to that of a queued or running job returns that job (idempotent submission, so a
/// restarted client finds its job again). Dataset paths of a job must lie inside `data_root`
/// (see [`super::confine`]): others are refused at submission with `forbidden`, and a persisted
/// job whose paths no longer do fails when it would start. A job the trainer's
/// [`Trainer::validate`] refuses is not queued.
#[allow(clippy::too_many_arguments)]
pub fn serve_with(
    session: &Session,
    keys: &Keys,
    id: &str,
    store: &Path,
    state_dir: &Path,
    data_root: &DataRoot,
    max_jobs: usize,
    trainer: Arc<dyn Trainer>,
    stop: &AtomicBool,
) -> Result<()> {
    std::fs::create_dir_all(store).map_err(|e| Error::Io {
        path: store.to_path_buf(),
        source: e,
    })?;
    let shared = Arc::new(Shared {
        jobs: Mutex::new(Jobs::open(&state_dir.join("jobs"))?),
        wake: Condvar::new(),
        cancel: Mutex::new(HashMap::new()),
        done: AtomicBool::new(false),
    });
    let workers: Vec<_> = (0..max_jobs.max(1))
        .map(|_| {
            let (shared, trainer) = (shared.clone(), trainer.clone());
            let cx = WorkerContext {
                session: session.clone(),
                keys: keys.clone(),
                id: id.to_string(),
                store: store.to_path_buf(),
                data_root: data_root.clone(),
            };
            std::thread::spawn(move || worker::run(&shared, trainer.as_ref(), &cx))
        })
        .collect();
    shared.wake.notify_all();

    let mut inbox = Inbox::new();
    inbox.declare(session, &keys.trainer_jobs(id)?, false)?;
    inbox.declare(session, &keys.under(&["trainer", id, "jobs", "*"]), true)?;
    tracing::info!("trainer '{id}': {} concurrent jobs", max_jobs.max(1));
    let served = serve_queries(
        session,
        keys,
        Role::Trainer,
        id,
        &inbox,
        stop,
        |is_status, q, body| {
            if is_status {
                job_query(&shared, &key_tail(q, "job id")?, &body)
            } else if body.is_empty() {
                to_json(&lock(&shared.jobs).list())
            } else {
                submit(&shared, trainer.as_ref(), data_root, id, &body)
            }
        },
    );
    shared.done.store(true, Ordering::Relaxed);
    for f in lock(&shared.cancel).values() {
        f.store(true, Ordering::Relaxed);
    }
    shared.wake.notify_all();
    for w in workers {
        let _ = w.join();
    }
    served
}

/// Largest job spec (JSON) a trainer accepts (PROTOCOL.md, "Limits"): every job's spec is kept
/// with its record, so this and [`super::jobs::MAX_FINISHED_JOBS`] bound what a peer can make
/// the trainer keep.
pub const MAX_JOB_SPEC: usize = 64 << 10;

/// `…/jobs/{job}`: the record, after an optional `{"cancel": true}`.
fn job_query(shared: &Shared, job: &str, body: &[u8]) -> Reply {
    if !body.is_empty() {
        #[derive(Deserialize)]
        #[serde(deny_unknown_fields)]
        struct Cmd {
            cancel: bool,
        }
        let c: Cmd = parse_json("job command", body)?;
        if c.cancel {
            let mut jobs = lock(&shared.jobs);
            jobs.cancel_queued(job);
            shared.cancel_running(job);
        }
    }
    let jobs = lock(&shared.jobs);
    let r = jobs
        .get(job)
        .ok_or_else(|| ErrorReply::new(ErrorCode::NotFound, format!("no job '{job}'")))?;
    to_json(r)
}

/// `…/jobs` with a body: a new job (or the unfinished one with the same spec).
fn submit(
    shared: &Shared,
    trainer: &dyn Trainer,
    data_root: &DataRoot,
    id: &str,
    body: &[u8],
) -> Reply {
    if body.len() > MAX_JOB_SPEC {
        return Err(ErrorReply::new(
            ErrorCode::TooLarge,
            format!(
                "a job spec of {} bytes (at most {MAX_JOB_SPEC})",
                body.len()
            ),
        ));
    }
    let spec: JobSpec = parse_json("job", body)?;
    validate_chunk("model name", &spec.model).map_err(|e| e.to_reply())?;
    let spec = super::confine(data_root, spec)?;
    trainer.validate(&spec)?;
    let mut jobs = lock(&shared.jobs);
    jobs.admit(&spec)?;
    let s = jobs.submit(spec);
    if s.existing {
        tracing::info!(
            "trainer '{id}': submission equals unfinished job {}",
            s.reply.job
        );
    }
    for job in &s.superseded {
        shared.cancel_running(job);
    }
    drop(jobs);
    shared.wake.notify_one();
    to_json(&s.reply)
}
