//! The scenario's extra processes: command lines with placeholders, `[[hooks]]` run at fixed
//! phases of a run, and `[[participants]]` (e.g. a planner) started beside the simulators.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::keyexpr::{validate_chunk, Role};

/// A command: one shell string (run by `sh -c`) or a program with its arguments. Both may hold
/// the placeholders `{python}`, `{out}`, `{session}` and `{connect}` (see
/// `orchestrator::commands`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum CommandLine {
    /// A shell command line (`sh -c`); placeholder values are shell-quoted.
    Shell(String),
    /// A program and its arguments; placeholder values are inserted as they are.
    Argv(Vec<String>),
}

impl CommandLine {
    /// True when there is nothing to run.
    pub fn is_empty(&self) -> bool {
        match self {
            CommandLine::Shell(s) => s.trim().is_empty(),
            CommandLine::Argv(a) => a.first().is_none_or(|p| p.is_empty()),
        }
    }

    /// The command as written (for messages).
    pub fn display(&self) -> String {
        match self {
            CommandLine::Shell(s) => s.clone(),
            CommandLine::Argv(a) => a.join(" "),
        }
    }
}

/// When a hook runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum HookPhase {
    /// After the readiness barrier and the scenario checks, before collection.
    BeforeCollect,
    /// After training, before closed-loop control.
    BeforeControl,
    /// After control, once `{out}/report.json` is written.
    AfterControl,
}

impl HookPhase {
    /// The name in the TOML file.
    pub fn as_str(self) -> &'static str {
        match self {
            HookPhase::BeforeCollect => "before-collect",
            HookPhase::BeforeControl => "before-control",
            HookPhase::AfterControl => "after-control",
        }
    }
}

/// A `[[hooks]]` entry: a command run to completion at `phase`, in the scenario's repository,
/// while the run's Zenoh session is up; a failure fails the run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HookSpec {
    /// When it runs.
    pub phase: HookPhase,
    /// What it runs.
    pub command: CommandLine,
}

/// The roles an extra participant may have.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ParticipantRole {
    /// A trajectory planner (`…/planner/{id}/plan`, `alive/planner/{id}`).
    Planner,
}

impl ParticipantRole {
    /// The liveliness role it announces.
    pub fn role(self) -> Role {
        match self {
            ParticipantRole::Planner => Role::Planner,
        }
    }
}

/// A `[[participants]]` entry: a process started like a command simulator (the orchestrator
/// appends `--id ID --session S --stdin-lifeline --connect ENDPOINT`) and awaited by its
/// liveliness token `alive/{role}/{id}` in the readiness barrier.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParticipantSpec {
    /// Its id (`[a-z0-9_-]`).
    pub id: String,
    /// Its role.
    pub role: ParticipantRole,
    /// What it runs.
    pub command: CommandLine,
}

/// Checks ids, duplicates and empty commands of the hooks and participants.
pub fn validate(hooks: &[HookSpec], participants: &[ParticipantSpec]) -> Result<()> {
    for (i, h) in hooks.iter().enumerate() {
        if h.command.is_empty() {
            return Err(Error::Config(format!(
                "hook {} has an empty command",
                i + 1
            )));
        }
    }
    for (i, p) in participants.iter().enumerate() {
        validate_chunk("participant id", &p.id)?;
        if p.command.is_empty() {
            return Err(Error::Config(format!(
                "participant '{}' has an empty command",
                p.id
            )));
        }
        if participants[..i]
            .iter()
            .any(|o| o.id == p.id && o.role == p.role)
        {
            return Err(Error::Config(format!(
                "participant {}/{} appears twice",
                p.role.role().as_str(),
                p.id
            )));
        }
    }
    Ok(())
}
