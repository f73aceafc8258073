//! The trainer's client side: submit a job and wait for it, watching the trainer's (and other
//! participants') liveliness.

use std::time::Duration;

use zenoh::Wait;

use super::jobs::{JobRecord, JobSpec, JobState, SubmitReply};
use crate::error::{Error, ErrorCode, ErrorReply, Result};
use crate::keyexpr::Role;

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
            // Watched: a trainer that died just before the poll is `Gone`, not a timeout.
            let b = client
                .start(&status_key, Vec::new(), Duration::from_secs(10), &who)?
                .wait(Some((live, Role::Trainer, id)))?;
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
