//! The trainer's jobs apart from Zenoh and threads: the wire types of a job, the queue, and the
//! persistence of every record under `{state-dir}/trainer/jobs/{job}.json` (written atomically,
//! under the same lock as the change it records, so a record on disk is never older than one
//! written before it).

use std::collections::{HashMap, VecDeque};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::{Error, ErrorCode, ErrorReply, Result};

/// Where a job's dataset comes from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum DatasetRef {
    /// A `.npz` file inside the trainer's data root.
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

impl JobState {
    /// Queued or running.
    pub fn unfinished(self) -> bool {
        matches!(self, JobState::Queued | JobState::Running)
    }
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
    /// The last progress message (a [`TrainProgress`] as JSON), if any.
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

/// What a running job reports after each iteration.
#[derive(Clone, Debug, Serialize)]
pub struct TrainProgress {
    /// The iteration this attempt started from (0 = from scratch).
    pub resumed_from: u64,
    /// The training loop's own report (iteration, total, loss, validation, ...).
    #[serde(flatten)]
    pub train: koopman::train::Progress,
}

impl TrainProgress {
    /// Whether this is the last iteration.
    pub fn is_last(&self) -> bool {
        self.train.iteration == self.train.total
    }
}

/// A progress publication at `…/trainer/{id}/jobs/{job}/progress`.
#[derive(Clone, Debug, Serialize)]
pub struct JobProgress<'a> {
    /// The job.
    pub job: &'a str,
    /// Its progress.
    #[serde(flatten)]
    pub progress: &'a TrainProgress,
}

/// The last publication of a job: how it ended.
#[derive(Clone, Debug, Serialize)]
pub struct JobEnded<'a> {
    /// The job.
    pub job: &'a str,
    /// Done, failed or cancelled.
    pub state: JobState,
    /// Why it failed or was cancelled.
    pub error: &'a Option<String>,
}

/// What a submission did.
#[derive(Clone, Debug, PartialEq)]
pub struct Submitted {
    /// The reply to send.
    pub reply: SubmitReply,
    /// Whether the spec equals that of an unfinished job (which `reply` names; nothing new).
    pub existing: bool,
    /// Unfinished jobs for the same model with another spec, marked superseded: the caller
    /// cancels the running ones.
    pub superseded: Vec<String>,
}

/// Most unfinished (queued or running) jobs a trainer holds (PROTOCOL.md, "Limits"): a
/// submission of another spec past it is refused with `busy`.
pub const MAX_UNFINISHED_JOBS: usize = 64;
/// Most finished (done, failed, cancelled) job records a trainer keeps: past it the oldest
/// (lowest job number) is forgotten, in memory and on disk, and its status is `not_found`.
pub const MAX_FINISHED_JOBS: usize = 256;

