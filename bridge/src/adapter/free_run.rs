//! The adapter's free-run state machine apart from Zenoh: ticks at absolute deadlines
//! `t0 + n/rate`, the latest command (clipped to the simulator's input bounds, and counted when
//! it had to be), zero-order hold and the timing counters. [`super::serve`] feeds it commands and
//! publishes the states its ticks return.

use std::time::{Duration, Instant};

use crate::codec::{CommandMsg, StateMsg};
use crate::error::{Error, ErrorReply, Result};
use crate::messages::ResetRequest;

use super::lockstep::Lockstep;

/// Free-run settings.
#[derive(Clone, Debug, PartialEq)]
pub struct FreeRunOptions {
    /// Steps per wall-clock second; `None` = real time (`1/dt`).
    pub rate_hz: Option<f64>,
    /// Stop after this many steps (then [`super::serve`] returns); `None` = until stopped.
    pub steps: Option<u64>,
    /// How to reset before the run starts.
    pub reset: ResetRequest,
}

/// Where a free run is: its clock, the publication sequence, the latest command.
pub struct FreeRun {
    period: Duration,
    steps: Option<u64>,
    t0: Instant,
    tick: u64,
    seq: u64,
    latest: Option<CommandMsg>,
    fresh: bool,
    seen_command: bool,
}

impl FreeRun {
    /// Resets `sim` as `opts` says and starts the clock now; returns the run and the first
    /// state message (`seq 0, k 0`) to publish.
    pub fn start(sim: &mut Lockstep<'_>, opts: &FreeRunOptions) -> Result<(Self, StateMsg)> {
        let rate = opts.rate_hz.unwrap_or(1.0 / sim.info().dt);
        if !(rate > 0.0 && rate.is_finite()) {
            return Err(Error::Config(format!("free-run rate {rate} Hz")));
        }
        sim.set_free_run(true);
        let x = sim
            .reset(&opts.reset)
            .map_err(|e| Error::Config(format!("free-run reset failed: {}", e.message)))?;
        let mut run = FreeRun {
            period: Duration::from_secs_f64(1.0 / rate),
            steps: opts.steps,
            t0: Instant::now(),
            tick: 0,
            seq: 0,
            latest: None,
            fresh: false,
            seen_command: false,
        };
        let first = run.message(0, 0.0, x, Vec::new());
        Ok((run, first))
    }

    /// When the next tick is due.
    pub fn deadline(&self) -> Instant {
        self.t0 + self.period.mul_f64((self.tick + 1) as f64)
    }

    /// Takes a received `Command` payload: a decodable one with `nu` finite values becomes the
    /// latest command, each value clipped into `[u_min, u_max]` (a command that needed it counts
    /// in `clipped_commands`); anything else counts in `errors`.
    pub fn command(&mut self, sim: &mut Lockstep<'_>, bytes: &[u8]) {
        let mut c = match CommandMsg::decode(bytes) {
            Ok(c) if sim.check_input(&c.u).is_ok() => c,
            _ => {
                sim.stats_mut().errors += 1;
                return;
            }
        };
        let info = sim.info();
        let mut clipped = false;
        for (v, (lo, hi)) in c.u.iter_mut().zip(info.u_min.iter().zip(&info.u_max)) {
            let inside = if *v < *lo {
                *lo
            } else if *v > *hi {
                *hi
            } else {
                *v
            };
            clipped |= inside != *v;
            *v = inside;
        }
        if clipped {
            sim.stats_mut().clipped_commands += 1;
        }
        self.latest = Some(c);
        self.fresh = true;
        self.seen_command = true;
    }

    /// If the next tick is due at `now`: counts its timing, steps `sim` with the latest
    /// command (zeros before the first) and returns the state message to publish. A backend
    /// failure is returned as its error reply.
    pub fn tick(
        &mut self,
        sim: &mut Lockstep<'_>,
        now: Instant,
    ) -> std::result::Result<Option<StateMsg>, ErrorReply> {
        let deadline = self.deadline();
        if now < deadline {
            return Ok(None);
        }
        let late = now - deadline;
        let k = sim.k();
        let stats = sim.stats_mut();
        stats.max_lateness_us = stats.max_lateness_us.max(late.as_micros() as u64);
        if late > self.period {
            stats.overruns += 1;
        }
        if self.seen_command {
            match (&self.latest, self.fresh) {
                (Some(c), true) if c.k >= k => {}
                (Some(_), true) => stats.late_commands += 1,
                _ => stats.missing_commands += 1,
            }
        }
        self.fresh = false;
        let u = match &self.latest {
            Some(c) => c.u.clone(),
            None => vec![0.0; sim.info().nu()],
        };
        let x = sim.step(&u)?;
        self.tick += 1;
        let t = sim.k() as f64 * sim.info().dt;
        let wall = self.t0.elapsed().as_secs_f64();
        if wall > 0.0 {
            sim.stats_mut().real_time_factor = t / wall;
        }
        Ok(Some(self.message(sim.k(), t, x, u)))
    }

    /// Whether the step limit has been reached.
    pub fn finished(&self) -> bool {
        self.steps.is_some_and(|n| self.tick >= n)
    }

