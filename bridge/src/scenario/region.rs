//! Each simulator's data region: its `[[sims]]` initial-state box and input bounds over
//! `[collect]`'s, checked without the simulator when the file is read.

use super::Scenario;
use crate::collect::SimRegion;
use crate::error::{Error, Result};
use crate::messages::InputBound;
use crate::scenario::Policy;

impl Scenario {
    /// The data region of simulator `sims[j]` that overrides `[collect]`'s ([`SimRegion`]; empty
    /// when its entry sets none): its `x0_low`/`x0_high` or `x0_center`/`x0_radius`, and
    /// `u_low`/`u_high`. Checked without the simulator: the box as `[collect]`'s
    /// ([`super::collect::x0_box_of`]); bounds finite, of equal length (or one of them a single
    /// value), `low ≤ high`; bounds only with a uniform policy (lockstep or adapter inputs); a
    /// box not with a planned or expert adapter policy. The lengths against `nx`/`nu` are
    /// checked with the simulator's `info` ([`crate::orchestrator::validate::validate_scenario`]).
    pub fn sim_region(&self, j: usize) -> Result<SimRegion> {
        let Some(s) = self.sims.get(j) else {
            return Ok(SimRegion::default());
        };
        let table = format!("[[sims]] '{}'", s.id);
        let x0_box =
            super::collect::x0_box_of(&table, [&s.x0_low, &s.x0_high, &s.x0_center], &s.x0_radius)?;
        let region = SimRegion {
            x0_box,
            low: s.u_low.clone(),
            high: s.u_high.clone(),
        };
        if region.is_empty() {
            return Ok(region);
        }
        self.collect.check_takes_region(&table)?;
        if (region.low.is_some() || region.high.is_some())
            && matches!(self.collect.policy, Policy::Scripted { .. })
        {
            return Err(Error::Config(format!(
                "{table}: u_low/u_high bound uniform random inputs; the scripted policy gives its \
                 inputs (drop them, or use kind = \"uniform\" or \"adapter\")"
            )));
        }
        check_bounds(&table, &region.low, &region.high)?;
        Ok(region)
    }
}

/// Input bounds as a scenario gives them: finite, `low ≤ high` where both are given (a single
/// value against every value of the other side), and lengths that fit each other.
fn check_bounds(table: &str, low: &Option<InputBound>, high: &Option<InputBound>) -> Result<()> {
    let values = |b: &Option<InputBound>| match b {
        Some(InputBound::All(v)) => vec![*v],
        Some(InputBound::Each(v)) => v.clone(),
        None => Vec::new(),
    };
    let bad = |m: String| Err(Error::Config(format!("{table}: {m}")));
    let (lo, hi) = (values(low), values(high));
    if let Some(v) = lo.iter().chain(&hi).find(|v| !v.is_finite()) {
        return bad(format!("u_low and u_high must be finite, got {v}"));
    }
    let pairs: Vec<(f64, f64)> = match (lo.len(), hi.len()) {
        (0, _) | (_, 0) => Vec::new(),
        (1, _) => hi.iter().map(|&h| (lo[0], h)).collect(),
        (_, 1) => lo.iter().map(|&l| (l, hi[0])).collect(),
        (a, b) if a == b => lo.iter().copied().zip(hi.iter().copied()).collect(),
        (a, b) => return bad(format!("u_low has {a} values and u_high {b}")),
    };
    if let Some((l, h)) = pairs.iter().find(|(l, h)| l > h) {
        return bad(format!("u_low {l} > u_high {h}"));
    }
    Ok(())
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
}
