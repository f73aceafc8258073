//! What a viewer shows, published on the session's `view/` keys only while someone subscribes:
//! the run's events and every closed-loop state with its reference, input, solve and the MPC's
//! plan in the simulator's coordinates (PROTOCOL.md §10).

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use koopman::model::LiftedModel;
use serde::Serialize;
use zenoh::pubsub::Publisher;
use zenoh::Wait;

use super::Event;
use crate::client::Client;
use crate::error::{Error, Result};
use crate::keyexpr::validate_chunk;

/// The run's view publishers (one for the events, one per simulator for its states) and the
/// models the plans are predicted with, each loaded once, when first watched.
pub struct RunView {
    client: Client,
    events: Publisher<'static>,
    steps: Mutex<HashMap<String, Arc<Publisher<'static>>>>,
    models_dir: PathBuf,
    models: Mutex<HashMap<String, Option<Arc<Predictor>>>>,
}

impl std::fmt::Debug for RunView {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RunView")
            .field("models_dir", &self.models_dir)
            .finish_non_exhaustive()
    }
}

/// One state of a closed loop (or replay) as a viewer sees it (`…/view/{sim}/step`, JSON).
#[derive(Debug, Serialize)]
pub struct ViewStep<'a> {
    /// The row's name as report.json gives it (a `[control]` loop: its model; a tracking task's
    /// row: `{model}+{label}`; a replay: `replay` or `replay+{label}`).
    pub row: &'a str,
    /// The reference's index in a tracking task's set; absent for a `[control]` loop.
    pub episode: Option<usize>,
    /// The step index of this state.
    pub k: usize,
    /// Its time, `k · dt`.
    pub t: f64,
    /// The state x_k (a non-finite value is `null`).
    pub x: &'a [f64],
    /// The reference r_k.
    pub reference: Vec<f64>,
    /// The input applied from this state; absent for the last state.
    pub u: Option<&'a [f64]>,
    /// The MPC's solve time inside the service, µs; absent for a replay and the last state.
    pub solve_us: Option<f64>,
    /// The solve's status (`solved`, `suboptimal`, `fallback`, `inaccurate`).
    pub status: Option<&'static str>,
    /// The MPC's plan from this state predicted by the model: x̂_k … x̂_{k+H}, in the simulator's
    /// coordinates; absent for a replay, the last state, and models without a linear lifting
    /// (NNDM, bilinear).
    pub plan: Option<Vec<Vec<f64>>>,
}

/// Which loop a control run is, for its view publications.
#[derive(Clone, Copy, Debug)]
pub struct StepView<'a> {
    /// The run's view.
    pub view: &'a RunView,
    /// The row name ([`ViewStep::row`]).
    pub row: &'a str,
    /// The reference's index ([`ViewStep::episode`]).
    pub episode: Option<usize>,
}

/// A lifted model and its matrices row by row (`[A | B]`, N × (N + nu)), for predicting a
/// plan's states.
struct Predictor {
    model: Box<dyn LiftedModel>,
    ab: Vec<f64>,
}

impl Predictor {
    fn new(model: Box<dyn LiftedModel>) -> Self {
        let (a, b) = (model.a(), model.b());
        let (n, nu) = (a.nrows(), b.ncols());
        let mut ab = Vec::with_capacity(n * (n + nu));
        for i in 0..n {
            ab.extend((0..n).map(|j| a[(i, j)]));
            ab.extend((0..nu).map(|j| b[(i, j)]));
        }
        Predictor { model, ab }
    }

    /// x̂_0 … x̂_H: `z = Φ(x)`, then `z ← A z + B u_j` for each planned input.
    fn states(&self, x: &[f64], plan_u: &[f64]) -> Option<Vec<Vec<f64>>> {
        let (nx, nu) = (self.model.nx(), self.model.nu());
        let mut zu = self.model.try_lift(x).ok()?;
        let n = zu.len();
        zu.resize(n + nu, 0.0);
        let mut next = vec![0.0; n];
        let mut out = vec![x.to_vec()];
        for u in plan_u.chunks_exact(nu) {
            zu[n..].copy_from_slice(u);
            for (row, z) in self.ab.chunks_exact(n + nu).zip(next.iter_mut()) {
                *z = row.iter().zip(&zu).map(|(r, v)| r * v).sum();
            }
            zu[..n].copy_from_slice(&next);
            out.push(next[..nx].to_vec());
        }
        Some(out)
    }
}

