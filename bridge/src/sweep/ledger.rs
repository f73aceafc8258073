//! Where every point of a sweep is — waiting, on a trainer (which job), finished or failed — and
//! the decisions of the dispatcher: which trainer gets the next point (the least loaded), what
//! happens when a trainer vanishes (its points wait for it a grace period, then go to others and
//! the orphaned jobs are cancelled if it comes back). Pure: no network, time passed in.

use std::collections::{BTreeMap, BTreeSet};
use std::time::{Duration, Instant};

/// The state of one point.
#[derive(Clone, Debug, PartialEq)]
pub enum PointState {
    /// Not on any trainer.
    Waiting,
    /// Submitted to `trainer` as `job`; `gone_since` is set while that trainer has no
    /// liveliness token.
    Submitted {
        /// Trainer id.
        trainer: String,
        /// Job id on that trainer.
        job: String,
        /// When the trainer's token disappeared (None while it is alive).
        gone_since: Option<Instant>,
    },
    /// Finished (its result is in the sweep's folder).
    Done,
    /// Failed `attempts` times; the last error.
    Failed {
        /// The last error message.
        error: String,
        /// Attempts so far.
        attempts: u32,
    },
}

/// The ledger of a sweep of `n` points.
#[derive(Debug)]
pub struct Ledger {
    states: Vec<PointState>,
    attempts: Vec<u32>,
    max_attempts: u32,
    grace: Duration,
    /// Jobs left behind on a trainer that vanished and whose points went elsewhere (trainer →
    /// job → point): cancel them when the trainer returns, so that no point is trained twice.
    orphans: BTreeMap<String, BTreeMap<String, usize>>,
}

impl Ledger {
    /// A ledger of `n` waiting points. A failed point is retried until it failed
    /// `max_attempts` times; a vanished trainer's points are moved after `grace`.
    pub fn new(n: usize, max_attempts: u32, grace: Duration) -> Self {
        Ledger {
            states: vec![PointState::Waiting; n],
            attempts: vec![0; n],
            max_attempts: max_attempts.max(1),
            grace,
            orphans: BTreeMap::new(),
        }
    }

    /// The state of point `i`.
    pub fn state(&self, i: usize) -> &PointState {
        &self.states[i]
    }

    /// Marks point `i` finished (e.g. found in the folder of an earlier run of the sweep).
    pub fn done(&mut self, i: usize) {
        self.states[i] = PointState::Done;
    }

    /// Records that point `i` went to `trainer` as `job`.
    pub fn submitted(&mut self, i: usize, trainer: &str, job: &str) {
        self.attempts[i] += 1;
        self.states[i] = PointState::Submitted {
            trainer: trainer.into(),
            job: job.into(),
            gone_since: None,
        };
    }

    /// Records that point `i`'s job failed: it waits again for another attempt, or stays failed
    /// once it has failed `max_attempts` times.
    pub fn failed(&mut self, i: usize, error: &str) {
        self.states[i] = if self.attempts[i] >= self.max_attempts {
            PointState::Failed {
                error: error.into(),
                attempts: self.attempts[i],
            }
        } else {
            PointState::Waiting
        };
    }

    /// Gives point `i` up for good (an error that another attempt would not change).
    pub fn give_up(&mut self, i: usize, error: &str) {
        self.states[i] = PointState::Failed {
            error: error.into(),
            attempts: self.attempts[i],
        };
    }

    /// Points on `trainer` and their job ids.
    pub fn on_trainer(&self, trainer: &str) -> Vec<(usize, String)> {
        self.states
            .iter()
            .enumerate()
            .filter_map(|(i, s)| match s {
                PointState::Submitted {
                    trainer: t, job, ..
                } if t == trainer => Some((i, job.clone())),
                _ => None,
            })
            .collect()
    }

    /// Follows the trainers' liveliness at time `now`: a submitted point whose trainer is not in
    /// `alive` starts (or continues) its grace period; past it, the point waits again and its
    /// job is remembered as an orphan. A trainer back in time keeps its points. Returns the
    /// points moved off vanished trainers.
    pub fn follow_liveliness(&mut self, alive: &BTreeSet<String>, now: Instant) -> Vec<usize> {
        let mut moved = Vec::new();
        for (i, s) in self.states.iter_mut().enumerate() {
            if let PointState::Submitted {
                trainer,
                job,
                gone_since,
            } = s
            {
                if alive.contains(trainer.as_str()) {
                    *gone_since = None;
                    continue;
                }
                let since = *gone_since.get_or_insert(now);
                if now.duration_since(since) >= self.grace {
                    self.orphans
                        .entry(trainer.clone())
                        .or_default()
                        .insert(job.clone(), i);
                    self.attempts[i] = self.attempts[i].saturating_sub(1);
                    *s = PointState::Waiting;
                    moved.push(i);
                }
            }
        }
        moved
    }

    /// Orphaned jobs on trainers that are alive again, with their points: the caller cancels
    /// them (at once where the point is no longer waiting; a waiting point may adopt its orphan
    /// instead), then calls [`Ledger::orphans_cancelled`].
    pub fn orphans_to_cancel(&self, alive: &BTreeSet<String>) -> Vec<(String, String, usize)> {
        self.orphans
            .iter()
            .filter(|(t, _)| alive.contains(t.as_str()))
            .flat_map(|(t, jobs)| jobs.iter().map(|(j, i)| (t.clone(), j.clone(), *i)))
            .collect()
    }

