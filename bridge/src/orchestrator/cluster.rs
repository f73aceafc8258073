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
    /// What a viewer of the run sees (published only while one subscribes).
    pub view: super::view::RunView,
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
        let view = super::view::RunView::declare(&client, opts.out_dir.join("models"))?;
        let mut c = Cluster {
            children,
            client,
            live,
            endpoint,
            existing,
            view,
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
