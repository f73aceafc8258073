//! The processes of a run: the orchestrator's own session and liveliness tracker, the simulators
//! and the services it starts as children, and the readiness barrier that waits for them.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use super::commands::Placeholders;
use super::{RunOptions, SERVICES_ID};
use crate::client::{Client, Liveliness};
use crate::error::{Error, Result};
use crate::keyexpr::{Keys, Role};
use crate::procs::{ChildProc, ServeLine};
use crate::scenario::{CommandLine, ParticipantSpec, SimSpec};
use crate::services::Service;
use crate::session::{free_loopback_endpoint, open_session, ZenohOptions};

/// By how much [`Cluster::deprioritise_sim`] raises a simulator's nice value.
pub const DEPRIORITISE_BY: i32 = 10;

/// Everything the orchestrator started, killed on drop.
pub struct Cluster {
    /// Child processes.
    pub children: Vec<ChildProc>,
    /// The orchestrator's client.
    pub client: Client,
    /// Liveliness of the session.
    pub live: Liveliness,
    /// The endpoint children connect to.
    pub endpoint: String,
    /// The participants that were already in the session and were used, not started
    /// ([`RunOptions::attach_existing`]).
    pub existing: Vec<(Role, String)>,
}

impl Drop for Cluster {
    /// The children close their sessions first (while this one is still there), then this one
    /// closes: the closing order leaves no transport errors in the logs.
    fn drop(&mut self) {
        crate::procs::stop_all(&mut self.children);
    }
}

/// How long the liveliness tokens of participants already in the session are given to arrive.
const DISCOVERY: Duration = Duration::from_millis(1500);

