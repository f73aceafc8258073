//! The trainer services `koopbridge sweep --local-trainers K` starts on this machine, kept
//! running: one that exits mid-sweep (killed, out of memory, crashed) is started again with the
//! same state folder, so it resumes its persisted job from the job's checkpoint within the
//! sweep's grace period instead of the sweep waiting for a trainer that never returns.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use bridge::procs::{stop_all, ChildProc, ServeLine};

/// How many times one local trainer is started again before the sweep gives up on it (its
/// points then go to the other trainers, as for any trainer that vanished).
pub const MAX_RESTARTS: u32 = 3;

/// How often the supervisor looks at its children.
const POLL: Duration = Duration::from_millis(250);

/// Where and how the local trainers run.
pub struct LocalTrainerSpec {
    /// The `koopbridge` executable.
    pub exe: PathBuf,
    /// The Zenoh session id they join.
    pub session_id: String,
    /// Endpoints they connect to (the sweep's own listener first).
    pub connect: Vec<String>,
    /// The sweep's folder: trainer `localK` keeps its state in `OUT/trainers/localK`.
    pub out: PathBuf,
    /// The folder their jobs' dataset paths must lie in (`--data-root`).
    pub data_root: PathBuf,
    /// Threads per job (`--train-threads`).
    pub threads: usize,
}

struct Slot {
    id: String,
    args: Vec<String>,
    log: PathBuf,
    child: ChildProc,
    restarts: u32,
    /// Exited after [`MAX_RESTARTS`] restarts, or could not be started again: left alone.
    given_up: bool,
}

/// The running local trainers and the thread that starts again those that exit. Dropping it
/// stops the supervisor first, then releases every trainer (their lifelines close) and reaps
/// them.
pub struct LocalTrainers {
    slots: Arc<Mutex<Vec<Slot>>>,
    stop: Arc<AtomicBool>,
    supervisor: Option<JoinHandle<()>>,
}

impl LocalTrainers {
    /// Starts `count` trainer services `local0…` and their supervisor; `say` receives one line
    /// per restart (and per trainer given up on).
    pub fn start(
        spec: &LocalTrainerSpec,
        count: usize,
        say: impl Fn(String) + Send + 'static,
    ) -> anyhow::Result<Self> {
        let mut slots = Vec::with_capacity(count);
        for k in 0..count {
            let id = format!("local{k}");
            let state = spec.out.join("trainers").join(&id);
            std::fs::create_dir_all(&state)?;
            let args = trainer_args(spec, &id, &state);
            let log = state.join("trainer.log");
            let child = ChildProc::spawn(&format!("trainer '{id}'"), &spec.exe, &args, &log)?;
            slots.push(Slot {
                id,
                args,
                log,
                child,
                restarts: 0,
                given_up: false,
            });
        }
        let slots = Arc::new(Mutex::new(slots));
        let stop = Arc::new(AtomicBool::new(false));
        let supervisor = {
            let (slots, stop, exe) = (slots.clone(), stop.clone(), spec.exe.clone());
            std::thread::Builder::new()
                .name("local-trainers".into())
                .spawn(move || supervise(&slots, &stop, &exe, &say))?
        };
        Ok(LocalTrainers {
            slots,
            stop,
            supervisor: Some(supervisor),
        })
    }
}

impl Drop for LocalTrainers {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.supervisor.take() {
            let _ = h.join();
        }
        let mut slots = self.slots.lock().unwrap_or_else(|p| p.into_inner());
        let mut children: Vec<ChildProc> = slots.drain(..).map(|s| s.child).collect();
        stop_all(&mut children);
    }
}

/// The command line of trainer `id` (`koopbridge serve trainer models …`), its lifeline on.
fn trainer_args(spec: &LocalTrainerSpec, id: &str, state: &Path) -> Vec<String> {
    let zenoh: Vec<String> = spec
        .connect
        .iter()
        .flat_map(|c| ["--connect".to_string(), c.clone()])
        .collect();
    ServeLine {
        services: &["trainer", "models"],
        session: &spec.session_id,
        id,
        store: &state.join("models"),
        state_dir: state,
        data_root: &spec.data_root,
        train_threads: Some(spec.threads),
        zenoh: &zenoh,
    }
    .args()
}

/// Until `stop`: every [`POLL`], starts again each trainer that has exited, keeping the log of
/// its previous life as `trainer.log.N`, up to [`MAX_RESTARTS`] times.
fn supervise(slots: &Mutex<Vec<Slot>>, stop: &AtomicBool, exe: &Path, say: &dyn Fn(String)) {
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(POLL);
        let mut slots = slots.lock().unwrap_or_else(|p| p.into_inner());
        for s in slots.iter_mut() {
            if s.given_up || stop.load(Ordering::Relaxed) {
                continue;
            }
            let Some(why) = s.child.exited() else {
                continue;
            };
            // "trainer 'local0' exited (signal: 9 (SIGKILL))", without the command line.
            let first = why.lines().next().unwrap_or_default();
            let status = first
                .split("; its command line")
                .next()
                .unwrap_or(first)
                .to_string();
            if s.restarts == MAX_RESTARTS {
                s.given_up = true;
                say(format!(
                    "{status}; not started again after {MAX_RESTARTS} restarts (log: {})",
                    s.log.display()
                ));
                continue;
            }
            s.restarts += 1;
            let kept = s.log.with_extension(format!("log.{}", s.restarts));
            let _ = std::fs::rename(&s.log, &kept);
            match ChildProc::spawn(&format!("trainer '{}'", s.id), exe, &s.args, &s.log) {
                Ok(child) => {
                    s.child = child;
                    say(format!(
                        "{status}; started again ({} of {MAX_RESTARTS}), it resumes its job from its checkpoint (previous log: {})",
                        s.restarts,
                        kept.display()
                    ));
                }
                Err(e) => {
                    s.given_up = true;
                    say(format!("{status}; could not be started again: {e}"));
                }
            }
        }
    }
}
