//! The sweep driver: submits the points of a [`SweepGrid`](super::SweepGrid) to every trainer
//! service that answers, least loaded first, follows their jobs and liveliness, moves the points
//! of a trainer that vanished to the others, and writes each finished point's model, metrics and
//! result row into the sweep's folder (so that a rerun skips it).

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use koopman::data::Dataset;
use koopman::train::TrainMetrics;
use serde::{Deserialize, Serialize};

use super::budget::record_budgets;
use super::grid::{Regularisers, SweepPoint};
use super::ledger::{Ledger, PointState};
use crate::client::{Client, Liveliness};
use crate::error::{Error, ErrorCode, Result};
use crate::keyexpr::Role;
use crate::services::trainer::{DatasetRef, JobRecord, JobSpec, JobState, SubmitReply};

/// The datasets every point trains on, as the trainers are to find them, and the test set as
/// this process reads it (for the conditioning figures of each result).
pub struct SweepData {
    /// Training pool.
    pub train: DatasetRef,
    /// Validation set.
    pub val: DatasetRef,
    /// Test set.
    pub test: DatasetRef,
    /// The test set itself.
    pub test_set: Dataset,
}

/// How the sweep runs.
#[derive(Clone, Debug)]
pub struct SweepOptions {
    /// The sweep's folder: `runs/{point}/` (model, metrics.json, result.json) and `results.csv`.
    pub out: PathBuf,
    /// Queued + running jobs a trainer may hold before it gets no more points.
    pub per_trainer: usize,
    /// How long a vanished trainer keeps its points before they go to the others.
    pub grace: Duration,
    /// Attempts of a point whose job fails before it is given up.
    pub max_attempts: u32,
    /// How long the sweep waits while no trainer answers before it gives up.
    pub no_trainer_timeout: Duration,
    /// Time between two rounds of status queries.
    pub poll: Duration,
}

impl SweepOptions {
    /// Defaults for a sweep into `out`: 1 job per trainer, 30 s grace, 2 attempts, 120 s without
    /// any trainer, 0.5 s polling.
    pub fn new(out: PathBuf) -> Self {
        SweepOptions {
            out,
            per_trainer: 1,
            grace: Duration::from_secs(30),
            max_attempts: 2,
            no_trainer_timeout: Duration::from_secs(120),
            poll: Duration::from_millis(500),
        }
    }
}

/// One finished point: a row of `results.csv`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PointResult {
    /// Point (and model) name.
    pub name: String,
    /// Environment of the data.
    pub env: String,
    /// Input/transition pairing of the data.
    pub pairing: String,
    /// Training windows m.
    pub m: usize,
    /// Encoder width multiplier.
    pub n_mult: usize,
    /// Latent dimension N = nx + n_mult · nx.
    pub latent_dim: usize,
    /// Training seed.
    pub seed: u64,
    /// Auxiliary losses.
    pub regularisers: Regularisers,
    /// Iterations trained.
    pub iterations: usize,
    /// Test prediction error (SPEC's metric).
    pub test_error: f64,
    /// κ(G) of the latent Gram matrix on the test set.
    pub gram_condition: Option<f64>,
    /// κ(BᵀB).
    pub bbt_condition: Option<f64>,
    /// Wall time of the training in seconds.
    pub wall_seconds: f64,
    /// The trainer that trained it.
    pub trainer: String,
    /// The budget factors c whose curve m = c·N·ln N it lies on (empty for a fixed-m point and
    /// in results written before budgets existed).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub budgets: Vec<f64>,
}

/// The columns of `results.csv`, in order.
pub const CSV_HEADER: &str = "name,env,pairing,m,n_mult,latent_dim,seed,regularisers,iterations,\
test_error,gram_condition,bbt_condition,wall_seconds,trainer,budgets";