/// The participants of `who` already in the session. Only looked for when this process connects
/// somewhere (without `--connect` or a config file nobody else can be reached: multicast
/// scouting is off); waits up to [`DISCOVERY`], less once all of `who` are found.
fn already_present(
    live: &Liveliness,
    who: &[(Role, String)],
    z: &ZenohOptions,
) -> Vec<(Role, String)> {
    if z.connect.is_empty() && z.zenoh_config.is_none() {
        return Vec::new();
    }
    let deadline = Instant::now() + DISCOVERY;
    loop {
        let found: Vec<(Role, String)> = who
            .iter()
            .filter(|(r, id)| live.is_alive(*r, id))
            .cloned()
            .collect();
        if found.len() == who.len() || Instant::now() >= deadline {
            return found;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// `role/id, …` for messages.
pub fn names(who: &[(Role, String)]) -> String {
    who.iter()
        .map(|(r, id)| format!("{}/{id}", r.as_str()))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The program of an external adapter command run in folder `base`: `{python}` is the first of
/// `base/.venv/bin/python` (the venv of the scenario's repository), `$KOOPBRIDGE_PYTHON`, the
/// `.venv/bin/python` of a folder above this `koopbridge` binary (the repository it was built
/// in), `python3` from `PATH` if it imports koopbridge, else `python3` anyway (a path that does
/// not exist is passed over); the choice is printed once on standard error. A relative path with
/// a `/` is taken relative to `base`; a bare name is looked up in `PATH`.
pub fn external_program(first: &str, base: &Path) -> PathBuf {
    if first == "{python}" {
        static SAID: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());
        let imports = |py: &Path| {
            std::process::Command::new(py)
                .args(["-c", "import koopbridge"])
                .stdin(std::process::Stdio::null())
                .stdout(std::process::Stdio::null())
                .stderr(std::process::Stdio::null())
                .status()
                .is_ok_and(|s| s.success())
        };
        let env = std::env::var_os("KOOPBRIDGE_PYTHON");
        let exe = std::env::current_exe().ok();
        let (python, why) = python_for(base, env.as_deref(), exe.as_deref(), &imports);
        if let Ok(mut said) = SAID.lock() {
            if !said.contains(&python) {
                eprintln!("koopbridge: {{python}} is {} ({why})", python.display());
                said.push(python.clone());
            }
        }
        return python;
    }
    let p = Path::new(first);
    if p.is_relative() && first.contains('/') {
        return base.join(p);
    }
    p.to_path_buf()
}

/// The choice of [`external_program`] for `{python}` and why, given `$KOOPBRIDGE_PYTHON` (`env`),
/// the running binary (`exe`) and whether a Python imports koopbridge (`imports`).
fn python_for(
    base: &Path,
    env: Option<&std::ffi::OsStr>,
    exe: Option<&Path>,
    imports: &dyn Fn(&Path) -> bool,
) -> (PathBuf, String) {
    let venv = base.join(".venv/bin/python");
    if venv.is_file() {
        return (
            venv,
            format!("the venv of the scenario's repository {}", base.display()),
        );
    }
    let mut passed = String::new();
    if let Some(v) = env.filter(|v| !v.is_empty()) {
        let p = PathBuf::from(v);
        let found = if p.components().count() > 1 {
            p.is_file().then_some(p.clone())
        } else {
            std::env::var_os("PATH").and_then(|path| {
                std::env::split_paths(&path)
                    .map(|d| d.join(&p))
                    .find(|c| c.is_file())
            })
        };
        match found {
            Some(py) => return (py, "KOOPBRIDGE_PYTHON".into()),
            None => passed = format!("; KOOPBRIDGE_PYTHON={} does not exist", p.display()),
        }
    }
    if let Some(repo) = exe.and_then(|e| {
        e.ancestors()
            .skip(1)
            .find(|d| d.join(".venv/bin/python").is_file())
    }) {
        let why = format!(
            "the venv of {}, where this koopbridge was built{passed}",
            repo.display()
        );
        return (repo.join(".venv/bin/python"), why);
    }
    let python3 = PathBuf::from("python3");
    let why = if imports(&python3) {
        format!("python3 from PATH, which imports koopbridge{passed}")
    } else {
        format!("python3 from PATH, which does NOT import koopbridge: set KOOPBRIDGE_PYTHON to a Python that does{passed}")
    };
    (python3, why)
}

/// `p` made absolute against the current folder (children may run elsewhere).
fn absolute(p: &Path) -> Result<PathBuf> {
    std::path::absolute(p).map_err(|e| Error::Io {
        path: p.to_path_buf(),
        source: e,
    })
}

impl Cluster {
    /// Opens the orchestrator's session on a free loopback port and starts `sims` (id, env) and,
    /// if `services` is non-empty, one `koopbridge serve` process with them (names as on the
    /// `serve` command line; an unknown name is an error).
    pub fn start(
        opts: &RunOptions,
        session_id: &str,
        sims: &[(String, String)],
        services: &[&str],
    ) -> Result<Self> {
        let specs: Vec<SimSpec> = sims
            .iter()
            .map(|(id, env)| SimSpec::builtin(id, env))
            .collect();
        Self::start_sims(opts, session_id, &specs, services)
    }

    /// Like [`Cluster::start`], with simulators that may be external adapter commands.
    pub fn start_sims(
        opts: &RunOptions,
        session_id: &str,
        sims: &[SimSpec],
        services: &[&str],
    ) -> Result<Self> {
        Self::launch(opts, session_id, sims, &Service::parse_all(services)?)
    }

    /// Like [`Cluster::start_sims`], with typed services.
    pub fn launch(
        opts: &RunOptions,
        session_id: &str,
        sims: &[SimSpec],
        services: &[Service],
    ) -> Result<Self> {
        Self::launch_in(opts, session_id, sims, services, None)
    }

    /// Like [`Cluster::launch`]; external simulator commands run in folder `base` (their
    /// `{python}` and relative paths resolve there; default: the current folder).
    pub fn launch_in(
        opts: &RunOptions,
        session_id: &str,
        sims: &[SimSpec],
        services: &[Service],
        base: Option<&Path>,
    ) -> Result<Self> {
        Self::launch_with(opts, session_id, sims, &[], services, base)
    }

    /// Like [`Cluster::launch_in`], with extra participants (`[[participants]]`, started like
    /// command simulators and awaited by their liveliness tokens). Commands may hold the
    /// placeholders of [`Placeholders`].
    pub fn launch_with(
        opts: &RunOptions,
        session_id: &str,
        sims: &[SimSpec],
        participants: &[ParticipantSpec],
        services: &[Service],
        base: Option<&Path>,
    ) -> Result<Self> {
        let keys = Keys::new(session_id)?;
        let mut z = opts.zenoh.clone();
        let endpoint = match z.listen.first() {
            Some(l) => l.clone(),
            None => {
                let ep = free_loopback_endpoint()?;
                z.listen = vec![ep.clone()];
                ep
            }
        };
        let session = open_session(&z)?;
        let client = Client::new(session, keys);
        let live = Liveliness::new(&client)?;
        let mut who: Vec<(Role, String)> = sims.iter().map(|s| (Role::Sim, s.id.clone())).collect();
        who.extend(participants.iter().map(|p| (p.role.role(), p.id.clone())));
        who.extend(services.iter().map(|s| (s.role(), SERVICES_ID.to_string())));
        let existing = already_present(&live, &who, &opts.zenoh);
        if !existing.is_empty() && !opts.attach_existing {
            return Err(Error::Config(format!(
                "already in session '{session_id}': {}; use them with --attach-existing, or run in another --session",
                names(&existing)
            )));
        }
        let missing = |role: Role, id: &str| !existing.iter().any(|(r, i)| *r == role && i == id);
        let services: Vec<Service> = services
            .iter()
            .copied()
            .filter(|s| missing(s.role(), SERVICES_ID))
            .collect();
        let mut child_connect: Vec<String> = vec![endpoint.clone()];
        child_connect.extend(opts.zenoh.connect.iter().cloned());
        let child_zenoh = ZenohOptions {
            connect: child_connect,
            listen: Vec::new(),
            mode: None,
            zenoh_config: opts
                .zenoh
                .zenoh_config
                .as_deref()
                .map(absolute)
                .transpose()?,
        }
        .to_args();
        let base = absolute(base.unwrap_or(Path::new(".")))?;
        let mut children = Vec::new();
        let logs = absolute(&opts.out_dir.join("logs"))?;
        let ph = Placeholders::new(&base, &absolute(&opts.out_dir)?, session_id, &endpoint);
        let tail_of = |id: &str| {
            let mut t: Vec<String> = ["--id", id, "--session", session_id, "--stdin-lifeline"]
                .map(String::from)
                .to_vec();
            t.extend(child_zenoh.iter().cloned());
            t
        };
        for p in participants
            .iter()
            .filter(|p| missing(p.role.role(), &p.id))
        {
            let role = p.role.role().as_str();
            let name = format!("participant {role}/{}", p.id);
            let log = logs.join(format!("{role}-{}.log", p.id));
            let (program, a) = ph.program(&p.command, &tail_of(&p.id), true);
            children.push(ChildProc::spawn_in(&name, &program, &a, &base, &log)?);
        }
        for spec in sims.iter().filter(|s| missing(Role::Sim, &s.id)) {
            let id = &spec.id;
            let name = format!("simulator '{id}'");
            let log = logs.join(format!("sim-{id}.log"));
            let child = match &spec.command {
                Some(cmd) => {
                    if cmd.is_empty() {
                        return Err(Error::Config(format!("{name}: empty command")));
                    }
                    let (program, a) =
                        ph.program(&CommandLine::Argv(cmd.clone()), &tail_of(id), false);
                    ChildProc::spawn_in(&name, &program, &a, &base, &log)?
                }
                None => {
                    let mut a: Vec<String> = vec!["sim".into(), "--env".into(), spec.env.clone()];
                    a.extend(tail_of(id));
                    ChildProc::spawn(&name, &opts.exe, &a, &log)?
                }
            };
            children.push(child);
        }
        if !services.is_empty() {
            let names: Vec<&str> = services.iter().map(|s| s.as_str()).collect();
            let (store, state) = (opts.out_dir.join("models"), opts.out_dir.join("state"));
            let a = ServeLine {
                services: &names,
                session: session_id,
                id: SERVICES_ID,
                store: &store,
                state_dir: &state,
                data_root: &opts.out_dir.join("data"),
                train_threads: None,
                zenoh: &child_zenoh,
            }
            .args();
            children.push(ChildProc::spawn(
                "services",
                &opts.exe,
                &a,
                &logs.join("services.log"),
            )?);
        }
        let mut c = Cluster {
            children,
            client,
            live,
            endpoint,
            existing,
        };
        c.wait_ready(&who, opts.ready_timeout)?;
        Ok(c)
    }

    /// Lowers the CPU priority (nice +10, every thread) of simulator `id`'s process if this
    /// cluster started it; false (with a warning when it failed) otherwise. One-way for an
    /// ordinary user: the process keeps the lower priority until it exits.
    pub fn deprioritise_sim(&self, id: &str) -> bool {
        let name = format!("simulator '{id}'");
        let Some(child) = self.children.iter().find(|c| c.name == name) else {
            return false;
        };
        match crate::priority::lower_priority(child.id(), DEPRIORITISE_BY) {
            Ok(_) => true,
            Err(e) => {
                tracing::warn!("{name}: its priority could not be lowered: {e}");
                false
            }
        }
    }

    /// Waits for the liveliness tokens of `who`, failing early if a child exits.
    pub fn wait_ready(&mut self, who: &[(Role, String)], timeout: Duration) -> Result<()> {
        let deadline = Instant::now() + timeout;
        loop {
            match self.live.wait_for(who, Duration::from_millis(200)) {
                Ok(()) => return Ok(()),
                Err(e) if Instant::now() > deadline => return Err(e),
                Err(_) => {}
            }
            for ch in &mut self.children {
                if let Some(msg) = ch.exited() {
                    return Err(Error::Config(msg));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(p: &Path) -> PathBuf {
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, "").unwrap();
        p.to_path_buf()
    }

    #[test]
    fn python_is_the_scenario_venv_then_koopbridge_python_then_the_build_venv_then_python3() {
        let t = std::env::temp_dir().join(format!("kb-python-for-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&t);
        let (base, other) = (t.join("scenarios"), t.join("my-python"));
        let chosen = file(&t.join("envpy/bin/python"));
        let exe = t.join("build/target/release/koopbridge");
        let yes = |_: &Path| true;
        let no = |_: &Path| false;
        let env = Some(chosen.as_os_str());
        // Nothing found: python3, said to lack koopbridge unless it imports it.
        let (py, why) = python_for(&base, None, Some(&exe), &no);
        assert_eq!(py, PathBuf::from("python3"));
        assert!(why.contains("does NOT import koopbridge"), "{why}");
        assert!(python_for(&base, None, None, &yes)
            .1
            .contains("which imports koopbridge"));
        // KOOPBRIDGE_PYTHON is honoured; a missing one falls through (and is named).
        assert_eq!(
            python_for(&base, env, Some(&exe), &no),
            (chosen.clone(), "KOOPBRIDGE_PYTHON".into())
        );
        let missing = other.join("bin/python");
        let (py, why) = python_for(&base, Some(missing.as_os_str()), Some(&exe), &yes);
        assert_eq!(py, PathBuf::from("python3"));
        assert!(
            why.contains(&format!(
                "KOOPBRIDGE_PYTHON={} does not exist",
                missing.display()
            )),
            "{why}"
        );
        // The venv above the binary comes after KOOPBRIDGE_PYTHON, before python3.
        let build_venv = file(&t.join("build/.venv/bin/python"));
        assert_eq!(python_for(&base, env, Some(&exe), &no).0, chosen);
        let (py, why) = python_for(&base, Some(missing.as_os_str()), Some(&exe), &yes);
        assert_eq!(py, build_venv);
        assert!(
            why.contains("where this koopbridge was built") && why.contains("does not exist"),
            "{why}"
        );
        // The scenario repository's own venv comes first.
        let own = file(&base.join(".venv/bin/python"));
        assert_eq!(python_for(&base, env, Some(&exe), &no).0, own);
        assert_eq!(external_program("{python}", &base), own);
        std::fs::remove_dir_all(&t).unwrap();
    }
}
