//! The table `koopbridge control` prints: one row of closed-loop metrics per controller.

use koopman::mpc::ClosedLoopMetrics;

/// Prints the column names.
pub fn print_header() {
    println!(
        "{:<26} {:>9} {:>9} {:>8} {:>10} {:>10} {:>9} {:>9} {:>6} {:>5}",
        "controller",
        "final err",
        "angle err",
        "t_goal",
        "track rms",
        "frobenius",
        "med ms",
        "p99 ms",
        "viol",
        "fb"
    );
}

/// Prints one controller's row.
pub fn print_row(m: &ClosedLoopMetrics) {
    println!(
        "{:<26} {:>9.4} {:>9.4} {:>8} {:>10.4} {:>10.3} {:>9.3} {:>9.3} {:>6} {:>5}{}",
        m.controller,
        m.final_error,
        m.final_angle_error,
        m.time_to_goal_s
            .map(|s| format!("{s:.2}s"))
            .unwrap_or_else(|| "never".into()),
        m.tracking_rms,
        m.tracking_frobenius,
        m.solve_ms_median,
        m.solve_ms_p99,
        m.input_violations,
        m.fallbacks,
        if m.diverged { "  DIVERGED" } else { "" }
    );
}