    fn message(&mut self, k: u64, t: f64, x: Vec<f64>, u: Vec<f64>) -> StateMsg {
        let m = StateMsg {
            seq: self.seq,
            k,
            t,
            x,
            u,
        };
        self.seq += 1;
        m
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::adapter::tests_lockstep::Counter;

    fn opts(steps: u64) -> FreeRunOptions {
        FreeRunOptions {
            rate_hz: Some(1000.0),
            steps: Some(steps),
            reset: ResetRequest {
                seed: None,
                x0: Some(vec![0.0, 1.0]),
                perturbation: None,
            },
        }
    }

    fn cmd(k: u64, u: f64) -> Vec<u8> {
        CommandMsg {
            seq: k,
            k,
            u: vec![u],
        }
        .encode()
    }

    /// Ticks once, as if its deadline had just passed.
    fn tick(run: &mut FreeRun, sim: &mut Lockstep<'_>) -> StateMsg {
        let at = run.deadline();
        run.tick(sim, at).unwrap().expect("due")
    }

    #[test]
    fn commands_are_clipped_to_the_bounds_and_counted() {
        let mut b = Counter::default();
        let mut sim = Lockstep::new(&mut b, "fr", 4).unwrap();
        let (mut run, first) = FreeRun::start(&mut sim, &opts(10)).unwrap();
        assert_eq!(
            (first.seq, first.k, first.x.clone()),
            (0, 0, vec![0.0, 1.0])
        );
        // Before any command: zeros, held.
        assert_eq!(tick(&mut run, &mut sim).u, vec![0.0]);
        // In bounds: applied as sent, not counted.
        run.command(&mut sim, &cmd(1, 1.25));
        assert_eq!(tick(&mut run, &mut sim).u, vec![1.25]);
        // Out of bounds either way (±2): the bound is applied, and counted.
        run.command(&mut sim, &cmd(2, 61.0));
        let s = tick(&mut run, &mut sim);
        assert_eq!((s.u.clone(), s.x.clone()), (vec![2.0], vec![3.25, 1.0]));
        run.command(&mut sim, &cmd(3, -1e9));
        assert_eq!(tick(&mut run, &mut sim).u, vec![-2.0]);
        assert_eq!(sim.stats().clipped_commands, 2);
        // Not a command, wrong length, non-finite: ignored (the last one stays), counted as errors.
        run.command(&mut sim, b"junk");
        run.command(
            &mut sim,
            &CommandMsg {
                seq: 9,
                k: 4,
                u: vec![1.0, 1.0],
            }
            .encode(),
        );
        run.command(&mut sim, &cmd(4, f64::NAN));
        let s = tick(&mut run, &mut sim);
        assert_eq!(s.u, vec![-2.0]);
        assert_eq!((sim.stats().errors, sim.stats().clipped_commands), (3, 2));
        drop(sim);
        assert_eq!(
            b.applied,
            vec![0.0, 1.25, 2.0, -2.0, -2.0],
            "what the backend got"
        );
    }

    #[test]
    fn ticks_wait_for_their_deadline_count_timing_and_stop_at_the_limit() {
        let mut b = Counter::default();
        let mut sim = Lockstep::new(&mut b, "fr", 4).unwrap();
        let (mut run, _) = FreeRun::start(&mut sim, &opts(3)).unwrap();
        let d = run.deadline();
        assert!(run
            .tick(&mut sim, d - Duration::from_micros(1))
            .unwrap()
            .is_none());
        // A tick 5 ms late (5 periods at 1 kHz): lateness and an overrun.
        let s = run
            .tick(&mut sim, d + Duration::from_millis(5))
            .unwrap()
            .unwrap();
        assert_eq!((s.seq, s.k), (1, 1));
        assert!((s.t - 0.5).abs() < 1e-12);
        assert_eq!(sim.stats().overruns, 1);
        assert!(sim.stats().max_lateness_us >= 5000);
        // A command answering the current state is on time; none at the next tick is missing;
        // one answering an older state is late.
        run.command(&mut sim, &cmd(1, 0.5));
        tick(&mut run, &mut sim);
        assert!(!run.finished());
        tick(&mut run, &mut sim);
        assert!(run.finished());
        assert_eq!(
            (sim.stats().missing_commands, sim.stats().late_commands),
            (1, 0)
        );
        run.command(&mut sim, &cmd(0, 0.5));
        let s = tick(&mut run, &mut sim);
        assert_eq!((s.seq, s.k), (4, 4));
        assert_eq!(sim.stats().late_commands, 1);
        assert_eq!(sim.stats().steps, 4);
    }

    #[test]
    fn a_bad_rate_or_a_failing_reset_is_a_configuration_error() {
        let mut b = Counter::default();
        let mut sim = Lockstep::new(&mut b, "fr", 4).unwrap();
        let bad_rate = FreeRunOptions {
            rate_hz: Some(0.0),
            ..opts(1)
        };
        assert!(matches!(
            FreeRun::start(&mut sim, &bad_rate),
            Err(Error::Config(_))
        ));
        let bad_reset = FreeRunOptions {
            reset: ResetRequest {
                seed: None,
                x0: Some(vec![1.0]),
                perturbation: None,
            },
            ..opts(1)
        };
        assert!(matches!(
            FreeRun::start(&mut sim, &bad_reset),
            Err(Error::Config(_))
        ));
    }
}
