//! The trainer service: accepts training jobs at `…/trainer/{id}/jobs`, runs up to `max_jobs` of
//! them at once on worker threads, publishes progress, persists every job spec and a checkpoint at
//! every validation so that a restarted service resumes its unfinished jobs where they were, and
//! stores finished models in the store.

use std::collections::{HashMap, VecDeque};
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::Duration;

use serde::{Deserialize, Serialize};
use zenoh::{Session, Wait};

use super::{key_tail, parse_json, serve_queries, to_json, Inbox};
use crate::error::{Error, ErrorCode, ErrorReply, Result};
use crate::keyexpr::{validate_chunk, Keys, Role};

/// Where a job's dataset comes from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum DatasetRef {
    /// A `.npz` file readable by the service.
    Path {
        /// Its path.
        path: PathBuf,
    },
    /// A recording served by a recorder at `…/data/{recording}`.
    Recording {
        /// Its name.
        recording: String,
    },
}

/// A training job.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JobSpec {
    /// Name of the finished model in the store (`[a-z0-9_-]`).
    pub model: String,
    /// Training windows.
    pub train: DatasetRef,
    /// Validation windows.
    pub val: DatasetRef,
    /// Test windows (optional).
    #[serde(default)]
    pub test: Option<DatasetRef>,
    /// `koopman::train::TrainConfig` fields (absent fields: SPEC defaults).
    #[serde(default)]
    pub config: serde_json::Map<String, serde_json::Value>,
}

/// Where a job is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum JobState {
    /// Waiting for a worker.
    Queued,
    /// Training.
    Running,
    /// Finished; the model is in the store.
    Done,
    /// Failed; see `error`.
    Failed,
    /// Cancelled on request.
    Cancelled,
}

/// A job and its status (persisted as `jobs/{job}.json`, and the reply of a status query).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobRecord {
    /// Job id.
    pub job: String,
    /// What to do.
    pub spec: JobSpec,
    /// Where it is.
    pub state: JobState,
    /// The last progress message (JSON), if any.
    #[serde(default)]
    pub progress: Option<serde_json::Value>,
    /// Final metrics (JSON) when done.
    #[serde(default)]
    pub metrics: Option<serde_json::Value>,
    /// Error message when failed.
    #[serde(default)]
    pub error: Option<String>,
    /// How many times the job was started (a restarted service resumes unfinished jobs).
    #[serde(default)]
    pub attempts: u32,
    /// Iteration the latest attempt started from (0 = from scratch; > 0 = resumed from the
    /// job's checkpoint).
    #[serde(default)]
    pub resumed_from: u64,
}

/// The `jobs` reply to a submission.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SubmitReply {
    /// The job id (status at `…/trainer/{id}/jobs/{job}`, progress at `…/{job}/progress`).
    pub job: String,
    /// Its state.
    pub state: JobState,
}

/// What actually trains: loads the data, trains, writes the model into `out_dir`, returns metrics.
pub trait Trainer: Send + Sync {
    /// Runs one job. `checkpoint` is the job's checkpoint file: continue from it if it exists
    /// and fits the job, and (re)write it atomically as training goes; the service deletes it
    /// when the job ends. `progress` receives JSON progress messages (a `resumed_from` field is
    /// copied into the job record) and may cancel with `Break`.
    fn train(
        &self,
        spec: &JobSpec,
        out_dir: &Path,
        checkpoint: &Path,
        progress: &mut dyn FnMut(serde_json::Value) -> ControlFlow<()>,
    ) -> Result<serde_json::Value>;
}

struct Shared {
    jobs: Mutex<HashMap<String, JobRecord>>,
    queue: Mutex<VecDeque<String>>,
    wake: Condvar,
    cancel: Mutex<HashMap<String, Arc<AtomicBool>>>,
    dir: PathBuf,
}