/// The number in a job id (`j0042-…` → 42), by which records are aged.
fn job_number(job: &str) -> usize {
    job.strip_prefix('j')
        .and_then(|j| j.split('-').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or(0)
}

/// The jobs of one trainer: records by id, the queue of job ids, the folder they persist in.
pub struct Jobs {
    dir: PathBuf,
    records: HashMap<String, JobRecord>,
    queue: VecDeque<String>,
    counter: usize,
}

impl Jobs {
    /// Opens the jobs folder `dir` (created if missing): every record found there is loaded,
    /// and every unfinished one is queued again (in job-id order) and persisted as `queued`.
    /// Files that are not job records are skipped.
    pub fn open(dir: &Path) -> Result<Self> {
        let io = |e| Error::Io {
            path: dir.to_path_buf(),
            source: e,
        };
        std::fs::create_dir_all(dir).map_err(io)?;
        let mut found: Vec<JobRecord> = std::fs::read_dir(dir)
            .map_err(io)?
            .filter_map(|e| e.ok())
            .filter(|e| e.path().extension().is_some_and(|x| x == "json"))
            .filter_map(|e| serde_json::from_slice(&std::fs::read(e.path()).ok()?).ok())
            .collect();
        found.sort_by(|a, b| a.job.cmp(&b.job));
        // Job numbers go on from the highest found (records may have been forgotten).
        let counter = found.iter().map(|r| job_number(&r.job)).max().unwrap_or(0);
        let mut jobs = Jobs {
            dir: dir.to_path_buf(),
            records: HashMap::new(),
            queue: VecDeque::new(),
            counter: counter.max(found.len()),
        };
        for mut r in found {
            if r.state.unfinished() {
                tracing::info!("resuming unfinished job {}", r.job);
                r.state = JobState::Queued;
                jobs.persist(&r);
                jobs.queue.push_back(r.job.clone());
            }
            jobs.records.insert(r.job.clone(), r);
        }
        jobs.forget_oldest_finished();
        Ok(jobs)
    }

    /// Whether `spec` may be submitted: always when it equals an unfinished job's spec (that
    /// job is returned), else `busy` when [`MAX_UNFINISHED_JOBS`] are unfinished.
    pub fn admit(&self, spec: &JobSpec) -> std::result::Result<(), ErrorReply> {
        let unfinished = self.records.values().filter(|r| r.state.unfinished());
        let (mut n, mut same) = (0, false);
        for r in unfinished {
            n += 1;
            same |= r.spec == *spec;
        }
        if same || n < MAX_UNFINISHED_JOBS {
            return Ok(());
        }
        Err(ErrorReply::new(
            ErrorCode::Busy,
            format!("{n} jobs are queued or running (at most {MAX_UNFINISHED_JOBS}); submit later"),
        ))
    }

    /// Forgets the oldest finished records (memory and file) past [`MAX_FINISHED_JOBS`].
    fn forget_oldest_finished(&mut self) {
        let mut done: Vec<(usize, String)> = self
            .records
            .values()
            .filter(|r| !r.state.unfinished())
            .map(|r| (job_number(&r.job), r.job.clone()))
            .collect();
        if done.len() <= MAX_FINISHED_JOBS {
            return;
        }
        done.sort();
        for (_, job) in &done[..done.len() - MAX_FINISHED_JOBS] {
            self.records.remove(job);
            let _ = std::fs::remove_file(self.dir.join(format!("{job}.json")));
        }
    }

    /// The folder the records persist in.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The record of `job`.
    pub fn get(&self, job: &str) -> Option<&JobRecord> {
        self.records.get(job)
    }

    /// Every record, in job-id order.
    pub fn list(&self) -> Vec<&JobRecord> {
        let mut v: Vec<&JobRecord> = self.records.values().collect();
        v.sort_by(|a, b| a.job.cmp(&b.job));
        v
    }

    /// Submits `spec`: a spec equal to that of an unfinished job returns that job (idempotent,
    /// so that a restarted client finds its job again); otherwise a new queued job, and the
    /// unfinished jobs for the same model with another spec are superseded (a queued one is
    /// cancelled here; a running one is named in [`Submitted::superseded`] for the caller to
    /// stop — the newer job would overwrite its model anyway).
    pub fn submit(&mut self, spec: JobSpec) -> Submitted {
        let same = self
            .list()
            .into_iter()
            .find(|r| r.state.unfinished() && r.spec == spec)
            .map(|r| SubmitReply {
                job: r.job.clone(),
                state: r.state,
            });
        if let Some(reply) = same {
            return Submitted {
                reply,
                existing: true,
                superseded: Vec::new(),
            };
        }
        self.counter += 1;
        let job = new_job_id(self.counter);
        let stale: Vec<String> = self
            .list()
            .into_iter()
            .filter(|r| r.state.unfinished() && r.spec.model == spec.model)
            .map(|r| r.job.clone())
            .collect();
        for s in &stale {
            tracing::info!("job {s} is superseded by job {job} (same model, another spec)");
            self.update(s, |r| {
                r.error = Some(format!("superseded by job {job}"));
                if r.state == JobState::Queued {
                    r.state = JobState::Cancelled;
                }
            });
        }
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
        self.persist(&r);
        self.records.insert(job.clone(), r);
        self.queue.push_back(job.clone());
        self.forget_oldest_finished();
        Submitted {
            reply: SubmitReply {
                job,
                state: JobState::Queued,
            },
            existing: false,
            superseded: stale,
        }
    }

    /// Cancels `job` if it is still queued (a running one is stopped by its worker).
    pub fn cancel_queued(&mut self, job: &str) {
        self.update(job, |r| {
            if r.state == JobState::Queued {
                r.state = JobState::Cancelled;
            }
        });
    }

    /// The next queued job, now `running` (one more attempt, from iteration 0 until the
    /// trainer reports otherwise) and persisted; jobs cancelled while queued are skipped.
    pub fn start_next(&mut self) -> Option<JobRecord> {
        while let Some(job) = self.queue.pop_front() {
            let started = self.update(&job, |r| {
                if r.state == JobState::Queued {
                    r.state = JobState::Running;
                    r.attempts += 1;
                    r.resumed_from = 0;
                }
            });
            if let Some(r) = started.filter(|r| r.state == JobState::Running) {
                return Some(r);
            }
        }
        None
    }

    /// Keeps the latest progress of a running job (in memory: the record on disk is rewritten
    /// when the job changes state).
    pub fn progress(&mut self, job: &str, p: &TrainProgress) {
        if let Some(r) = self.records.get_mut(job) {
            r.resumed_from = p.resumed_from;
            r.progress = serde_json::to_value(p).ok();
        }
    }

    /// Ends `job`: `Ok(metrics)` = done; `Err((cancelled, message))` = cancelled (keeping an
    /// earlier reason such as "superseded by …") or failed. Persists and returns the record.
    pub fn finish(
        &mut self,
        job: &str,
        outcome: std::result::Result<serde_json::Value, (bool, String)>,
    ) -> Option<JobRecord> {
        let r = self.update(job, |r| match outcome {
            Ok(metrics) => {
                r.state = JobState::Done;
                r.metrics = Some(metrics);
            }
            Err((true, message)) => {
                r.state = JobState::Cancelled;
                r.error.get_or_insert(message);
            }
            Err((false, message)) => {
                r.state = JobState::Failed;
                r.error = Some(message);
            }
        });
        self.forget_oldest_finished();
        r
    }

    /// Applies `f` to the record of `job` and persists it; returns the new record.
    pub fn update(&mut self, job: &str, f: impl FnOnce(&mut JobRecord)) -> Option<JobRecord> {
        let r = self.records.get_mut(job)?;
        f(r);
        let r = r.clone();
        self.persist(&r);
        Some(r)
    }

    fn persist(&self, r: &JobRecord) {
        let p = self.dir.join(format!("{}.json", r.job));
        let ok = serde_json::to_vec_pretty(r)
            .ok()
            .and_then(|b| koopman::fsutil::write_atomic(&p, &b).ok());
        if ok.is_none() {
            tracing::warn!("could not persist job {} to {}", r.job, p.display());
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

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("kb-jobs-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    fn spec(model: &str, iterations: u64) -> JobSpec {
        JobSpec {
            model: model.into(),
            train: DatasetRef::Recording {
                recording: "tr".into(),
            },
            val: DatasetRef::Path {
                path: "/data/val.npz".into(),
            },
            test: None,
            config: serde_json::json!({"iterations": iterations})
                .as_object()
                .unwrap()
                .clone(),
        }
    }

    fn on_disk(dir: &Path, job: &str) -> JobRecord {
        serde_json::from_slice(&std::fs::read(dir.join(format!("{job}.json"))).unwrap()).unwrap()
    }

    #[test]
    fn submissions_are_idempotent_queued_in_order_and_persisted() {
        let dir = scratch("submit");
        let mut jobs = Jobs::open(&dir).unwrap();
        let a = jobs.submit(spec("a", 10));
        assert!(!a.existing && a.superseded.is_empty());
        assert_eq!(a.reply.state, JobState::Queued);
        // The same spec again: the same job, nothing new.
        let again = jobs.submit(spec("a", 10));
        assert!(again.existing);
        assert_eq!(again.reply.job, a.reply.job);
        let b = jobs.submit(spec("b", 10));
        assert_eq!(jobs.list().len(), 2);
        assert_eq!(on_disk(&dir, &b.reply.job).state, JobState::Queued);
        // Started in submission order, each persisted as running with one attempt.
        let first = jobs.start_next().unwrap();
        assert_eq!(
            (first.job.as_str(), first.attempts),
            (a.reply.job.as_str(), 1)
        );
        assert_eq!(on_disk(&dir, &first.job).state, JobState::Running);
        // A running job's spec still finds it.
        let running = jobs.submit(spec("a", 10));
        assert_eq!(
            (running.reply.job.as_str(), running.reply.state),
            (a.reply.job.as_str(), JobState::Running)
        );
        jobs.cancel_queued(&b.reply.job);
        assert!(jobs.start_next().is_none(), "a cancelled job is skipped");
        assert_eq!(on_disk(&dir, &b.reply.job).state, JobState::Cancelled);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn another_spec_for_the_same_model_supersedes_the_unfinished_jobs() {
        let dir = scratch("supersede");
        let mut jobs = Jobs::open(&dir).unwrap();
        let running = jobs.submit(spec("m", 10)).reply.job;
        jobs.start_next().unwrap();
        let queued = jobs.submit(spec("m", 20)).reply.job;
        let newest = jobs.submit(spec("m", 30));
        // Both older ones are named; the queued one is cancelled here, the running one is the
        // caller's to stop.
        assert_eq!(newest.superseded.len(), 2);
        assert!(newest.superseded.contains(&running) && newest.superseded.contains(&queued));
        let q = jobs.get(&queued).unwrap();
        assert_eq!(q.state, JobState::Cancelled);
        let why = format!("superseded by job {}", newest.reply.job);
        assert_eq!(q.error.as_deref(), Some(why.as_str()));
        assert_eq!(jobs.get(&running).unwrap().state, JobState::Running);
        // Its worker stops it: cancelled, keeping the reason.
        let r = jobs
            .finish(&running, Err((true, "cancelled".into())))
            .unwrap();
        assert_eq!(
            (r.state, r.error.as_deref()),
            (JobState::Cancelled, Some(why.as_str()))
        );
        assert_eq!(on_disk(&dir, &running).state, JobState::Cancelled);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_reopened_folder_requeues_unfinished_jobs_and_keeps_finished_ones() {
        let dir = scratch("reopen");
        let (done, failed, running, queued) = {
            let mut jobs = Jobs::open(&dir).unwrap();
            let ids: Vec<String> = (0..4)
                .map(|i| jobs.submit(spec(&format!("m{i}"), 10)).reply.job)
                .collect();
            for _ in 0..3 {
                jobs.start_next().unwrap();
            }
            jobs.finish(&ids[0], Ok(serde_json::json!({"iterations": 10})));
            jobs.finish(&ids[1], Err((false, "diverged".into())));
            (
                ids[0].clone(),
                ids[1].clone(),
                ids[2].clone(),
                ids[3].clone(),
            )
        };
        std::fs::write(dir.join("junk.json"), b"{not a record").unwrap();
        std::fs::write(dir.join(format!("{running}.ckpt")), b"checkpoint").unwrap();
        let mut jobs = Jobs::open(&dir).unwrap();
        assert_eq!(jobs.list().len(), 4, "the junk file is skipped");
        assert_eq!(jobs.get(&done).unwrap().state, JobState::Done);
        assert_eq!(
            jobs.get(&failed).unwrap().error.as_deref(),
            Some("diverged")
        );
        assert_eq!(on_disk(&dir, &running).state, JobState::Queued);
        let a = jobs.start_next().unwrap();
        let b = jobs.start_next().unwrap();
        assert_eq!((a.job, a.attempts), (running, 2));
        assert_eq!((b.job, b.attempts), (queued, 1));
        assert!(jobs.start_next().is_none());
        // New ids never reuse an old one.
        let fresh = jobs.submit(spec("m9", 10)).reply.job;
        assert!(jobs.list().iter().filter(|r| r.job == fresh).count() == 1);
        assert!(fresh.starts_with("j0005-"), "{fresh}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A peer cannot make a trainer keep more than the limits: `busy` past
    /// [`MAX_UNFINISHED_JOBS`] (a repeated spec still finds its job), and the oldest finished
    /// records forgotten past [`MAX_FINISHED_JOBS`], in memory and on disk, numbers going on.
    #[test]
    fn unfinished_jobs_and_finished_records_are_bounded() {
        let dir = scratch("limits");
        let mut jobs = Jobs::open(&dir).unwrap();
        let ids: Vec<String> = (0..MAX_UNFINISHED_JOBS)
            .map(|i| jobs.submit(spec(&format!("m{i}"), 10)).reply.job)
            .collect();
        let e = jobs.admit(&spec("another", 10)).unwrap_err();
        assert_eq!(e.code, ErrorCode::Busy);
        assert!(jobs.admit(&spec("m3", 10)).is_ok(), "the same spec again");
        // Finish them all and more: only the newest MAX_FINISHED_JOBS records stay.
        let total = MAX_FINISHED_JOBS + 10;
        for i in 0..total {
            let job = if i < ids.len() {
                ids[i].clone()
            } else {
                jobs.admit(&spec(&format!("m{i}"), 10)).unwrap();
                jobs.submit(spec(&format!("m{i}"), 10)).reply.job
            };
            jobs.start_next().unwrap();
            jobs.finish(&job, Ok(serde_json::json!({})));
        }
        assert_eq!(jobs.list().len(), MAX_FINISHED_JOBS);
        assert!(jobs.get(&ids[0]).is_none() && jobs.get(&ids[9]).is_none());
        assert!(jobs.get(&ids[10]).is_some());
        assert!(!dir.join(format!("{}.json", ids[0])).exists());
        let files = std::fs::read_dir(&dir).unwrap().count();
        assert_eq!(files, MAX_FINISHED_JOBS);
        // Reopened: the numbers go on after the highest, not after the count.
        let mut jobs = Jobs::open(&dir).unwrap();
        let next = jobs.submit(spec("z", 1)).reply.job;
        assert_eq!(job_number(&next), total + 1, "{next}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
