//! The warnings a finished closed loop deserves: the MPC's unsolved steps and the simulator's
//! episode ends, worded for the console and report.json's `warnings`.

use super::closed_loop::ControlReport;

impl ControlReport {
    /// The warning a loop whose MPC did not solve every step deserves (`None` when every
    /// solve was `solved`): how many of how many steps, by status, and what that means.
    pub fn not_solved_warning(&self) -> Option<String> {
        if self.not_solved == 0 {
            return None;
        }
        let by: Vec<String> = self
            .not_solved_by_status
            .iter()
            .map(|(k, v)| format!("{k} {v}"))
            .collect();
        let fallback = self
            .not_solved_by_status
            .get("fallback")
            .copied()
            .unwrap_or(0);
        Some(format!(
            "control of '{}' (model '{}'): the MPC did not solve {} of {} steps ({}){}",
            self.sim,
            self.model,
            self.not_solved,
            self.u.len(),
            by.join(", "),
            if fallback > 0 {
                "; on a fallback the solver failed and the previous plan, shifted and clamped to \
                 the bounds, was applied: check [control].mpc (bounds, x_min/x_max, solver, \
                 max_iterations, time_limit) and the model"
            } else {
                "; check [control].mpc (max_iterations, time_limit) — or, with a bilinear model, \
                 'suboptimal' is its sequential convex MPC reaching its cap of 3 linearisations \
                 (the best plan found is applied; not a [control].mpc setting)"
            }
        ))
    }
}

impl ControlReport {
    /// Every warning this loop deserves, in the order a reader should see them: the MPC's
    /// unsolved steps, then the simulator's episode ends.
    pub fn warnings(&self) -> Vec<String> {
        self.not_solved_warning()
            .into_iter()
            .chain(self.terminated_warning())
            .collect()
    }

    /// The warning a loop whose simulator flagged an episode end deserves (`None` otherwise):
    /// from which step, for how many, and that the loop went on.
    pub fn terminated_warning(&self) -> Option<String> {
        let f = &self.step_flags;
        let first = f.first_terminated?;
        Some(format!(
            "control of '{}' (model '{}'): the simulator reported the episode ended \
             (terminated: a fall or the task's end) at step {first}, and at {} of {} steps; the \
             loop went on, so the metrics include the steps after it",
            self.sim,
            self.model,
            f.terminated,
            self.u.len()
        ))
    }
}