fn write_record(dir: &Path, r: &JobRecord) {
    let p = dir.join(format!("{}.json", r.job));
    let ok = serde_json::to_vec_pretty(r)
        .ok()
        .and_then(|b| crate::fsutil::write_atomic(&p, &b).ok());
    if ok.is_none() {
        tracing::warn!("could not persist job {} to {}", r.job, p.display());
    }
}

impl Shared {
    fn update(&self, job: &str, f: impl FnOnce(&mut JobRecord)) -> Option<JobRecord> {
        let mut jobs = self.jobs.lock().unwrap_or_else(|e| e.into_inner());
        let r = jobs.get_mut(job)?;
        f(r);
        Some(r.clone())
    }
}

/// Cancels the unfinished jobs for the same model as `spec` but with another spec: the newer
/// submission `by` would overwrite their model anyway (e.g. a scenario restarted with changed
/// settings must not first finish the stale job of its previous run).
fn supersede(shared: &Shared, spec: &JobSpec, by: &str) {
    let stale: Vec<String> = shared
        .jobs
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .values()
        .filter(|r| {
            matches!(r.state, JobState::Queued | JobState::Running)
                && r.spec.model == spec.model
                && r.spec != *spec
        })
        .map(|r| r.job.clone())
        .collect();
    for job in stale {
        tracing::info!("job {job} is superseded by job {by} (same model, another spec)");
        if let Some(f) = shared
            .cancel
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(&job)
        {
            f.store(true, Ordering::Relaxed);
        }
        if let Some(r) = shared.update(&job, |r| {
            r.error = Some(format!("superseded by job {by}"));
            if r.state == JobState::Queued {
                r.state = JobState::Cancelled;
            }
        }) {
            write_record(&shared.dir, &r);
        }
    }
}

fn new_job_id(n: usize) -> String {
    let t = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis() as u64)
        .unwrap_or(0);
    format!("j{n:04}-{:x}", t & 0xff_ffff)
}