impl PointResult {
    /// Its CSV row (no quoting is needed: every text field is a key chunk or a known name; the
    /// budget factors are separated by `;`).
    pub fn csv_row(&self) -> String {
        let opt = |v: Option<f64>| v.map_or(String::new(), |x| format!("{x:e}"));
        let budgets: Vec<String> = self.budgets.iter().map(f64::to_string).collect();
        format!(
            "{},{},{},{},{},{},{},{},{},{:e},{},{},{:.3},{},{}",
            self.name,
            self.env,
            self.pairing,
            self.m,
            self.n_mult,
            self.latent_dim,
            self.seed,
            self.regularisers.as_str(),
            self.iterations,
            self.test_error,
            opt(self.gram_condition),
            opt(self.bbt_condition),
            self.wall_seconds,
            self.trainer,
            budgets.join(";")
        )
    }
}

/// What the driver reports as it goes.
#[derive(Debug)]
pub enum SweepEvent<'a> {
    /// Points found finished in the folder at the start.
    Resumed {
        /// How many.
        done: usize,
    },
    /// A point went to a trainer (or was found there already).
    Submitted {
        /// The point.
        point: &'a SweepPoint,
        /// Trainer id.
        trainer: &'a str,
        /// Job id.
        job: &'a str,
    },
    /// A point's trainer vanished longer than the grace period; the point waits for another.
    Moved {
        /// The point.
        point: &'a SweepPoint,
    },
    /// A point finished.
    Finished {
        /// The point.
        point: &'a SweepPoint,
        /// Its result.
        result: &'a PointResult,
    },
    /// A point's job failed (`retry`: it will be tried again).
    Failed {
        /// The point.
        point: &'a SweepPoint,
        /// Why.
        error: &'a str,
        /// Whether it is tried again.
        retry: bool,
    },
    /// A running point's latest training progress (once per status round).
    Progress {
        /// The point.
        point: &'a SweepPoint,
        /// Trainer id.
        trainer: &'a str,
        /// Iterations done.
        iteration: u64,
        /// Iterations in all.
        total: u64,
    },
    /// The trainers that answer changed.
    Trainers {
        /// Their ids.
        alive: &'a [String],
    },
}

/// How a sweep ended.
#[derive(Debug, Default)]
pub struct SweepSummary {
    /// Points finished (this run and earlier ones).
    pub done: usize,
    /// Points given up, with their last error.
    pub failed: Vec<(String, String)>,
}

/// Where point `name`'s run folder is.
pub fn run_dir(out: &Path, name: &str) -> PathBuf {
    out.join("runs").join(name)
}

/// Reads every `runs/*/result.json` of a sweep folder (sorted by name).
pub fn read_results(out: &Path) -> Result<Vec<PointResult>> {
    let runs = out.join("runs");
    let mut v = Vec::new();
    let Ok(rd) = std::fs::read_dir(&runs) else {
        return Ok(v);
    };
    for e in rd.flatten() {
        let p = e.path().join("result.json");
        if let Ok(bytes) = std::fs::read(&p) {
            let r: PointResult = serde_json::from_slice(&bytes)
                .map_err(|e| Error::Config(format!("{}: not a sweep result: {e}", p.display())))?;
            v.push(r);
        }
    }
    v.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(v)
}

/// Writes `results.csv` from every finished point of the folder (atomically).
pub fn write_csv(out: &Path) -> Result<PathBuf> {
    let mut s = String::from(CSV_HEADER);
    s.push('\n');
    for r in read_results(out)? {
        s.push_str(&r.csv_row());
        s.push('\n');
    }
    let p = out.join("results.csv");
    koopman::fsutil::write_atomic(&p, s.as_bytes())?;
    Ok(p)
}

fn spec_of(p: &SweepPoint, data: &SweepData) -> JobSpec {
    JobSpec {
        model: p.name.clone(),
        train: data.train.clone(),
        val: data.val.clone(),
        test: Some(data.test.clone()),
        config: p.config(),
    }
}

