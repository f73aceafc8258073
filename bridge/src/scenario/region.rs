//! Each simulator's data region: its `[[sims]]` initial-state box and input bounds over
//! `[collect]`'s, checked without the simulator when the file is read.

use super::Scenario;
use crate::collect::SimRegion;
use crate::error::{Error, Result};
use crate::messages::CollectPolicy;
use crate::scenario::collect::takes_region;
use crate::scenario::data_region::check_bounds;
use crate::scenario::Policy;

impl Scenario {
    /// The `[collect]` policy simulator `sims[j]` collects with: the shared one, its `inputs`
    /// replaced by the simulator's `[[sims]]` `collect_inputs` when it gives them (with
    /// `kind = "adapter"`; checked by [`Scenario::sim_region`]).
    pub fn sim_policy(&self, j: usize) -> Policy {
        let own = self.sims.get(j).and_then(|s| s.collect_inputs.as_ref());
        match (&self.collect.policy, own) {
            (Policy::Adapter { block, .. }, Some(inputs)) => Policy::Adapter {
                inputs: inputs.clone(),
                block: *block,
            },
            (p, _) => p.clone(),
        }
    }

    /// The data region of simulator `sims[j]` that overrides `[collect]`'s ([`SimRegion`]; empty
    /// when its entry sets none): its `x0_low`/`x0_high` or `x0_center`/`x0_radius`,
    /// `u_low`/`u_high`, and its `collect_inputs`. Checked without the simulator: the box as
    /// `[collect]`'s ([`super::data_region::x0_box_of`]); bounds finite, of equal length (or one of
    /// them a single value), `low ≤ high`; bounds only with a uniform policy (lockstep or adapter
    /// inputs); a box not with a planned or expert adapter policy ([`Scenario::sim_policy`]: its
    /// own inputs, else the shared ones); `collect_inputs` only with `kind = "adapter"`, and a
    /// planned or expert one only for an external adapter (`command`). The lengths against
    /// `nx`/`nu` are checked with the simulator's `info`
    /// ([`crate::orchestrator::validate::validate_scenario`]).
    pub fn sim_region(&self, j: usize) -> Result<SimRegion> {
        let Some(s) = self.sims.get(j) else {
            return Ok(SimRegion::default());
        };
        let table = format!("[[sims]] '{}'", s.id);
        self.check_collect_inputs(s, &table)?;
        let region = SimRegion {
            x0_box: s.x0_box_in(&table)?,
            low: s.u_low.clone(),
            high: s.u_high.clone(),
            inputs: s.collect_inputs.clone(),
        };
        let policy = self.sim_policy(j);
        if region.is_empty() {
            // `[collect]`'s box (checked against the shared policy) applies to its own inputs.
            if s.collect_inputs.is_some() && self.collect.x0_box()?.is_some() {
                takes_region(
                    &policy,
                    &format!("{table} with [collect]'s initial-state box"),
                )?;
            }
            return Ok(region);
        }
        takes_region(&policy, &table)?;
        if (region.low.is_some() || region.high.is_some())
            && matches!(self.collect.policy, Policy::Scripted { .. })
        {
            return Err(Error::Config(format!(
                "{table}: u_low/u_high bound uniform random inputs; the scripted policy gives its \
                 inputs (drop them, or use kind = \"uniform\" or \"adapter\")"
            )));
        }
        check_bounds(&table, ["u_low", "u_high"], &region.low, &region.high)?;
        Ok(region)
    }