/// Serves trainer `id` with any [`Trainer`]. Unfinished jobs found in `state_dir/jobs` are queued
/// again first (resumed from their checkpoint `jobs/{job}.ckpt` when there is one). Submitting a
/// spec equal to that of a queued or running job returns that job (idempotent submission, so a
/// restarted client finds its job again).
#[allow(clippy::too_many_arguments)]
pub fn serve_with(
    session: &Session,
    keys: &Keys,
    id: &str,
    store: &Path,
    state_dir: &Path,
    max_jobs: usize,
    trainer: Arc<dyn Trainer>,
    stop: &AtomicBool,
) -> Result<()> {
    let dir = state_dir.join("jobs");
    std::fs::create_dir_all(&dir).map_err(|e| Error::Io {
        path: dir.clone(),
        source: e,
    })?;
    std::fs::create_dir_all(store).map_err(|e| Error::Io {
        path: store.to_path_buf(),
        source: e,
    })?;
    let shared = Arc::new(Shared {
        jobs: Mutex::new(HashMap::new()),
        queue: Mutex::new(VecDeque::new()),
        wake: Condvar::new(),
        cancel: Mutex::new(HashMap::new()),
        dir: dir.clone(),
    });
    // Resume: every persisted job that did not finish is queued again.
    let mut found: Vec<JobRecord> = std::fs::read_dir(&dir)
        .map_err(|e| Error::Io {
            path: dir.clone(),
            source: e,
        })?
        .filter_map(|e| e.ok())
        .filter(|e| e.path().extension().is_some_and(|x| x == "json"))
        .filter_map(|e| serde_json::from_slice::<JobRecord>(&std::fs::read(e.path()).ok()?).ok())
        .collect();
    found.sort_by(|a, b| a.job.cmp(&b.job));
    let mut counter = found.len();
    for mut r in found {
        if matches!(r.state, JobState::Queued | JobState::Running) {
            tracing::info!("trainer '{id}': resuming unfinished job {}", r.job);
            r.state = JobState::Queued;
            write_record(&dir, &r);
            shared
                .queue
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .push_back(r.job.clone());
        }
        shared
            .jobs
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(r.job.clone(), r);
    }
    let done = Arc::new(AtomicBool::new(false));
    let mut workers = Vec::new();
    for _ in 0..max_jobs.max(1) {
        let (shared, trainer, done, session, keys, id, store) = (
            shared.clone(),
            trainer.clone(),
            done.clone(),
            session.clone(),
            keys.clone(),
            id.to_string(),
            store.to_path_buf(),
        );
        workers.push(std::thread::spawn(move || {
            worker(
                &shared,
                trainer.as_ref(),
                &done,
                &session,
                &keys,
                &id,
                &store,
            )
        }));
    }
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
                let job = key_tail(q, "job id")?;
                if !body.is_empty() {
                    #[derive(Deserialize)]
                    #[serde(deny_unknown_fields)]
                    struct Cmd {
                        cancel: bool,
                    }
                    let c: Cmd = parse_json("job command", &body)?;
                    if c.cancel {
                        if let Some(f) = shared
                            .cancel
                            .lock()
                            .unwrap_or_else(|e| e.into_inner())
                            .get(&job)
                        {
                            f.store(true, Ordering::Relaxed);
                        }
                        shared.update(&job, |r| {
                            if r.state == JobState::Queued {
                                r.state = JobState::Cancelled;
                            }
                        });
                    }
                }
                let r = shared
                    .jobs
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .get(&job)
                    .cloned()
                    .ok_or_else(|| {
                        ErrorReply::new(ErrorCode::NotFound, format!("no job '{job}'"))
                    })?;
                return to_json(&r);
            }
            if body.is_empty() {
                let jobs = shared.jobs.lock().unwrap_or_else(|e| e.into_inner());
                let mut list: Vec<&JobRecord> = jobs.values().collect();
                list.sort_by(|a, b| a.job.cmp(&b.job));
                return to_json(&list);
            }
            let spec: JobSpec = parse_json("job", &body)?;
            validate_chunk("model name", &spec.model).map_err(|e| e.to_reply())?;
            let same = shared
                .jobs
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .values()
                .filter(|r| {
                    matches!(r.state, JobState::Queued | JobState::Running) && r.spec == spec
                })
                .min_by(|a, b| a.job.cmp(&b.job))
                .map(|r| (r.job.clone(), r.state));
            if let Some((job, state)) = same {
                tracing::info!("trainer '{id}': submission equals unfinished job {job}");
                return to_json(&SubmitReply { job, state });
            }
            counter += 1;
            let job = new_job_id(counter);
            supersede(&shared, &spec, &job);
            let r = JobRecord {
                job: job.clone(),
                spec,
                state: JobState::Queued,
                progress: None,
                metrics: None,
                error: None,
                attempts: 0,
                resumed_from: 0,
            };
            write_record(&dir, &r);
            shared
                .jobs
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .insert(job.clone(), r);
            shared
                .queue
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .push_back(job.clone());
            shared.wake.notify_one();
            to_json(&SubmitReply {
                job,
                state: JobState::Queued,
            })
        },
    );
    done.store(true, Ordering::Relaxed);
    for f in shared
        .cancel
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .values()
    {
        f.store(true, Ordering::Relaxed);
    }
    shared.wake.notify_all();
    for w in workers {
        let _ = w.join();
    }
    served
}

