//! The JSON control plane for `koopbridge.Client` through the `bridge` crate's own types and
//! functions (model store fetch, MPC `configure`, trainer jobs): no second copy of the protocol.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use bridge::client::Client as Inner;
use bridge::keyexpr::validate_chunk;
use bridge::services::models;
use bridge::services::mpc::{ConfigureReply, ConfigureRequest};
use bridge::services::trainer::{DatasetRef, JobRecord, JobSpec, JobState, SubmitReply};
use bridge::{Error, ErrorCode, Result};
use koopman::mpc::MpcConfig;

/// A JSON reply decoded as `T`, or a `bad_request` protocol error naming `who`.
fn decode<T: serde::de::DeserializeOwned>(who: &str, bytes: &[u8]) -> Result<T> {
    serde_json::from_slice(bytes)
        .map_err(|e| Error::protocol(ErrorCode::BadRequest, format!("{who}: reply: {e}")))
}

fn encode<T: serde::Serialize>(v: &T) -> Result<Vec<u8>> {
    serde_json::to_vec(v).map_err(|e| Error::Config(e.to_string()))
}

/// Fetches model `name` with `bridge::services::models::fetch` into a fresh temporary folder
/// beside `dest`, then moves its model directory to `dest` (replacing an older one) with
/// `koopman::fsutil::commit_dir`. Nothing is left behind on failure. Returns `dest`.
pub fn fetch_model(inner: &Inner, name: &str, dest: &Path, timeout: Duration) -> Result<PathBuf> {
    let dest = std::path::absolute(dest).map_err(|e| Error::Io {
        path: dest.to_path_buf(),
        source: e,
    })?;
    // Removed when dropped, whatever happens below.
    let tmp = koopman::fsutil::TempDir::beside(&dest)?;
    let got = models::fetch(inner, name, tmp.path(), timeout)?;
    koopman::fsutil::commit_dir(&got, &dest)?;
    Ok(dest)
}

/// Configures MPC service `id` with `model` and the MPC settings `mpc` (JSON object of
/// `MpcConfig` fields, plus `offset_free` (an `OffsetFreeConfig` object) for a bilinear model,
/// checked here); returns the service's reply.
pub fn configure_mpc(
    inner: &Inner,
    id: &str,
    model: &str,
    mut mpc: serde_json::Value,
    timeout: Duration,
) -> Result<ConfigureReply> {
    validate_chunk("MPC id", id)?;
    let offset_free = match mpc.as_object_mut().and_then(|o| o.remove("offset_free")) {
        None | Some(serde_json::Value::Null) => None,
        Some(v) => Some(
            serde_json::from_value(v)
                .map_err(|e| Error::Config(format!("MPC configuration: offset_free: {e}")))?,
        ),
    };
    let mpc: MpcConfig = serde_json::from_value(mpc)
        .map_err(|e| Error::Config(format!("MPC configuration: {e}")))?;
    let req = ConfigureRequest {
        model: model.to_string(),
        mpc: Some(mpc),
        offset_free,
    };
    let who = format!("MPC service '{id}'");
    let key = inner.keys.under(&["mpc", id, "configure"]);
    decode(&who, &inner.query(&key, encode(&req)?, timeout, &who)?)
}

/// A dataset reference: `recording:NAME` for a recorder's dataset, else a path (made absolute).
pub fn dataset(d: &str) -> Result<DatasetRef> {
    match d.strip_prefix("recording:") {
        Some(name) => {
            validate_chunk("recording", name)?;
            Ok(DatasetRef::Recording {
                recording: name.to_string(),
            })
        }
        None => Ok(DatasetRef::Path {
            path: std::path::absolute(d).map_err(|e| Error::Io {
                path: d.into(),
                source: e,
            })?,
        }),
    }
}

/// Submits `spec` to trainer `id`; returns the job id.
pub fn submit_job(inner: &Inner, id: &str, spec: &JobSpec, timeout: Duration) -> Result<String> {
    let who = format!("trainer '{id}'");
    let key = inner.keys.trainer_jobs(id)?;
    let r: SubmitReply = decode(&who, &inner.query(&key, encode(spec)?, timeout, &who)?)?;
    Ok(r.job)
}

/// The record of job `job` on trainer `id`.
pub fn job(inner: &Inner, id: &str, job: &str, timeout: Duration) -> Result<JobRecord> {
    let who = format!("trainer '{id}'");
    let key = inner.keys.trainer_job(id, job)?;
    decode(&who, &inner.query(&key, Vec::new(), timeout, &who)?)
}

/// One poll of a job being waited for: `Some(record)` when done, an error when it failed or
/// was cancelled or `deadline` passed, `None` to poll again.
pub fn poll_job(
    inner: &Inner,
    id: &str,
    job_id: &str,
    deadline: Instant,
    waited: Duration,
) -> Result<Option<JobRecord>> {
    let rec = job(inner, id, job_id, Duration::from_secs(10))?;
    match rec.state {
        JobState::Done => Ok(Some(rec)),
        JobState::Failed | JobState::Cancelled => Err(Error::Config(format!(
            "training job {job_id} on trainer '{id}' {}: {}",
            if rec.state == JobState::Failed {
                "failed"
            } else {
                "was cancelled"
            },
            rec.error.as_deref().unwrap_or("no error message")
        ))),
        s if Instant::now() >= deadline => Err(Error::Timeout {
            who: format!("trainer '{id}'"),
            what: format!(
                "job {job_id} (state {s:?} after {:.0} s)",
                waited.as_secs_f64()
            ),
            after_ms: waited.as_millis() as u64,
        }),
        _ => Ok(None),
    }
}
