//! Helpers of the fault tests (`tests/faults.rs`, `tests/faults_restart.rs`): waiting for the
//! first error after a kill, the pendulum stepped in the test process, and the check that a
//! killed run left no half-written file.

use std::path::Path;
use std::time::{Duration, Instant};

use bridge::adapter::{SimBackend, SystemBackend};
use bridge::error::Error;
use bridge::messages::ResetRequest;
use bridge::services::trainer::JobRecord;

/// What the issue asks of every detection.
pub const DETECT: Duration = Duration::from_secs(1);

/// Repeats `f` until it fails (at most `limit` after `since`), returning the error and the time
/// from `since` to the failure.
pub fn first_error<T>(
    since: Instant,
    limit: Duration,
    mut f: impl FnMut() -> bridge::Result<T>,
) -> (Error, Duration) {
    loop {
        match f() {
            Ok(_) => assert!(
                since.elapsed() < limit,
                "still answering {limit:?} after the kill"
            ),
            Err(e) => return (e, since.elapsed()),
        }
    }
}

/// Simulator `id`'s state after `inputs` from `x0`, stepped here (the independent computation).
pub fn local_states(x0: &[f64], inputs: &[f64]) -> Vec<Vec<f64>> {
    let mut b = SystemBackend::new(koopman::systems::by_name("damped-pendulum").unwrap());
    let mut xs = vec![b
        .reset(&ResetRequest {
            seed: None,
            x0: Some(x0.to_vec()),
            perturbation: None,
        })
        .unwrap()];
    for u in inputs {
        xs.push(b.step(&[*u]).unwrap());
    }
    xs
}

/// Every file the trainer and the model store keep under `out` is whole: job records parse,
/// checkpoints load, models load with their metrics. Returns the number of leftover temporary
/// files (hidden `.{name}.….tmp` names, never read as data).
pub fn nothing_half_written(out: &Path) -> usize {
    let mut temps = 0;
    let jobs = out.join("state/trainer/jobs");
    for e in std::fs::read_dir(&jobs).unwrap().flatten() {
        let p = e.path();
        let name = e.file_name().to_string_lossy().into_owned();
        if name.starts_with('.') {
            temps += 1;
        } else if name.ends_with(".json") {
            let r: JobRecord = serde_json::from_slice(&std::fs::read(&p).unwrap())
                .unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            assert_eq!(format!("{}.json", r.job), name);
        } else if name.ends_with(".ckpt") {
            koopman::train::Checkpoint::load(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        }
    }
    if let Ok(d) = std::fs::read_dir(out.join("models")) {
        for e in d.flatten() {
            if e.file_name().to_string_lossy().starts_with('.') {
                temps += 1;
                continue;
            }
            koopman::model::load_lifted(&e.path()).unwrap();
            let m = std::fs::read(e.path().join("metrics.json")).unwrap();
            serde_json::from_slice::<serde_json::Value>(&m).unwrap();
        }
    }
    temps
}
