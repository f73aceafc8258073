//! The console line of a finished closed loop: its errors, its time to goal, and how its inputs
//! were decided (the MPC's solve figures, or the baseline rule that needed no model).

use super::closed_loop::ControlReport;
use crate::scenario::Controller;

/// `"N steps"`, or `"never"` when the goal was not reached and held.
pub fn time_to_goal_text(steps: Option<usize>) -> String {
    steps.map_or_else(|| "never".into(), |k| format!("{k} steps"))
}

impl ControlReport {
    /// `"0"`, or the count with its statuses: `"500 of 500 (fallback 500)"`.
    pub fn not_solved_text(&self) -> String {
        if self.not_solved == 0 {
            return "0".into();
        }
        let by: Vec<String> = self
            .not_solved_by_status
            .iter()
            .map(|(k, v)| format!("{k} {v}"))
            .collect();
        format!(
            "{} of {} ({})",
            self.not_solved,
            self.u.len(),
            by.join(", ")
        )
    }

    /// The loop's summary line: `control of 'SIM' (LABEL): final error …, tracking RMS …, time
    /// to goal …`, then the MPC's solve figures — or, for a baseline, which rule decided (it
    /// asked no solver). An unlabelled row names its model when `by_model` (several kinds).
    pub fn summary_line(&self, by_model: bool) -> String {
        let name = match (&self.label, by_model) {
            (Some(label), _) => format!(" ({label})"),
            (None, true) => format!(" with model '{}'", self.model),
            (None, false) => String::new(),
        };
        let decided = match self.controller {
            Controller::Mpc => format!(
                "not solved {}, solve median {:.0} µs, round trip median {:.0} µs",
                self.not_solved_text(),
                self.solve_median_us,
                self.solve_round_trip_median_us
            ),
            other => format!("controller {} (no model)", other.name()),
        };
        format!(
            "control of '{}'{name}: final error {:.4}, tracking RMS {:.4}, time to goal {}, {decided}",
            self.sim,
            self.final_error,
            self.tracking_rms_total,
            time_to_goal_text(self.time_to_goal_steps),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::time_to_goal_text;

    #[test]
    fn a_goal_never_reached_reads_never() {
        assert_eq!(time_to_goal_text(None), "never");
        assert_eq!(time_to_goal_text(Some(31)), "31 steps");
    }
}
