//! `[train] pretrained`: model folders trained elsewhere (`koopbridge train`, a sweep, another
//! run) that a scenario's tracking tasks score beside the models it trains, one row each.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::keyexpr::validate_chunk;

/// One model folder trained elsewhere: served under `name` from the run's model store (copied
/// into `OUT/models/{name}`), a row of every tracking task of simulator `sim`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PretrainedSpec {
    /// Its name in the model store and its row's name (`[a-z0-9_-]`; distinct from every other
    /// model of the run).
    pub name: String,
    /// The model folder (`config.json` with its `kind`, its weights): `{out}` expanded, a relative
    /// path in the scenario's repository; read when control starts, so that a hook may write it.
    pub path: String,
    /// Which simulator's tasks it is a row of (default: the first); its `nx`/`nu` must be the
    /// simulator's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sim: Option<String>,
}

/// Checks the entries of `[train] pretrained` against each other and the simulators `sims`:
/// valid and distinct names, none of them `taken` (the names of the models the run trains), a
/// path, a simulator that exists.
pub fn check(list: &[PretrainedSpec], sims: &[&str], taken: &[String]) -> Result<()> {
    for (i, p) in list.iter().enumerate() {
        let bad = |m: String| {
            Err(Error::Config(format!(
                "[train] pretrained '{}': {m}",
                p.name
            )))
        };
        validate_chunk("[train] pretrained name", &p.name)?;
        if list[..i].iter().any(|q| q.name == p.name) {
            return bad("the name is given twice".into());
        }
        if taken.contains(&p.name) {
            return bad("is the name of a model this run trains; choose another".into());
        }
        if p.path.trim().is_empty() {
            return bad("`path` is empty".into());
        }
        if let Some(s) = &p.sim {
            if !sims.contains(&s.as_str()) {
                return bad(format!("no simulator '{s}' (the simulators: {sims:?})"));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(name: &str, path: &str, sim: Option<&str>) -> PretrainedSpec {
        PretrainedSpec {
            name: name.into(),
            path: path.into(),
            sim: sim.map(str::to_string),
        }
    }

    #[test]
    fn bad_entries_are_refused_naming_the_model() {
        let taken = vec!["run-pend".to_string()];
        let err = |l: &[PretrainedSpec]| check(l, &["pend"], &taken).unwrap_err().to_string();
        assert!(check(&[spec("big", "m/big", None)], &["pend"], &taken).is_ok());
        assert!(err(&[spec("a", "x", None), spec("a", "y", None)]).contains("twice"));
        assert!(err(&[spec("run-pend", "x", None)]).contains("this run trains"));
        assert!(err(&[spec("big", " ", None)]).contains("path"));
        assert!(err(&[spec("big", "x", Some("arm"))]).contains("no simulator 'arm'"));
        assert!(err(&[spec("Big/../x", "x", None)]).contains("pretrained name"));
    }
}