fn worker(
    shared: &Shared,
    trainer: &dyn Trainer,
    done: &AtomicBool,
    session: &Session,
    keys: &Keys,
    id: &str,
    store: &Path,
) {
    loop {
        let job = {
            let mut q = shared.queue.lock().unwrap_or_else(|e| e.into_inner());
            loop {
                if done.load(Ordering::Relaxed) {
                    return;
                }
                if let Some(j) = q.pop_front() {
                    break j;
                }
                q = shared
                    .wake
                    .wait_timeout(q, Duration::from_millis(200))
                    .map(|(g, _)| g)
                    .unwrap_or_else(|e| e.into_inner().0);
            }
        };
        let Some(rec) = shared.update(&job, |r| {
            if r.state == JobState::Queued {
                r.state = JobState::Running;
                r.attempts += 1;
                r.resumed_from = 0;
            }
        }) else {
            continue;
        };
        if rec.state != JobState::Running {
            write_record(&shared.dir, &rec);
            continue;
        }
        write_record(&shared.dir, &rec);
        let flag = Arc::new(AtomicBool::new(false));
        shared
            .cancel
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(job.clone(), flag.clone());
        let progress_key = keys.trainer_progress(id, &job).ok();
        let tmp = store.join(format!(".{}.tmp-{job}", rec.spec.model));
        let checkpoint = shared.dir.join(format!("{job}.ckpt"));
        let _ = std::fs::remove_dir_all(&tmp);
        let mut last_put = std::time::Instant::now() - Duration::from_secs(1);
        let outcome = std::fs::create_dir_all(&tmp)
            .map_err(|e| Error::Io {
                path: tmp.clone(),
                source: e,
            })
            .and_then(|_| {
                trainer.train(&rec.spec, &tmp, &checkpoint, &mut |p| {
                    let last = p.get("iteration").and_then(|v| v.as_u64())
                        == p.get("total").and_then(|v| v.as_u64());
                    if last_put.elapsed() > Duration::from_millis(200)
                        || last
                        || p.get("validation").is_some_and(|v| !v.is_null())
                    {
                        last_put = std::time::Instant::now();
                        if let Some(k) = &progress_key {
                            let mut msg = p.clone();
                            if let Some(o) = msg.as_object_mut() {
                                o.insert("job".into(), job.clone().into());
                            }
                            let _ = session
                                .put(k, serde_json::to_vec(&msg).unwrap_or_default())
                                .wait();
                        }
                        let from = p.get("resumed_from").and_then(|v| v.as_u64());
                        shared.update(&job, |r| {
                            r.resumed_from = from.unwrap_or(r.resumed_from);
                            r.progress = Some(p);
                        });
                    }
                    if flag.load(Ordering::Relaxed) {
                        ControlFlow::Break(())
                    } else {
                        ControlFlow::Continue(())
                    }
                })
            });
        shared
            .cancel
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .remove(&job);
        if done.load(Ordering::Relaxed) && flag.load(Ordering::Relaxed) {
            // The service is stopping: leave the job `running` on disk so that a restart resumes it.
            let _ = std::fs::remove_dir_all(&tmp);
            return;
        }
        let finished = match outcome {
            Ok(metrics) => {
                let final_dir = store.join(&rec.spec.model);
                let _ = std::fs::remove_dir_all(&final_dir);
                let moved = std::fs::write(
                    tmp.join("metrics.json"),
                    serde_json::to_vec_pretty(&metrics).unwrap_or_default(),
                )
                .and_then(|_| std::fs::rename(&tmp, &final_dir));
                shared.update(&job, |r| match moved {
                    Ok(()) => {
                        r.state = JobState::Done;
                        r.metrics = Some(metrics);
                    }
                    Err(e) => {
                        r.state = JobState::Failed;
                        r.error = Some(format!(
                            "could not store the model in {}: {e}",
                            final_dir.display()
                        ));
                    }
                })
            }
            Err(e) => {
                let _ = std::fs::remove_dir_all(&tmp);
                let cancelled = matches!(
                    e,
                    Error::Koopman(koopman::Error::Cancelled) | Error::Stopped
                );
                shared.update(&job, |r| {
                    r.state = if cancelled {
                        JobState::Cancelled
                    } else {
                        JobState::Failed
                    };
                    // A cancelled job keeps the reason it was cancelled for, if it has one.
                    if !(cancelled && r.error.is_some()) {
                        r.error = Some(e.to_string());
                    }
                })
            }
        };
        if let Some(r) = finished {
            // The job has ended (done, failed or cancelled): its checkpoint is of no more use.
            let _ = std::fs::remove_file(&checkpoint);
            tracing::info!("trainer '{id}': job {} {:?}", r.job, r.state);
            write_record(&shared.dir, &r);
            if let Some(k) = &progress_key {
                let msg = serde_json::json!({"job": r.job, "state": r.state, "error": r.error});
                let _ = session
                    .put(k, serde_json::to_vec(&msg).unwrap_or_default())
                    .wait();
            }
        }
    }
}