    /// Refuses `collect_inputs` that `s` cannot collect with: any without `[collect] policy =
    /// { kind = "adapter" }` (a lockstep policy chooses the inputs itself), and a planned or
    /// expert one for a built-in system (which draws uniform inputs only).
    fn check_collect_inputs(&self, s: &super::SimSpec, table: &str) -> Result<()> {
        let Some(inputs) = &s.collect_inputs else {
            return Ok(());
        };
        let lockstep = match self.collect.policy {
            Policy::Adapter { .. } => None,
            Policy::Uniform { .. } => Some("uniform"),
            Policy::Scripted { .. } => Some("scripted"),
        };
        if let Some(kind) = lockstep {
            return Err(Error::Config(format!(
                "{table}: collect_inputs replaces the `inputs` of [collect] policy = {{ kind = \
                 \"adapter\" }}; the {kind} policy steps the simulators in lockstep and chooses \
                 their inputs itself (use kind = \"adapter\", or drop collect_inputs)"
            )));
        }
        if s.command.is_none() && !matches!(inputs, CollectPolicy::Uniform { .. }) {
            return Err(Error::Config(format!(
                "{table}: collect_inputs = {}: the built-in system '{}' draws uniform inputs \
                 only; a planned or expert policy is run by an external adapter that implements \
                 it (`command`: the Drake Gen3's planned, a legged robot's expert)",
                inputs.describe(),
                s.env
            )));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use crate::messages::InputBound;
    use crate::scenario::Scenario;

    const BASE: &str = r#"
name = "demo"
[[sims]]
id = "pend"
env = "damped-pendulum"
REGION
[[sims]]
id = "other"
env = "damped-pendulum"
[collect]
policy = POLICY
train_windows = 10
val_windows = 2
test_windows = 2
"#;

    fn parse(region: &str, policy: &str) -> crate::error::Result<Scenario> {
        Scenario::parse(&BASE.replace("REGION", region).replace("POLICY", policy))
    }

    #[test]
    fn a_simulator_gets_its_own_region_over_the_shared_one() {
        let adapter = "{ kind = \"adapter\" }";
        let s = parse(
            "x0_center = [0.0, 0.0]\nx0_radius = [0.5, 1.0]\nu_low = -2.0\nu_high = [2.0]",
            adapter,
        )
        .unwrap();
        let r = s.sim_region(0).unwrap();
        assert_eq!(
            r.x0_box,
            Some((vec![-0.5, -1.0], vec![0.5, 1.0])),
            "centre ± radius"
        );
        assert_eq!(r.low, Some(InputBound::All(-2.0)));
        assert!(s.sim_region(1).unwrap().is_empty());
        let s = parse(
            "x0_low = [-1, -2]\nx0_high = [1, 2]",
            "{ kind = \"uniform\" }",
        )
        .unwrap();
        assert_eq!(
            s.sim_region(0).unwrap().x0_box,
            Some((vec![-1.0, -2.0], vec![1.0, 2.0]))
        );
    }

    #[test]
    fn a_bad_region_names_the_simulator_and_the_reason() {
        let err = |region: &str, policy: &str| parse(region, policy).unwrap_err().to_string();
        let uniform = "{ kind = \"uniform\" }";
        let e = err("x0_low = [-1, -2]", uniform);
        assert!(
            e.contains("[[sims]] 'pend'") && e.contains("go together"),
            "{e}"
        );
        let e = err("x0_low = [1, -2]\nx0_high = [0, 2]", uniform);
        assert!(
            e.contains("'pend'") && e.contains("the box is empty"),
            "{e}"
        );
        let e = err(
            "x0_low = [0]\nx0_high = [1]\nx0_center = [0]\nx0_radius = 1",
            uniform,
        );
        assert!(e.contains("not both"), "{e}");
        let e = err("u_low = 1.0\nu_high = 0.5", uniform);
        assert!(
            e.contains("'pend'") && e.contains("u_low 1 > u_high 0.5"),
            "{e}"
        );
        let e = err("u_low = [0, 1]\nu_high = [1, 2, 3]", uniform);
        assert!(e.contains("u_low has 2 values and u_high 3"), "{e}");
        let e = err("u_low = -1.0", "{ kind = \"scripted\", inputs = [[1.0]] }");
        assert!(e.contains("scripted policy"), "{e}");
        let planned = "{ kind = \"adapter\", inputs = { kind = \"planned\" } }";
        let e = err("x0_center = [0, 0]\nx0_radius = 0.1", planned);
        assert!(
            e.contains("'pend'") && e.contains("need uniform inputs"),
            "{e}"
        );
        // A lockstep box for one simulator only is fine with scripted inputs.
        assert!(parse(
            "x0_center = [0, 0]\nx0_radius = 0.1",
            "{ kind = \"scripted\", inputs = [[1.0]] }"
        )
        .is_ok());
    }

    /// An external adapter (`walker`) beside a built-in system (`pend`); `INPUTS` is the
    /// walker's `collect_inputs`, `PEND` more keys of the pendulum's entry.
    const MIXED: &str = r#"
name = "demo"
[[sims]]
id = "pend"
env = "damped-pendulum"
PEND
[[sims]]
id = "walker"
command = ["my-legged-adapter"]
INPUTS
[collect]
policy = POLICY
train_windows = 10
val_windows = 2
test_windows = 2
"#;

    fn mixed(inputs: &str, pend: &str, policy: &str) -> crate::error::Result<Scenario> {
        Scenario::parse(
            &MIXED
                .replace("INPUTS", inputs)
                .replace("PEND", pend)
                .replace("POLICY", policy),
        )
    }

    #[test]
    fn a_simulator_collects_with_its_own_inputs_over_the_shared_ones() {
        use crate::messages::{CollectPolicy, ExpertSettings};
        use crate::scenario::Policy;
        let adapter = "{ kind = \"adapter\", block = 7 }";
        let s = mixed("collect_inputs = { kind = \"expert\" }", "", adapter).unwrap();
        let expert = CollectPolicy::Expert(ExpertSettings::default());
        assert_eq!(
            s.sim_policy(1),
            Policy::Adapter {
                inputs: expert.clone(),
                block: 7
            },
            "the walker's own inputs, the shared block"
        );
        assert_eq!(s.sim_region(1).unwrap().inputs, Some(expert));
        assert_eq!(
            s.sim_policy(0),
            Policy::Adapter {
                inputs: CollectPolicy::default(),
                block: 7
            },
            "the pendulum keeps the shared inputs"
        );
        assert_eq!(s.sim_region(0).unwrap().inputs, None);
        // Its own region goes with its own uniform inputs, even when the shared ones are expert.
        let s = mixed(
            "collect_inputs = { kind = \"uniform\", low = -0.5 }\nx0_center = [0.0]\nx0_radius = 0.1",
            "collect_inputs = { kind = \"uniform\" }",
            "{ kind = \"adapter\", inputs = { kind = \"expert\" } }",
        )
        .unwrap();
        let r = s.sim_region(1).unwrap();
        assert_eq!(r.x0_box, Some((vec![-0.1], vec![0.1])));
        assert!(matches!(
            s.sim_policy(1),
            Policy::Adapter {
                inputs: CollectPolicy::Uniform { low: Some(InputBound::All(l)), .. },
                block: 500
            } if l == -0.5
        ));
        // The unknown key of its own inputs is refused (deny_unknown_fields inside).
        let e = mixed(
            "collect_inputs = { kind = \"expert\", pace = 1 }",
            "",
            adapter,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("pace"), "{e}");
    }

    #[test]
    fn own_inputs_a_simulator_cannot_collect_with_are_refused_naming_why() {
        let err = |inputs: &str, pend: &str, policy: &str| {
            mixed(inputs, pend, policy).unwrap_err().to_string()
        };
        let adapter = "{ kind = \"adapter\" }";
        let expert = "collect_inputs = { kind = \"expert\" }";
        // A built-in system draws uniform inputs only.
        let e = err("", expert, adapter);
        assert!(
            e.contains("[[sims]] 'pend'")
                && e.contains("built-in system 'damped-pendulum' draws uniform inputs only"),
            "{e}"
        );
        let planned = "collect_inputs = { kind = \"planned\" }";
        assert!(err("", planned, adapter).contains("uniform inputs only"));
        // Only the adapter policy has inputs to replace.
        for (policy, kind) in [
            ("{ kind = \"uniform\" }", "uniform"),
            ("{ kind = \"scripted\", inputs = [[1.0]] }", "scripted"),
        ] {
            let e = err(expert, "", policy);
            assert!(
                e.contains("[[sims]] 'walker'")
                    && e.contains("collect_inputs replaces")
                    && e.contains(&format!("the {kind} policy steps")),
                "{e}"
            );
        }
        // Expert inputs take no region: the simulator's own, or [collect]'s.
        let e = err(&format!("{expert}\nu_low = -1.0"), "", adapter);
        assert!(
            e.contains("'walker'") && e.contains("need uniform inputs"),
            "{e}"
        );
        let shared_box = "{ kind = \"adapter\" }\nx0_low = [0.0]\nx0_high = [1.0]";
        let e = err(expert, "", shared_box);
        assert!(
            e.contains("'walker' with [collect]'s initial-state box")
                && e.contains("need uniform inputs"),
            "{e}"
        );
        // The same without the override is fine.
        assert!(mixed("", "", shared_box).is_ok());
    }
}
