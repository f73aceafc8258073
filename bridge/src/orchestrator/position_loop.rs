//! The position loop on a plan (`[control] position_loop`): before each error-state MPC solve the
//! planned velocities — in the planned state and in the feed-forward window alike — are
//! corrected by `−gain · (q − q_plan)` and the inputs clipped to the MPC's bounds.

use crate::scenario::PositionLoopSpec;

/// A checked position loop for a simulator with `nx` states and `nu` inputs.
#[derive(Clone, Debug, PartialEq)]
pub struct PositionLoop {
    spec: PositionLoopSpec,
    u_min: Vec<f64>,
    u_max: Vec<f64>,
}

impl PositionLoop {
    /// Checks `spec` against the simulator's dimensions (`nu` positions and velocities, distinct
    /// state indices below `nx`, a finite gain ≥ 0); the corrected inputs are clipped to
    /// `u_min`/`u_max` (`nu` values each, infinite where unbounded; `None`: unbounded). The error
    /// says what does not fit.
    pub fn new(
        spec: &PositionLoopSpec,
        nx: usize,
        nu: usize,
        u_min: Option<&[f64]>,
        u_max: Option<&[f64]>,
    ) -> Result<Self, String> {
        let bad = |m: String| Err(format!("position_loop: {m}"));
        for (name, idx) in [("position", &spec.position), ("velocity", &spec.velocity)] {
            if idx.len() != nu {
                return bad(format!(
                    "{name} has {} indices; the simulator has {nu} inputs (input i commands velocity[i] of position[i])",
                    idx.len()
                ));
            }
            if let Some(i) = idx.iter().find(|&&i| i >= nx) {
                return bad(format!(
                    "{name} index {i} is not a state (the simulator has {nx} states)"
                ));
            }
        }
        let mut all: Vec<usize> = spec
            .position
            .iter()
            .chain(&spec.velocity)
            .copied()
            .collect();
        all.sort_unstable();
        if all.windows(2).any(|w| w[0] == w[1]) {
            return bad(format!(
                "position {:?} and velocity {:?} must name distinct states",
                spec.position, spec.velocity
            ));
        }
        if !(spec.gain.is_finite() && spec.gain >= 0.0) {
            return bad(format!("gain must be finite and ≥ 0, got {}", spec.gain));
        }
        let bound = |b: Option<&[f64]>, inf: f64| match b {
            Some(b) if b.len() == nu => Ok(b.to_vec()),
            Some(b) => Err(format!(
                "position_loop: {} input bounds for {nu} inputs",
                b.len()
            )),
            None => Ok(vec![inf; nu]),
        };
        Ok(PositionLoop {
            spec: spec.clone(),
            u_min: bound(u_min, f64::NEG_INFINITY)?,
            u_max: bound(u_max, f64::INFINITY)?,
        })
    }

    /// The settings it runs with.
    pub fn spec(&self) -> &PositionLoopSpec {
        &self.spec
    }

    /// Corrects, for the measured state `x`, the planned state of this step `plan_state` (`nx`
    /// values) and the feed-forward window `feedforward` (`H·nu` values, step-major) in place:
    /// `c = −gain · (x[position] − plan_state[position])` is added to the planned velocities
    /// and to every planned input, which is then clipped to the bounds.
    pub fn correct(&self, x: &[f64], plan_state: &mut [f64], feedforward: &mut [f64]) {
        let s = &self.spec;
        let c: Vec<f64> = s
            .position
            .iter()
            .map(|&i| -s.gain * (x[i] - plan_state[i]))
            .collect();
        for (&v, ci) in s.velocity.iter().zip(&c) {
            plan_state[v] += ci;
        }
        let nu = c.len();
        for step in feedforward.chunks_mut(nu) {
            for (i, u) in step.iter_mut().enumerate() {
                *u = (*u + c[i]).clamp(self.u_min[i], self.u_max[i]);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(gain: f64) -> PositionLoopSpec {
        PositionLoopSpec {
            position: vec![1, 2],
            velocity: vec![3, 4],
            gain,
        }
    }

    #[test]
    fn corrects_the_planned_velocities_and_every_input_then_clips() {
        let pl =
            PositionLoop::new(&spec(10.0), 5, 2, Some(&[-1.0, -1.0]), Some(&[1.0, 1.0])).unwrap();
        // x = [ee, q1, q2, qd1, qd2]; the plan is 0.01 ahead on q1 and 0.02 behind on q2.
        let x = [9.0, 0.10, 0.20, 0.0, 0.0];
        let mut state = vec![8.0, 0.11, 0.18, 0.5, -0.5];
        let mut ff = vec![0.5, -0.5, 0.95, -0.95];
        pl.correct(&x, &mut state, &mut ff);
        // c = −10 · (x_q − plan_q) = (+0.1, −0.2), written out by hand.
        let expect_state = [8.0, 0.11, 0.18, 0.6, -0.7];
        let expect_ff = [0.6, -0.7, 1.0, -1.0]; // 1.05 and −1.15 clipped
        for (a, b) in state
            .iter()
            .zip(expect_state)
            .chain(ff.iter().zip(expect_ff))
        {
            assert!((a - b).abs() < 1e-12, "{state:?} {ff:?}");
        }
        // Gain 0 leaves the plan as it is (inside the bounds).
        let off = PositionLoop::new(&spec(0.0), 5, 2, None, None).unwrap();
        let (mut s2, mut f2) = (vec![8.0, 0.11, 0.18, 0.5, -0.5], vec![0.5, -0.5]);
        off.correct(&x, &mut s2, &mut f2);
        assert_eq!(
            (s2, f2),
            (vec![8.0, 0.11, 0.18, 0.5, -0.5], vec![0.5, -0.5])
        );
    }

    #[test]
    fn refuses_what_does_not_fit_the_simulator() {
        let e =
            |s: &PositionLoopSpec, nx, nu| PositionLoop::new(s, nx, nu, None, None).unwrap_err();
        assert!(e(&spec(1.0), 5, 3).contains("3 inputs"));
        assert!(e(&spec(1.0), 4, 2).contains("index 4"));
        let mut same = spec(1.0);
        same.velocity = vec![2, 3];
        assert!(e(&same, 5, 2).contains("distinct"));
        assert!(e(&spec(f64::NAN), 5, 2).contains("gain"));
        assert!(PositionLoop::new(&spec(1.0), 5, 2, Some(&[0.0]), None).is_err());
    }
}
