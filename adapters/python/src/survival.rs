//! `survival`: the scenario engine's survival metric of a tracking task (`bridge`'s
//! `orchestrator::survival`), for runs made outside it (the legged expert's own rollouts).

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use bridge::orchestrator::survival::survival_of_run;
use bridge::scenario::SurvivalSpec;

use crate::convert::rows_f64;

/// Survival steps of the run `x` (states `x_0 .. x_n`, `x_0` the shared start) with the
/// simulator's fall flags `terminated` (one per state) against `reference` (`r_0 .. r_L`):
/// the steps completed before the first state whose mean absolute error over `states` exceeds
/// `threshold`, that fell or that is not finite — or `length` (default `L`) when none fails;
/// exactly what a `[control]` tracking task with `survival = { threshold, states }` reports.
/// `ValueError` for a bad threshold, a state index out of range, mismatched lengths, or a run
/// shorter than `length` without a failure.
#[pyfunction]
#[pyo3(signature = (x, reference, terminated, threshold, states, length = None))]
pub fn survival(
    x: &Bound<'_, PyAny>,
    reference: &Bound<'_, PyAny>,
    terminated: Vec<bool>,
    threshold: f64,
    states: Vec<usize>,
    length: Option<usize>,
) -> PyResult<usize> {
    let (n, nx, xv) = rows_f64(x, "x")?;
    let (l, rx, rv) = rows_f64(reference, "reference")?;
    let err = |m: String| Err(PyValueError::new_err(format!("survival: {m}")));
    if nx != rx {
        return err(format!("x has {nx} states per row, reference {rx}"));
    }
    if !(threshold.is_finite() && threshold > 0.0) {
        return err(format!(
            "threshold must be a finite number > 0, got {threshold}"
        ));
    }
    if states.is_empty() {
        return err("states must name at least one state index".into());
    }
    if let Some(&i) = states.iter().find(|&&i| i >= nx) {
        return err(format!(
            "state {i} is out of range (0..{})",
            nx.saturating_sub(1)
        ));
    }
    let rows = |v: &[f64], r: usize| -> Vec<Vec<f64>> {
        (0..r).map(|i| v[i * nx..(i + 1) * nx].to_vec()).collect()
    };
    let spec = SurvivalSpec { threshold, states };
    let length = length.unwrap_or(l.saturating_sub(1));
    survival_of_run(&rows(&xv, n), &terminated, &rows(&rv, l), length, &spec)
        .map_err(|m| PyValueError::new_err(format!("survival: {m}")))
}