/// Client side: submits `spec` to trainer `id` and waits for the job to finish, calling
/// `on_progress` with each progress message. Returns the final record; fails if the trainer
/// disappears (liveliness) or the job fails.
pub fn submit_and_wait(
    client: &crate::client::Client,
    live: &crate::client::Liveliness,
    id: &str,
    spec: &JobSpec,
    on_progress: &mut dyn FnMut(&serde_json::Value),
) -> Result<JobRecord> {
    submit_and_wait_watching(client, live, id, spec, &[], on_progress)
}

/// [`submit_and_wait`] that also fails with [`Error::Gone`] naming the participant as soon as one
/// of `watch` (role, id) withdraws its liveliness token (e.g. the simulators of a scenario, which
/// the run needs after training).
pub fn submit_and_wait_watching(
    client: &crate::client::Client,
    live: &crate::client::Liveliness,
    id: &str,
    spec: &JobSpec,
    watch: &[(Role, String)],
    on_progress: &mut dyn FnMut(&serde_json::Value),
) -> Result<JobRecord> {
    let who = format!("trainer '{id}'");
    let body = serde_json::to_vec(spec).map_err(|e| Error::Config(e.to_string()))?;
    let b = client.query(
        &client.keys.trainer_jobs(id)?,
        body,
        Duration::from_secs(30),
        &who,
    )?;
    let sub: SubmitReply = serde_json::from_slice(&b)
        .map_err(|e| Error::protocol(ErrorCode::BadRequest, format!("{who}: {e}")))?;
    let (tx, rx) = std::sync::mpsc::channel::<serde_json::Value>();
    let _sub = client
        .session
        .declare_subscriber(client.keys.trainer_progress(id, &sub.job)?)
        .callback(move |s| {
            if let Ok(v) = serde_json::from_slice(&s.payload().to_bytes()) {
                let _ = tx.send(v);
            }
        })
        .wait()
        .map_err(Error::zenoh)?;
    let status_key = client.keys.trainer_job(id, &sub.job)?;
    let mut last_poll = std::time::Instant::now();
    loop {
        if let Ok(v) = rx.recv_timeout(Duration::from_millis(50)) {
            if v.get("state").is_none() {
                on_progress(&v);
            }
        }
        if live.is_gone(Role::Trainer, id) {
            return Err(Error::Gone(who));
        }
        if let Some((role, other)) = watch.iter().find(|(r, i)| live.is_gone(*r, i)) {
            let what = match role {
                Role::Sim => "simulator",
                r => r.as_str(),
            };
            return Err(Error::Gone(format!("{what} '{other}'")));
        }
        if last_poll.elapsed() > Duration::from_millis(500) {
            last_poll = std::time::Instant::now();
            let b = client.query(&status_key, Vec::new(), Duration::from_secs(10), &who)?;
            let r: JobRecord = serde_json::from_slice(&b)
                .map_err(|e| Error::protocol(ErrorCode::BadRequest, format!("{who}: {e}")))?;
            match r.state {
                JobState::Done => return Ok(r),
                JobState::Failed | JobState::Cancelled => {
                    return Err(Error::Remote {
                        who,
                        reply: ErrorReply::new(
                            ErrorCode::Internal,
                            format!(
                                "job {} {:?}: {}",
                                r.job,
                                r.state,
                                r.error.unwrap_or_default()
                            ),
                        ),
                    })
                }
                _ => {}
            }
        }
    }
}