    /// Forgets an orphan once it was cancelled.
    pub fn orphans_cancelled(&mut self, trainer: &str, job: &str) {
        if let Some(jobs) = self.orphans.get_mut(trainer) {
            jobs.remove(job);
            if jobs.is_empty() {
                self.orphans.remove(trainer);
            }
        }
    }

    /// Which waiting points go to which trainers now. `load` is each alive trainer's number of
    /// queued and running jobs (as it reports); a trainer takes points while its load is below
    /// `per_trainer`, the least loaded first (ties by id), waiting points in order.
    pub fn assign(
        &self,
        load: &BTreeMap<String, usize>,
        per_trainer: usize,
    ) -> Vec<(usize, String)> {
        let mut load: BTreeMap<String, usize> = load.clone();
        let mut out = Vec::new();
        for (i, s) in self.states.iter().enumerate() {
            if *s != PointState::Waiting {
                continue;
            }
            let Some(t) = load
                .iter()
                .filter(|(_, l)| **l < per_trainer)
                .min_by(|a, b| a.1.cmp(b.1).then(a.0.cmp(b.0)))
                .map(|(t, _)| t.clone())
            else {
                break;
            };
            *load.entry(t.clone()).or_default() += 1;
            out.push((i, t));
        }
        out
    }

    /// Counts `(waiting, submitted, done, failed)`.
    pub fn counts(&self) -> (usize, usize, usize, usize) {
        let mut c = (0, 0, 0, 0);
        for s in &self.states {
            match s {
                PointState::Waiting => c.0 += 1,
                PointState::Submitted { .. } => c.1 += 1,
                PointState::Done => c.2 += 1,
                PointState::Failed { .. } => c.3 += 1,
            }
        }
        c
    }

    /// Whether every point is done or failed for good.
    pub fn finished(&self) -> bool {
        let (w, s, _, _) = self.counts();
        w == 0 && s == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn alive(ids: &[&str]) -> BTreeSet<String> {
        ids.iter().map(|s| s.to_string()).collect()
    }

    fn load(pairs: &[(&str, usize)]) -> BTreeMap<String, usize> {
        pairs.iter().map(|(t, l)| (t.to_string(), *l)).collect()
    }

    #[test]
    fn assignment_fills_the_least_loaded_trainer_first() {
        let l = Ledger::new(5, 2, Duration::from_secs(5));
        let a = l.assign(&load(&[("a", 1), ("b", 0)]), 2);
        // b (0) gets one, then a and b tie at 1 -> a by id, then b; a and b are both full (2).
        assert_eq!(
            a,
            vec![(0, "b".into()), (1, "a".into()), (2, "b".into())],
            "3 free slots for 5 points"
        );
        assert!(
            l.assign(&BTreeMap::new(), 2).is_empty(),
            "no trainer, no assignment"
        );
    }

    #[test]
    fn a_vanished_trainer_keeps_its_points_through_the_grace_period_then_loses_them() {
        let t0 = Instant::now();
        let mut l = Ledger::new(3, 2, Duration::from_secs(10));
        l.submitted(0, "a", "j1");
        l.submitted(1, "b", "j1");
        l.submitted(2, "a", "j2");
        assert!(l.follow_liveliness(&alive(&["b"]), t0).is_empty());
        assert!(l
            .follow_liveliness(&alive(&["b"]), t0 + Duration::from_secs(9))
            .is_empty());
        let moved = l.follow_liveliness(&alive(&["b"]), t0 + Duration::from_secs(10));
        assert_eq!(moved, vec![0, 2]);
        assert_eq!(*l.state(0), PointState::Waiting);
        assert_eq!(l.on_trainer("b"), vec![(1, "j1".to_string())]);
        // The moved points go to b; a's orphans are cancelled when it returns.
        assert!(l.orphans_to_cancel(&alive(&["b"])).is_empty());
        let back = alive(&["a", "b"]);
        assert_eq!(
            l.orphans_to_cancel(&back),
            vec![("a".into(), "j1".into(), 0), ("a".into(), "j2".into(), 2)]
        );
        l.orphans_cancelled("a", "j1");
        l.orphans_cancelled("a", "j2");
        assert!(l.orphans_to_cancel(&back).is_empty());
        // Moving a point off a vanished trainer is not a failed attempt.
        l.submitted(0, "b", "j7");
        l.failed(0, "boom");
        assert_eq!(
            *l.state(0),
            PointState::Waiting,
            "first real failure is retried"
        );
    }

    #[test]
    fn a_trainer_back_within_the_grace_period_keeps_its_points() {
        let t0 = Instant::now();
        let mut l = Ledger::new(1, 2, Duration::from_secs(10));
        l.submitted(0, "a", "j1");
        l.follow_liveliness(&alive(&[]), t0);
        l.follow_liveliness(&alive(&["a"]), t0 + Duration::from_secs(5));
        assert!(
            l.follow_liveliness(&alive(&[]), t0 + Duration::from_secs(12))
                .is_empty(),
            "the grace period restarts after the trainer came back"
        );
        assert!(matches!(l.state(0), PointState::Submitted { .. }));
    }

    #[test]
    fn failures_retry_then_stop() {
        let mut l = Ledger::new(1, 2, Duration::from_secs(1));
        l.submitted(0, "a", "j1");
        l.failed(0, "nan");
        assert_eq!(*l.state(0), PointState::Waiting);
        l.submitted(0, "a", "j2");
        l.failed(0, "nan again");
        assert_eq!(
            *l.state(0),
            PointState::Failed {
                error: "nan again".into(),
                attempts: 2
            }
        );
        assert!(l.finished());
        assert_eq!(l.counts(), (0, 0, 0, 1));
    }
}
