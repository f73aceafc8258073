//! `koopbridge view`: Rerun's view of a running session (`--session`), or of a recorded
//! `view.rrd` (`--open`), through the Python viewer participant `python -m koopbridge.view`.

use std::path::{Path, PathBuf};

/// Arguments of `koopbridge view`.
#[derive(clap::Args)]
#[command(after_help = "Examples:\n  \
    koopbridge run scenarios/damped-pendulum.toml --session demo --listen tcp/127.0.0.1:7501\n  \
    koopbridge view --session demo --connect tcp/127.0.0.1:7501 --web\n  \
    koopbridge view --open results/damped-pendulum/view.rrd\n\n\
    `koopbridge run --view` starts this viewer itself. The viewer is a participant of the\n\
    session (liveliness token alive/viewer/ID): it subscribes to the run's view keys\n\
    (PROTOCOL.md §10) and the trainer's progress, and never slows or stops the run.")]
pub struct ViewArgs {
    /// A recorded view (`view.rrd`) to open in Rerun's viewer instead of a live session.
    #[arg(long, value_name = "FILE", conflicts_with = "session")]
    pub open: Option<PathBuf>,
    /// The session to watch.
    #[arg(long, required_unless_present = "open")]
    pub session: Option<String>,
    /// The viewer's participant id.
    #[arg(long, default_value = "view")]
    pub id: String,
    /// Rerun's web viewer on a local port (the address is printed) instead of the desktop one.
    #[arg(long)]
    pub web: bool,
    /// The web viewer's port (default: a free one).
    #[arg(long, value_name = "PORT")]
    pub web_port: Option<u16>,
    /// Also record what is shown into FILE (`.rrd`).
    #[arg(long, value_name = "FILE")]
    pub save: Option<PathBuf>,
    #[command(flatten)]
    pub zenoh: super::ZenohArgs,
}

/// The arguments of `python -m koopbridge.view` for `args`.
fn python_args(args: &ViewArgs) -> Vec<String> {
    let mut a: Vec<String> = vec!["-m".into(), "koopbridge.view".into()];
    if let Some(f) = &args.open {
        a.extend(["--open".into(), f.display().to_string()]);
    } else {
        a.extend(["--session".into(), args.session.clone().unwrap_or_default()]);
        a.extend(["--id".into(), args.id.clone()]);
        a.push(if args.web { "--web" } else { "--native" }.into());
        if let Some(f) = &args.save {
            a.extend(["--save".into(), f.display().to_string()]);
        }
        a.extend(args.zenoh.options().to_args());
    }
    if let (true, Some(p)) = (args.web, args.web_port) {
        a.extend(["--web-port".into(), p.to_string()]);
    }
    if args.open.is_some() && args.web {
        a.push("--web".into());
    }
    a
}

/// Runs `koopbridge view`: the Python viewer replaces this process (on Unix; elsewhere it runs
/// in the foreground and its exit status is passed on), so that stopping `koopbridge view` stops
/// the viewer.
pub fn run(args: ViewArgs) -> anyhow::Result<()> {
    let python = bridge::orchestrator::program::external_program("{python}", Path::new("."));
    let mut cmd = std::process::Command::new(&python);
    cmd.args(python_args(&args));
    #[cfg(unix)]
    {
        use std::os::unix::process::CommandExt;
        let e = cmd.exec();
        anyhow::bail!("could not start {}: {e}", python.display());
    }
    #[cfg(not(unix))]
    {
        let status = cmd
            .status()
            .map_err(|e| anyhow::anyhow!("could not start {}: {e}", python.display()))?;
        if !status.success() {
            anyhow::bail!("the viewer ended with {status}");
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        v: ViewArgs,
    }

    #[test]
    fn a_session_or_a_file_is_passed_on_to_the_python_viewer() {
        let c = Cli::parse_from([
            "x",
            "--session",
            "s1",
            "--connect",
            "tcp/127.0.0.1:7501",
            "--web",
        ]);
        let line = python_args(&c.v).join(" ");
        assert!(
            line.starts_with("-m koopbridge.view --session s1 --id view --web"),
            "{line}"
        );
        assert!(line.contains("--connect tcp/127.0.0.1:7501"), "{line}");
        let c = Cli::parse_from(["x", "--open", "r/view.rrd"]);
        assert_eq!(
            python_args(&c.v).join(" "),
            "-m koopbridge.view --open r/view.rrd"
        );
        assert!(
            Cli::try_parse_from(["x"]).is_err(),
            "a session or a file is needed"
        );
        assert!(Cli::try_parse_from(["x", "--open", "a.rrd", "--session", "s"]).is_err());
    }
}
