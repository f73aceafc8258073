//! Command lines of a run's external processes: the placeholders `{python}`, `{out}`,
//! `{session}` and `{connect}`, the program a command starts, and `[[hooks]]` run to completion
//! with their logs under `{out}/logs/`.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use crate::error::{Error, Result};
use crate::procs::tail;
use crate::scenario::{CommandLine, HookPhase, HookSpec};

/// The values of the placeholders of a run.
#[derive(Clone, Debug)]
pub struct Placeholders {
    /// `{python}`: the Python with koopbridge installed, chosen by `program::python_for`: the
    /// repository's `.venv`, then `KOOPBRIDGE_PYTHON`, then the venv above the binary, then
    /// `python3`.
    pub python: PathBuf,
    /// `{out}`: the run's output folder (absolute).
    pub out: PathBuf,
    /// `{session}`: the koopbridge session id.
    pub session: String,
    /// `{connect}`: the Zenoh endpoint of the orchestrator (what children `--connect` to).
    pub connect: String,
    /// The folder commands run in (the scenario's repository).
    pub base: PathBuf,
}

/// `s` in single quotes for `sh` (a `'` inside becomes `'\''`).
pub fn shell_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', "'\\''"))
}

impl Placeholders {
    /// The placeholders of a run whose commands run in `base`.
    pub fn new(base: &Path, out: &Path, session: &str, connect: &str) -> Self {
        Placeholders {
            python: super::program::external_program("{python}", base),
            out: out.to_path_buf(),
            session: session.to_string(),
            connect: connect.to_string(),
            base: base.to_path_buf(),
        }
    }

    /// `text` with every placeholder replaced; `quote` shell-quotes the values.
    pub fn expand(&self, text: &str, quote: bool) -> String {
        let q = |v: &str| if quote { shell_quote(v) } else { v.to_string() };
        text.replace("{python}", &q(&self.python.display().to_string()))
            .replace("{out}", &q(&self.out.display().to_string()))
            .replace("{session}", &q(&self.session))
            .replace("{connect}", &q(&self.connect))
    }

    /// The program and arguments that run `cmd` with `extra` appended: a shell string becomes
    /// `sh -c 'exec CMD "$@"' sh EXTRA…` (so the started process is the command itself, and its
    /// lifeline reaches it); a program list resolves its program like a simulator's
    /// ([`super::program::external_program`]). `exec`: `false` runs a shell string as it is
    /// (hooks may be several commands).
    pub fn program(
        &self,
        cmd: &CommandLine,
        extra: &[String],
        exec: bool,
    ) -> (PathBuf, Vec<String>) {
        match cmd {
            CommandLine::Shell(s) => {
                let body = self.expand(s, true);
                let script = if exec {
                    format!("exec {body} \"$@\"")
                } else {
                    body
                };
                let mut a = vec!["-c".to_string(), script, "sh".to_string()];
                a.extend(extra.iter().cloned());
                (PathBuf::from("sh"), a)
            }
            CommandLine::Argv(v) => {
                let (first, rest) = v
                    .split_first()
                    .map_or(("", &[][..]), |(f, r)| (f.as_str(), r));
                let program = super::program::external_program(first, &self.base);
                let mut a: Vec<String> = rest.iter().map(|x| self.expand(x, false)).collect();
                a.extend(extra.iter().cloned());
                (program, a)
            }
        }
    }
}

