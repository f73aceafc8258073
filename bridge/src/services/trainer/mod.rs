//! The trainer service: accepts training jobs at `…/trainer/{id}/jobs`, runs up to `max_jobs` of
//! them at once on worker threads, publishes progress, persists every job spec and a checkpoint at
//! every validation so that a restarted service resumes its unfinished jobs where they were, and
//! stores finished models in the store.
//!
//! - [`jobs`]: the job types, the queue and its persistence (no Zenoh, no threads);
//! - [`worker`]: the [`Trainer`] trait and the worker threads;
//! - [`service`]: the Zenoh queryables ([`serve_with`]);
//! - [`client`]: [`submit_and_wait`] and [`submit_and_wait_watching`].

pub mod client;
pub mod jobs;
pub mod service;
pub mod worker;

pub use client::{submit_and_wait, submit_and_wait_watching};
pub use jobs::{
    DatasetRef, JobProgress, JobRecord, JobSpec, JobState, Jobs, SubmitReply, TrainProgress,
};
pub use service::serve_with;
pub use worker::Trainer;

use crate::error::ErrorReply;
use crate::fsutil::DataRoot;

/// `spec` with every `{"path": …}` dataset resolved inside `root` (symlinks followed), or a
/// `forbidden` error that names no file.
pub fn confine(root: &DataRoot, mut spec: JobSpec) -> std::result::Result<JobSpec, ErrorReply> {
    for r in [&mut spec.train, &mut spec.val]
        .into_iter()
        .chain(spec.test.as_mut())
    {
        if let DatasetRef::Path { path } = r {
            *path = root.resolve("dataset path", path)?;
        }
    }
    Ok(spec)
}
