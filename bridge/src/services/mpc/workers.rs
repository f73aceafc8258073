//! One solver thread per configured model: the MPC service's queries arrive on one thread, and
//! each `solve` is handed to its model's thread, which answers it, so that the closed loops of
//! several simulators (one model each) are solved side by side instead of in turn.

use std::collections::HashMap;
use std::sync::mpsc;
use std::thread::JoinHandle;

use zenoh::query::Query;

use super::controller::ServiceController;
use crate::codec::{SolveReply, SolveRequest};
use crate::error::{ErrorCode, ErrorReply};
use crate::services::respond;

/// What a model's thread is asked to do, in order of arrival.
enum Job {
    /// Plan for this request and answer the query.
    Solve(Query, Box<SolveRequest>),
    /// Use this controller from now on (the model was configured again).
    Replace(Box<ServiceController>),
}

/// Most models an MPC service keeps configured (a controller and a solver thread each;
/// PROTOCOL.md, "Limits"): configuring or solving for another model past it is `busy`.
pub const MAX_MODELS: usize = 32;

/// A model's solver thread.
struct Worker {
    jobs: mpsc::Sender<Job>,
    thread: JoinHandle<()>,
}

/// The solver threads of an MPC service, by model name.
#[derive(Default)]
pub struct SolveWorkers {
    by_model: HashMap<String, Worker>,
}

impl SolveWorkers {
    /// Whether `model` has a thread (was configured, or solved for, before).
    pub fn has(&self, model: &str) -> bool {
        self.by_model.contains_key(model)
    }

    /// Gives `model` the controller `c`: a new thread for a new model; for a known one, solves
    /// queued before this call still use the old controller, every later one the new.
    /// `internal` if no thread could be started; `busy` for a new model when [`MAX_MODELS`]
    /// are configured.
    pub fn install(&mut self, model: &str, c: ServiceController) -> Result<(), ErrorReply> {
        self.admit(model)?;
        let c = match self.by_model.get(model) {
            None => c,
            Some(w) => match w.jobs.send(Job::Replace(Box::new(c))) {
                Ok(()) => return Ok(()),
                // The thread ended (a panic in a solve): a fresh one gets the controller.
                Err(mpsc::SendError(job)) => {
                    tracing::warn!("the solver thread of model '{model}' had ended; starting anew");
                    if let Some(w) = self.by_model.remove(model) {
                        let _ = w.thread.join();
                    }
                    let Job::Replace(c) = job else {
                        return Ok(());
                    };
                    *c
                }
            },
        };
        let (jobs, rx) = mpsc::channel();
        let name = model.to_string();
        let thread = std::thread::Builder::new()
            .name(format!("mpc-{model}"))
            .spawn(move || serve_model(&name, c, rx))
            .map_err(|e| {
                ErrorReply::new(
                    ErrorCode::Internal,
                    format!("could not start a solver thread: {e}"),
                )
            })?;
        self.by_model
            .insert(model.to_string(), Worker { jobs, thread });
        Ok(())
    }

    /// `busy` when `model` is new and [`MAX_MODELS`] models are configured (checked before a
    /// controller is built for it).
    pub fn admit(&self, model: &str) -> Result<(), ErrorReply> {
        if self.has(model) || self.by_model.len() < MAX_MODELS {
            return Ok(());
        }
        Err(ErrorReply::new(
            ErrorCode::Busy,
            format!("{MAX_MODELS} models are configured (the most); model '{model}' is not"),
        ))
    }

    /// Hands query `q` (request `req`) to `model`'s thread, which answers it. `Err` (answered
    /// here) when the model has no live thread.
    pub fn solve(&self, model: &str, q: Query, req: SolveRequest) -> Result<(), ErrorReply> {
        let w = self.by_model.get(model).ok_or_else(|| {
            ErrorReply::new(
                ErrorCode::NotFound,
                format!("model '{model}' is not configured"),
            )
        })?;
        w.jobs.send(Job::Solve(q, Box::new(req))).map_err(|_| {
            ErrorReply::new(
                ErrorCode::Internal,
                format!("the solver thread of model '{model}' has ended"),
            )
        })
    }

    /// Ends every thread after the solves already handed to it.
    pub fn shut_down(self) {
        for (_, w) in self.by_model {
            drop(w.jobs);
            let _ = w.thread.join();
        }
    }
}

/// The body of a model's thread: answers each solve with its controller until the service
/// drops the sender.
fn serve_model(model: &str, mut c: ServiceController, jobs: mpsc::Receiver<Job>) {
    while let Ok(job) = jobs.recv() {
        match job {
            Job::Replace(new) => c = *new,
            Job::Solve(q, req) => {
                let reply = c
                    .solve_with_feedforward(&req.x, &req.reference, &req.feedforward)
                    .map(|sol| {
                        SolveReply {
                            status: sol.status,
                            iterations: sol.iterations as u32,
                            solve_time_ns: sol.solve_time.as_nanos() as u64,
                            u: sol.u,
                        }
                        .encode()
                    })
                    .map_err(|e| e.to_reply());
                respond(&q, reply);
            }
        }
    }
    tracing::debug!("solver thread of model '{model}' ends");
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Past [`MAX_MODELS`] a new model is `busy`; a configured one is always admitted.
    #[test]
    fn configured_models_are_bounded() {
        let mut w = SolveWorkers::default();
        for i in 0..MAX_MODELS {
            assert!(w.admit(&format!("m{i}")).is_ok());
            let (jobs, _) = mpsc::channel();
            let thread = std::thread::spawn(|| ());
            w.by_model.insert(format!("m{i}"), Worker { jobs, thread });
        }
        assert_eq!(w.admit("another").unwrap_err().code, ErrorCode::Busy);
        assert!(w.admit("m3").is_ok());
        w.shut_down();
    }
}
