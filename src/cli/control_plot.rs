//! The plot of one `koopbridge control` run: states against references and inputs against their
//! bounds, as one PNG.

use std::path::Path;

use koopman::mpc::{ClosedLoopMetrics, Trajectory};
use koopman::systems::System;

use crate::plot::{time_series_png, Panel, Series};

/// Draws the angles, the other states (each with its reference) and the inputs (with the bounds)
/// of a closed-loop run into `path`.
pub fn plot_trajectory(
    path: &Path,
    system: &dyn System,
    m: &ClosedLoopMetrics,
    tr: &Trajectory,
    lo: &[f64],
    hi: &[f64],
) -> anyhow::Result<()> {
    let names = system.state_names();
    let angles = system.angle_indices();
    let column = |rows: &[Vec<f64>], i: usize| rows.iter().map(|r| r[i]).collect::<Vec<f64>>();
    let mut angle_panel = Panel {
        title: "angles".into(),
        y_label: "rad".into(),
        series: vec![],
    };
    let mut rate_panel = Panel {
        title: "other states".into(),
        y_label: "value".into(),
        series: vec![],
    };
    for (i, name) in names.iter().enumerate() {
        let panel = if angles.contains(&i) {
            &mut angle_panel
        } else {
            &mut rate_panel
        };
        panel
            .series
            .push(Series::new(name.clone(), &tr.t, &column(&tr.x, i)));
        panel
            .series
            .push(Series::new(format!("{name} ref"), &tr.t, &column(&tr.r, i)).dashed());
    }
    let tu: Vec<f64> = tr.t[..tr.u.len()].to_vec();
    let mut input_panel = Panel {
        title: "inputs".into(),
        y_label: "u".into(),
        series: vec![],
    };
    for (i, name) in system.input_names().iter().enumerate() {
        input_panel
            .series
            .push(Series::new(name.clone(), &tu, &column(&tr.u, i)));
    }
    let ends = [
        tu.first().copied().unwrap_or(0.0),
        tu.last().copied().unwrap_or(1.0),
    ];
    if let (Some(l), Some(h)) = (
        lo.iter().copied().reduce(f64::min),
        hi.iter().copied().reduce(f64::max),
    ) {
        input_panel
            .series
            .push(Series::new("u max", &ends, &[h, h]).dashed());
        input_panel
            .series
            .push(Series::new("u min", &ends, &[l, l]).dashed());
    }
    let title = format!("{} {:?} — {}", m.env, m.task, m.controller).to_lowercase();
    time_series_png(
        path,
        &title,
        "t [s]",
        &[angle_panel, rate_panel, input_panel],
        1000,
    )
}
