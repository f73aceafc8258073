//! Child processes of the orchestrator: started from the current executable with a stdin
//! "lifeline" (they exit when it closes), logs to files; when dropped, released and given
//! [`GRACE`] to exit on their own before they are killed.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::error::{Error, Result};

/// One child process.
pub struct ChildProc {
    /// A name for messages (e.g. `simulator 'pend'`).
    pub name: String,
    /// Its log file (stderr and stdout).
    pub log: PathBuf,
    /// The command line it was started with (for messages).
    pub command_line: String,
    child: Child,
}

/// `exe args…` as one line, arguments with spaces or quotes in single quotes.
pub fn command_line(exe: &Path, args: &[String]) -> String {
    std::iter::once(exe.display().to_string())
        .chain(args.iter().cloned())
        .map(|a| {
            if a.is_empty() || a.contains([' ', '\'', '"', '\t']) {
                format!("'{}'", a.replace('\'', "'\\''"))
            } else {
                a
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// The command line of a `koopbridge serve` child, shared by the orchestrator's services and a
/// sweep's local trainers so that both start a service the same way.
pub struct ServeLine<'a> {
    /// The services it runs (`trainer`, `mpc`, `models`, …).
    pub services: &'a [&'a str],
    /// The Zenoh session id it joins (`--session`).
    pub session: &'a str,
    /// Its service id (`--id`).
    pub id: &'a str,
    /// Where it keeps models (`--store`).
    pub store: &'a Path,
    /// Where it keeps job state (`--state-dir`).
    pub state_dir: &'a Path,
    /// The folder every dataset path it is sent must lie in (`--data-root`).
    pub data_root: &'a Path,
    /// Threads per training job (`--train-threads`); the service's default when `None`.
    pub train_threads: Option<usize>,
    /// Zenoh options as arguments (`--connect E`, `--listen E`, …).
    pub zenoh: &'a [String],
}

impl ServeLine<'_> {
    /// The arguments after the executable, with the stdin lifeline on.
    pub fn args(&self) -> Vec<String> {
        let mut a = vec!["serve".to_string()];
        a.extend(self.services.iter().map(|s| s.to_string()));
        for (k, v) in [("--session", self.session), ("--id", self.id)] {
            a.extend([k.to_string(), v.to_string()]);
        }
        for (k, v) in [
            ("--store", self.store),
            ("--state-dir", self.state_dir),
            ("--data-root", self.data_root),
        ] {
            a.extend([k.to_string(), v.display().to_string()]);
        }
        if let Some(t) = self.train_threads {
            a.extend(["--train-threads".to_string(), t.to_string()]);
        }
        a.push("--stdin-lifeline".into());
        a.extend(self.zenoh.iter().cloned());
        a
    }
}

impl ChildProc {
    /// Starts `exe args…` with stdin piped (the lifeline) and output to `log`.
    pub fn spawn(name: &str, exe: &Path, args: &[String], log: &Path) -> Result<Self> {
        Self::start(name, exe, args, &[], None, log)
    }

    /// [`ChildProc::spawn`] in folder `dir`.
    pub fn spawn_in(
        name: &str,
        exe: &Path,
        args: &[String],
        dir: &Path,
        log: &Path,
    ) -> Result<Self> {
        Self::start(name, exe, args, &[], Some(dir), log)
    }

    /// [`ChildProc::spawn`] with extra environment variables `env` (name, value).
    pub fn spawn_env(
        name: &str,
        exe: &Path,
        args: &[String],
        env: &[(&str, &str)],
        log: &Path,
    ) -> Result<Self> {
        Self::start(name, exe, args, env, None, log)
    }

    /// Starts the process; a program that cannot be started is a configuration error that names
    /// the participant and the command line.
    fn start(
        name: &str,
        exe: &Path,
        args: &[String],
        env: &[(&str, &str)],
        dir: Option<&Path>,
        log: &Path,
    ) -> Result<Self> {
        let io = |p: &Path, e| Error::Io {
            path: p.to_path_buf(),
            source: e,
        };
        if let Some(d) = log.parent() {
            std::fs::create_dir_all(d).map_err(|e| io(d, e))?;
        }
        let out = std::fs::File::create(log).map_err(|e| io(log, e))?;
        let err = out.try_clone().map_err(|e| io(log, e))?;
        let command_line = command_line(exe, args);
        let mut cmd = Command::new(exe);
        cmd.args(args)
            .envs(env.iter().copied())
            .stdin(Stdio::piped())
            .stdout(Stdio::from(out))
            .stderr(Stdio::from(err));
        if let Some(d) = dir {
            cmd.current_dir(d);
        }
        let child = cmd.spawn().map_err(|e| {
            let in_dir = dir.map_or(String::new(), |d| format!(" in {}", d.display()));
            Error::Config(format!(
                "{name} could not be started ({e}): {command_line}{in_dir}"
            ))
        })?;
        Ok(ChildProc {
            name: name.to_string(),
            log: log.to_path_buf(),
            command_line,
            child,
        })
    }

    /// The OS process id.
    pub fn id(&self) -> u32 {
        self.child.id()
    }

    /// `Some(message)` if the process has exited (with the end of its log).
    pub fn exited(&mut self) -> Option<String> {
        match self.child.try_wait() {
            Ok(Some(status)) => Some(format!(
                "{} exited ({status}); its command line: {}\nend of {}:\n{}",
                self.name,
                self.command_line,
                self.log.display(),
                tail(&self.log, 1500)
            )),
            _ => None,
        }
    }

    /// Closes the lifeline (standard input): a child started with `--stdin-lifeline` closes its
    /// Zenoh session and exits on its own.
    pub fn release(&mut self) {
        drop(self.child.stdin.take());
    }

    /// Waits until `deadline` for the process to exit, then kills it; reaps it.
    pub fn reap(&mut self, deadline: Instant) {
        loop {
            match self.child.try_wait() {
                Ok(None) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(10))
                }
                Ok(None) => return self.kill(),
                _ => return,
            }
        }
    }

    /// Kills the process (if still running) and reaps it.
    pub fn kill(&mut self) {
        drop(self.child.stdin.take());
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
    }
}

/// How long a released child is given to exit on its own before it is killed.
pub const GRACE: Duration = Duration::from_secs(2);

/// Releases every child first, then reaps each within [`GRACE`]: they close their sessions
/// while their peers are still there (no transport errors in their logs).
pub fn stop_all(children: &mut [ChildProc]) {
    for c in children.iter_mut() {
        c.release();
    }
    let deadline = Instant::now() + GRACE;
    for c in children.iter_mut() {
        c.reap(deadline);
    }
}

impl Drop for ChildProc {
    fn drop(&mut self) {
        self.release();
        self.reap(Instant::now() + GRACE);
    }
}

/// The last `n` bytes of a text file (lossy).
pub fn tail(path: &Path, n: usize) -> String {
    let b = std::fs::read(path).unwrap_or_default();
    String::from_utf8_lossy(&b[b.len().saturating_sub(n)..]).into_owned()
}