/// Runs the sweep until every point is finished or given up.
pub fn run_sweep(
    client: &Client,
    live: &Liveliness,
    points: &[SweepPoint],
    data: &SweepData,
    opts: &SweepOptions,
    on_event: &mut dyn FnMut(SweepEvent<'_>),
) -> Result<SweepSummary> {
    let mut ledger = Ledger::new(points.len(), opts.max_attempts, opts.grace);
    let by_name: HashMap<&str, usize> = points
        .iter()
        .enumerate()
        .map(|(i, p)| (p.name.as_str(), i))
        .collect();
    let specs: Vec<JobSpec> = points.iter().map(|p| spec_of(p, data)).collect();
    let mut resumed = 0;
    for (i, p) in points.iter().enumerate() {
        let dir = run_dir(&opts.out, &p.name);
        if dir.join("result.json").is_file() {
            // A point trained earlier (at a fixed m, or on another budget curve) joins the
            // budget curves it lies on in this sweep.
            record_budgets(&dir, &p.budgets)?;
            ledger.done(i);
            resumed += 1;
        }
    }
    on_event(SweepEvent::Resumed { done: resumed });
    let mut fetch_failures: HashMap<usize, u32> = HashMap::new();
    let mut last_alive: Vec<String> = Vec::new();
    let mut no_trainer_since: Option<Instant> = None;
    let mut summary = SweepSummary::default();
    while !ledger.finished() {
        let now = Instant::now();
        let alive_list = live.alive_ids(Role::Trainer);
        if alive_list != last_alive {
            on_event(SweepEvent::Trainers { alive: &alive_list });
            last_alive = alive_list.clone();
        }
        let alive: BTreeSet<String> = alive_list.iter().cloned().collect();
        if alive.is_empty() {
            let since = *no_trainer_since.get_or_insert(now);
            if now.duration_since(since) > opts.no_trainer_timeout {
                return Err(Error::Timeout {
                    who: "trainer services".into(),
                    what: format!(
                        "any trainer (no '…/alive/trainer/*' token); {} of {} points done",
                        ledger.counts().2,
                        points.len()
                    ),
                    after_ms: opts.no_trainer_timeout.as_millis() as u64,
                });
            }
        } else {
            no_trainer_since = None;
        }
        for i in ledger.follow_liveliness(&alive, now) {
            on_event(SweepEvent::Moved { point: &points[i] });
        }
        // Orphans of points already elsewhere are cancelled first, before they can finish.
        for (t, job, i) in ledger.orphans_to_cancel(&alive) {
            if *ledger.state(i) != PointState::Waiting && cancel(client, &t, &job).is_ok() {
                ledger.orphans_cancelled(&t, &job);
            }
        }
        // One status round: each trainer's job list gives its load and the fate of our jobs.
        let mut load: BTreeMap<String, usize> = BTreeMap::new();
        for t in &alive {
            let Ok(records) = list_jobs(client, t) else {
                continue;
            };
            load.insert(
                t.clone(),
                records
                    .iter()
                    .filter(|r| matches!(r.state, JobState::Queued | JobState::Running))
                    .count(),
            );
            for r in &records {
                let Some(&i) = by_name.get(r.spec.model.as_str()) else {
                    continue;
                };
                if r.spec != specs[i] {
                    continue;
                }
                let ours = matches!(ledger.state(i),
                    PointState::Submitted { trainer, job, .. } if trainer == t && *job == r.job);
                let waiting = *ledger.state(i) == PointState::Waiting;
                match r.state {
                    // A job found unfinished on a trainer (an earlier run of this sweep) is
                    // adopted rather than trained again.
                    JobState::Queued | JobState::Running if waiting => {
                        // A trainer back from the dead resumes the job from its checkpoint:
                        // keep it rather than cancel it as an orphan.
                        ledger.orphans_cancelled(t, &r.job);
                        ledger.submitted(i, t, &r.job);
                        on_event(SweepEvent::Submitted {
                            point: &points[i],
                            trainer: t,
                            job: &r.job,
                        });
                    }
                    JobState::Done if ours || waiting => {
                        match finish(client, &points[i], t, r, data, opts) {
                            Ok(res) => {
                                ledger.done(i);
                                let _ = write_csv(&opts.out);
                                on_event(SweepEvent::Finished {
                                    point: &points[i],
                                    result: &res,
                                });
                            }
                            Err(e) => {
                                let n = fetch_failures.entry(i).or_default();
                                *n += 1;
                                if *n >= 10 {
                                    let msg = format!("collecting the result: {e}");
                                    ledger.give_up(i, &msg);
                                    on_event(SweepEvent::Failed {
                                        point: &points[i],
                                        error: &msg,
                                        retry: false,
                                    });
                                }
                            }
                        }
                    }
                    JobState::Running if ours => {
                        let field = |k: &str| {
                            r.progress
                                .as_ref()
                                .and_then(|p| p.get(k))
                                .and_then(|v| v.as_u64())
                        };
                        if let (Some(iteration), Some(total)) = (field("iteration"), field("total"))
                        {
                            on_event(SweepEvent::Progress {
                                point: &points[i],
                                trainer: t,
                                iteration,
                                total,
                            });
                        }
                    }
                    JobState::Failed | JobState::Cancelled if ours => {
                        let msg = r
                            .error
                            .clone()
                            .unwrap_or_else(|| format!("job {:?}", r.state));
                        ledger.failed(i, &msg);
                        on_event(SweepEvent::Failed {
                            point: &points[i],
                            error: &msg,
                            retry: *ledger.state(i) == PointState::Waiting,
                        });
                    }
                    _ => {}
                }
            }
        }
        // Orphans not adopted above (their points are elsewhere now) are cancelled.
        for (t, job, _) in ledger.orphans_to_cancel(&alive) {
            if cancel(client, &t, &job).is_ok() {
                ledger.orphans_cancelled(&t, &job);
            }
        }
        for (i, t) in ledger.assign(&load, opts.per_trainer) {
            match submit(client, &t, &specs[i]) {
                Ok(job) => {
                    ledger.submitted(i, &t, &job);
                    on_event(SweepEvent::Submitted {
                        point: &points[i],
                        trainer: &t,
                        job: &job,
                    });
                }
                Err(e) => {
                    // A typed refusal (bad request, forbidden) will not change: give the point
                    // up. Anything else (the trainer went away) is retried next round.
                    if let Error::Remote { reply, .. } = &e {
                        if matches!(
                            reply.code,
                            ErrorCode::BadRequest | ErrorCode::NotFound | ErrorCode::Forbidden
                        ) {
                            let mut msg = e.to_string();
                            if reply.code == ErrorCode::Forbidden {
                                msg.push_str(&format!(
                                    " (trainer '{t}' reads datasets only inside its --data-root: \
                                     start it with --data-root holding the data, or run the \
                                     sweep with --serve-data)"
                                ));
                            }
                            ledger.give_up(i, &msg);
                            on_event(SweepEvent::Failed {
                                point: &points[i],
                                error: &msg,
                                retry: false,
                            });
                        }
                    }
                }
            }
        }
        if ledger.finished() {
            break;
        }
        std::thread::sleep(opts.poll);
    }
    for (i, p) in points.iter().enumerate() {
        match ledger.state(i) {
            PointState::Done => summary.done += 1,
            PointState::Failed { error, .. } => {
                summary.failed.push((p.name.clone(), error.clone()))
            }
            _ => {}
        }
    }
    Ok(summary)
}

fn who(t: &str) -> String {
    format!("trainer '{t}'")
}

fn list_jobs(client: &Client, t: &str) -> Result<Vec<JobRecord>> {
    let b = client.query(
        &client.keys.trainer_jobs(t)?,
        Vec::new(),
        Duration::from_secs(5),
        &who(t),
    )?;
    serde_json::from_slice(&b)
        .map_err(|e| Error::protocol(ErrorCode::BadRequest, format!("{}: {e}", who(t))))
}

fn submit(client: &Client, t: &str, spec: &JobSpec) -> Result<String> {
    let body = serde_json::to_vec(spec).map_err(|e| Error::Config(e.to_string()))?;
    let b = client.query(
        &client.keys.trainer_jobs(t)?,
        body,
        Duration::from_secs(10),
        &who(t),
    )?;
    let r: SubmitReply = serde_json::from_slice(&b)
        .map_err(|e| Error::protocol(ErrorCode::BadRequest, format!("{}: {e}", who(t))))?;
    Ok(r.job)
}

fn cancel(client: &Client, t: &str, job: &str) -> Result<()> {
    client.query(
        &client.keys.trainer_job(t, job)?,
        br#"{"cancel": true}"#.to_vec(),
        Duration::from_secs(5),
        &who(t),
    )?;
    Ok(())
}

/// Collects a finished job: the model from whichever store has it, its metrics, the
/// conditioning figures on the test set, and the result row, all under `runs/{point}/`.
fn finish(
    client: &Client,
    p: &SweepPoint,
    trainer: &str,
    r: &JobRecord,
    data: &SweepData,
    opts: &SweepOptions,
) -> Result<PointResult> {
    let mut metrics_json = r
        .metrics
        .clone()
        .ok_or_else(|| Error::Config(format!("job {} has no metrics", r.job)))?;
    let metrics: TrainMetrics = serde_json::from_value(metrics_json.clone())
        .map_err(|e| Error::Config(format!("job {} metrics: {e}", r.job)))?;
    // The run folder reads like one of `koopbridge train` (which `koopbridge scaling` reads).
    if let Some(o) = metrics_json.as_object_mut() {
        o.insert("model".into(), "koopman".into());
        o.insert("trainer".into(), trainer.into());
        if !p.budgets.is_empty() {
            o.insert("budgets".into(), serde_json::json!(p.budgets));
        }
    }
    let bytes = client.query_first_ok(
        &client.keys.model(&p.name)?,
        Vec::new(),
        Duration::from_secs(60),
        &format!("model store ({})", p.name),
    )?;
    let runs = opts.out.join("runs");
    std::fs::create_dir_all(&runs).map_err(|e| Error::Io {
        path: runs.clone(),
        source: e,
    })?;
    // The archive of another model is refused before it could replace that model's run.
    let dir = crate::services::models::unpack_model(&bytes, &runs, &p.name)?;
    koopman::fsutil::write_atomic(
        &dir.join("metrics.json"),
        &serde_json::to_vec_pretty(&metrics_json).map_err(|e| Error::Config(e.to_string()))?,
    )?;
    let model = koopman::model::load_lifted(&dir)?;
    let gram_condition = koopman::analysis::gram_condition(model.as_ref(), &data.test_set).ok();
    let bbt_condition = if model.nu() > 0 {
        koopman::analysis::bbt_condition(model.as_ref()).ok()
    } else {
        None
    };
    let res = PointResult {
        name: p.name.clone(),
        env: metrics.env.clone(),
        pairing: format!("{:?}", metrics.pairing).to_lowercase(),
        m: metrics.train_samples,
        n_mult: p.n_mult,
        latent_dim: model.latent_dim(),
        seed: p.seed,
        regularisers: p.regularisers,
        iterations: metrics.iterations,
        test_error: metrics
            .test_prediction_error
            .ok_or_else(|| Error::Config(format!("job {} has no test prediction error", r.job)))?,
        gram_condition,
        bbt_condition,
        wall_seconds: metrics.wall_seconds,
        trainer: trainer.to_string(),
        budgets: p.budgets.clone(),
    };
    koopman::fsutil::write_atomic(
        &dir.join("result.json"),
        &serde_json::to_vec_pretty(&res).map_err(|e| Error::Config(e.to_string()))?,
    )?;
    Ok(res)
}