/// Runs every hook of `phase` in order (hook N is the N-th `[[hooks]]` entry, from 1), each to
/// completion in `ph.base` with its output in `{out}/logs/hook-N.log`; the first that fails
/// ends the run, naming the hook, its command and the end of its log.
pub fn run_hooks(
    hooks: &[HookSpec],
    phase: HookPhase,
    ph: &Placeholders,
    on: &mut dyn FnMut(&str),
) -> Result<()> {
    for (i, h) in hooks.iter().enumerate().filter(|(_, h)| h.phase == phase) {
        let n = i + 1;
        on(&format!(
            "hook {n} ({}): {}",
            phase.as_str(),
            h.command.display()
        ));
        let log = ph.out.join("logs").join(format!("hook-{n}.log"));
        let io = |p: &Path, e| Error::Io {
            path: p.to_path_buf(),
            source: e,
        };
        if let Some(d) = log.parent() {
            std::fs::create_dir_all(d).map_err(|e| io(d, e))?;
        }
        let out = std::fs::File::create(&log).map_err(|e| io(&log, e))?;
        let err = out.try_clone().map_err(|e| io(&log, e))?;
        let (program, args) = ph.program(&h.command, &[], false);
        let status = Command::new(&program)
            .args(&args)
            .current_dir(&ph.base)
            .stdin(Stdio::null())
            .stdout(Stdio::from(out))
            .stderr(Stdio::from(err))
            .status();
        let fail = |what: String| {
            Error::Config(format!(
                "hook {n} ({}) {what}: {}\nend of {}:\n{}",
                phase.as_str(),
                h.command.display(),
                log.display(),
                tail(&log, 1500)
            ))
        };
        match status {
            Ok(s) if s.success() => {}
            Ok(s) => return Err(fail(format!("failed ({s})"))),
            Err(e) => return Err(fail(format!("could not be started ({e})"))),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ph() -> Placeholders {
        Placeholders {
            python: PathBuf::from("/v/bin/python"),
            out: PathBuf::from("/r/it's out"),
            session: "s1".into(),
            connect: "tcp/127.0.0.1:7447".into(),
            base: PathBuf::from("/repo"),
        }
    }

    #[test]
    fn placeholders_expand_quoted_in_shell_strings_and_raw_in_argument_lists() {
        let p = ph();
        let (prog, a) = p.program(
            &CommandLine::Shell("{python} x.py --out {out}/r.npy".into()),
            &["--id".into(), "p".into()],
            true,
        );
        assert_eq!(prog, PathBuf::from("sh"));
        assert_eq!(
            a,
            [
                "-c",
                "exec '/v/bin/python' x.py --out '/r/it'\\''s out'/r.npy \"$@\"",
                "sh",
                "--id",
                "p"
            ]
        );
        let (prog, a) = p.program(
            &CommandLine::Argv(vec![
                "tools/x".into(),
                "--s={session}".into(),
                "{connect}".into(),
            ]),
            &[],
            false,
        );
        assert_eq!(prog, PathBuf::from("/repo/tools/x"));
        assert_eq!(a, ["--s=s1", "tcp/127.0.0.1:7447"]);
    }

    #[test]
    fn a_failing_hook_names_itself_its_command_and_its_log() {
        let out = std::env::temp_dir().join(format!("kb-hooks-{}", std::process::id()));
        let mut p = ph();
        p.out = out.clone();
        p.base = std::env::temp_dir();
        let hooks = vec![
            HookSpec {
                phase: HookPhase::BeforeCollect,
                command: CommandLine::Shell("echo hello > {out}/h.txt".into()),
            },
            HookSpec {
                phase: HookPhase::AfterControl,
                command: CommandLine::Shell("echo boom-output; exit 3".into()),
            },
        ];
        std::fs::create_dir_all(&out).unwrap();
        let mut seen = Vec::new();
        run_hooks(&hooks, HookPhase::BeforeCollect, &p, &mut |m| {
            seen.push(m.to_string())
        })
        .unwrap();
        assert_eq!(
            std::fs::read_to_string(out.join("h.txt")).unwrap(),
            "hello\n"
        );
        assert_eq!(seen.len(), 1);
        let e = run_hooks(&hooks, HookPhase::AfterControl, &p, &mut |_| {})
            .unwrap_err()
            .to_string();
        assert!(e.contains("hook 2 (after-control) failed"), "{e}");
        assert!(
            e.contains("exit 3") && e.contains("boom-output") && e.contains("hook-2.log"),
            "{e}"
        );
        std::fs::remove_dir_all(&out).ok();
    }
}