impl RunView {
    /// Declares the events publisher of `client`'s session; plans are predicted with the models
    /// saved under `models_dir/{name}`.
    pub fn declare(client: &Client, models_dir: PathBuf) -> Result<Self> {
        let events = client
            .session
            .declare_publisher(client.keys.view_events())
            .wait()
            .map_err(Error::zenoh)?;
        Ok(RunView {
            client: client.clone(),
            events,
            steps: Mutex::new(HashMap::new()),
            models_dir,
            models: Mutex::new(HashMap::new()),
        })
    }

    /// Publishes a run event (a phase, collection or control progress, a warning) when someone
    /// subscribes; the trainer publishes its own progress. Never fails the run.
    pub fn event(&self, e: &Event<'_>) {
        if !watched(&self.events) {
            return;
        }
        let v = match e {
            Event::Phase(text) => serde_json::json!({"event": "phase", "text": text}),
            Event::Collect(split, done, total) => {
                serde_json::json!({"event": "collect", "split": split, "done": done, "total": total})
            }
            Event::Control(done, total) => {
                serde_json::json!({"event": "control", "done": done, "total": total})
            }
            Event::Warning(text) => serde_json::json!({"event": "warning", "text": text}),
            Event::Train(_) => return,
        };
        put(&self.events, v.to_string().into_bytes());
    }

    /// The publisher of simulator `sim`'s view states, if someone subscribes to it.
    pub fn step_publisher(&self, sim: &str) -> Option<Arc<Publisher<'static>>> {
        let mut steps = self.steps.lock().ok()?;
        let p = match steps.get(sim) {
            Some(p) => Arc::clone(p),
            None => {
                let key = self.client.keys.view_step(sim).ok()?;
                let p = self.client.session.declare_publisher(key).wait().ok()?;
                let p = Arc::new(p);
                steps.insert(sim.to_string(), Arc::clone(&p));
                p
            }
        };
        watched(&p).then_some(p)
    }

    /// Publishes `step` on `publisher` (JSON). Never fails the run.
    pub fn publish_step(publisher: &Publisher<'static>, step: &ViewStep<'_>) {
        if let Ok(bytes) = serde_json::to_vec(step) {
            put(publisher, bytes);
        }
    }

    /// The plan's states x̂_0 … x̂_H predicted by model `model` from `x` under the planned inputs
    /// `plan_u` (`H·nu`), or `None` when the model has no linear lifting or cannot be read (it
    /// is then not tried again).
    pub fn plan(&self, model: &str, x: &[f64], plan_u: &[f64]) -> Option<Vec<Vec<f64>>> {
        let p = {
            let mut models = self.models.lock().ok()?;
            models
                .entry(model.to_string())
                .or_insert_with(|| self.load(model))
                .clone()?
        };
        p.states(x, plan_u)
    }

    fn load(&self, name: &str) -> Option<Arc<Predictor>> {
        validate_chunk("model name", name).ok()?;
        let model = koopman::model::load_lifted(&self.models_dir.join(name)).ok()?;
        Some(Arc::new(Predictor::new(model)))
    }
}

/// Whether someone subscribes to what `p` publishes.
fn watched(p: &Publisher<'_>) -> bool {
    p.matching_status().wait().is_ok_and(|m| m.matching())
}

/// Puts `bytes` on `p`; a failure is logged, never returned (a viewer never stops a run).
fn put(p: &Publisher<'_>, bytes: Vec<u8>) {
    if let Err(e) = p.put(bytes).wait() {
        tracing::debug!("view publication failed: {e}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use koopman::model::matrix::MatrixModel;

    #[test]
    fn a_plan_is_the_model_rolled_out_under_the_planned_inputs() {
        // x⁺ = A x + B u with A = [[1, 0.1], [0, 0.9]], B = [0, 0.5] (nx = N = 2, nu = 1):
        // from x = (1, 2) with u = 2 then −4: (1.2, 2.8), then (1.48, 0.52).
        let m = MatrixModel::new(
            faer::mat![[1.0, 0.1], [0.0, 0.9]],
            faer::mat![[0.0], [0.5]],
            faer::Mat::zeros(0, 2),
            Vec::new(),
        )
        .unwrap();
        let p = Predictor::new(Box::new(m));
        let got = p.states(&[1.0, 2.0], &[2.0, -4.0]).unwrap();
        let want = [[1.0, 2.0], [1.2, 2.8], [1.48, 0.52]];
        assert_eq!(got.len(), 3);
        for (g, w) in got.iter().zip(want) {
            assert!(
                g.iter().zip(w).all(|(a, b)| (a - b).abs() < 1e-12),
                "{got:?}"
            );
        }
        assert!(p.states(&[f64::NAN, 0.0], &[1.0]).is_none());
        assert!(
            p.states(&[1.0], &[1.0]).is_none(),
            "a state of the wrong length"
        );
    }
}
