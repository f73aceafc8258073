//! The names of the services `koopbridge serve` runs, typed: each with its liveliness role.

use crate::error::{Error, Result};
use crate::keyexpr::Role;

/// A koopbridge service (what `koopbridge serve NAME…` starts).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Service {
    /// Training jobs (`…/trainer/{id}/jobs`).
    Trainer,
    /// Model predictive control (`…/mpc/{id}/{configure,solve,attach}`).
    Mpc,
    /// Stream recording (`…/recorder/{id}/record`, `…/data/{name}`).
    Recorder,
    /// The model store (`…/models/{name}`).
    Models,
}

impl Service {
    /// Every service, in the order `koopbridge serve` starts them by default.
    pub const ALL: [Service; 4] = [
        Service::Trainer,
        Service::Mpc,
        Service::Recorder,
        Service::Models,
    ];

    /// The name on the command line (`trainer`, `mpc`, `recorder`, `models`).
    pub fn as_str(self) -> &'static str {
        match self {
            Service::Trainer => "trainer",
            Service::Mpc => "mpc",
            Service::Recorder => "recorder",
            Service::Models => "models",
        }
    }

    /// The role of its liveliness token `…/alive/{role}/{id}`.
    pub fn role(self) -> Role {
        match self {
            Service::Trainer => Role::Trainer,
            Service::Mpc => Role::Mpc,
            Service::Recorder => Role::Recorder,
            Service::Models => Role::Models,
        }
    }

    /// Parses every name of `names`; an unknown name is an error listing the valid ones.
    pub fn parse_all(names: &[&str]) -> Result<Vec<Service>> {
        names.iter().map(|n| n.parse()).collect()
    }
}

impl std::fmt::Display for Service {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for Service {
    type Err = Error;

    fn from_str(s: &str) -> Result<Self> {
        Service::ALL
            .into_iter()
            .find(|v| v.as_str() == s)
            .ok_or_else(|| {
                let valid: Vec<&str> = Service::ALL.iter().map(|v| v.as_str()).collect();
                Error::Config(format!(
                    "unknown service '{s}'; valid: {}",
                    valid.join(", ")
                ))
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_unknown_names_are_refused() {
        for s in Service::ALL {
            assert_eq!(s.as_str().parse::<Service>().unwrap(), s);
            assert_eq!(s.role().as_str(), s.as_str());
        }
        let e = Service::parse_all(&["mpc", "modles"])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("'modles'") && e.contains("trainer, mpc, recorder, models"),
            "{e}"
        );
    }
}
