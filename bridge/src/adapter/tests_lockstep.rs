//! Tests of the adapter's lockstep state machine ([`super::lockstep::Lockstep`]) without Zenoh:
//! request bytes in, reply bytes or typed errors out, the per-k reply cache, and the
//! [`Counter`] test simulator shared with the free-run tests.

use crate::adapter::backend::{SimBackend, SimError};
use crate::adapter::lockstep::*;
use crate::codec::{StepReply, StepRequest, StepStatus};
use crate::error::{Error, ErrorCode, ErrorReply};
use crate::keyexpr::SimLeaf;
use crate::messages::{InfoReply, ResetRequest, SimInfo};
use crate::services::Reply;

/// `x_{k+1} = x_k + u_k` (two states, one input in ±2) that counts its steps, fails
/// (returns a non-finite state) when `u` is exactly 1.5 and reports `terminated` when it is
/// exactly -1.25.
#[derive(Default)]
pub(crate) struct Counter {
    pub(crate) x: Vec<f64>,
    pub(crate) steps: usize,
    pub(crate) applied: Vec<f64>,
}

impl SimBackend for Counter {
    fn info(&self) -> SimInfo {
        SimInfo {
            env: "counter".into(),
            kind: "test".into(),
            version: "0".into(),
            dt: 0.5,
            state_names: vec!["a".into(), "b".into()],
            input_names: vec!["u".into()],
            u_min: vec![-2.0],
            u_max: vec![2.0],
            angle_indices: vec![],
            extra: Default::default(),
        }
    }
    fn reset(&mut self, req: &ResetRequest) -> std::result::Result<Vec<f64>, SimError> {
        if req.seed == Some(99) {
            return Err(SimError::Unsupported("no seed 99".into()));
        }
        self.x = req.x0.clone().unwrap_or(vec![0.0, 10.0]);
        Ok(self.x.clone())
    }
    fn step(&mut self, u: &[f64]) -> std::result::Result<Vec<f64>, SimError> {
        self.steps += 1;
        self.applied.push(u[0]);
        if u[0] == 1.5 {
            return Ok(vec![f64::NAN, 0.0]);
        }
        self.x = vec![self.x[0] + u[0], self.x[1]];
        Ok(self.x.clone())
    }
    fn step_reporting(
        &mut self,
        u: &[f64],
    ) -> std::result::Result<(Vec<f64>, StepStatus), SimError> {
        let ended = StepStatus::new(u[0] == -1.25, false, false);
        Ok((self.step(u)?, ended))
    }
}

fn step(s: &mut Lockstep<'_>, k: u64, u: &[f64]) -> Reply {
    s.answer(SimLeaf::Step, &StepRequest { k, u: u.to_vec() }.encode())
}

fn code(r: Reply) -> ErrorCode {
    r.expect_err("an error reply").code
}

#[test]
fn info_reports_mode_k_and_counters() {
    let mut b = Counter::default();
    let mut s = Lockstep::new(&mut b, "c1", 4).unwrap();
    let i: InfoReply = serde_json::from_slice(&s.answer(SimLeaf::Info, b"").unwrap()).unwrap();
    assert_eq!((i.id.as_str(), i.mode.as_str(), i.k), ("c1", "lockstep", 0));
    assert_eq!(i.sim.nx(), 2);
    s.answer(SimLeaf::Reset, b"").unwrap();
    step(&mut s, 0, &[1.0]).unwrap();
    s.set_free_run(true);
    let i: InfoReply = serde_json::from_slice(&s.answer(SimLeaf::Info, b"").unwrap()).unwrap();
    assert_eq!((i.mode.as_str(), i.k, i.stats.steps), ("free-run", 1, 1));
    // Free-running: lockstep requests are busy, and counted as errors.
    assert_eq!(code(s.answer(SimLeaf::Reset, b"")), ErrorCode::Busy);
    assert_eq!(code(step(&mut s, 1, &[0.0])), ErrorCode::Busy);
    assert_eq!(s.stats().errors, 2);
}

#[test]
fn steps_follow_k_and_a_retry_returns_the_cached_reply_without_stepping_twice() {
    let mut b = Counter::default();
    let mut s = Lockstep::new(&mut b, "c", 4).unwrap();
    assert_eq!(
        code(step(&mut s, 0, &[1.0])),
        ErrorCode::OutOfOrder,
        "before reset"
    );
    let r = StepReply::decode(&s.answer(SimLeaf::Reset, br#"{"x0": [1, 2]}"#).unwrap()).unwrap();
    assert_eq!((r.k, r.x), (0, vec![1.0, 2.0]));
    let first = step(&mut s, 0, &[0.25]).unwrap();
    let r = StepReply::decode(&first).unwrap();
    assert_eq!((r.k, r.t, r.x), (1, 0.5, vec![1.25, 2.0]));
    // The same k and the bit-identical u: the cached bytes, no second step.
    assert_eq!(step(&mut s, 0, &[0.25]).unwrap(), first);
    assert_eq!(s.stats().cache_hits, 1);
    // The same k with another u: conflict; a k that is neither next nor cached: out_of_order.
    assert_eq!(code(step(&mut s, 0, &[0.5])), ErrorCode::Conflict);
    let e = step(&mut s, 5, &[0.5]).unwrap_err();
    assert_eq!(e.code, ErrorCode::OutOfOrder);
    assert!(e.message.contains("k = 1"), "{}", e.message);
    step(&mut s, 1, &[1.0]).unwrap();
    assert_eq!((s.k(), s.stats().steps, s.stats().errors), (2, 2, 3));
    drop(s);
    assert_eq!(b.steps, 2, "the backend stepped once per k");
}

#[test]
fn the_backends_step_status_travels_in_the_reply_and_its_cached_retry() {
    let mut b = Counter::default();
    let mut s = Lockstep::new(&mut b, "c", 4).unwrap();
    let reset = s.answer(SimLeaf::Reset, b"").unwrap();
    assert_eq!(
        (reset[3], StepReply::decode(&reset).unwrap().status),
        (0x02, StepStatus::EMPTY)
    );
    let ended = step(&mut s, 0, &[-1.25]).unwrap();
    let r = StepReply::decode(&ended).unwrap();
    assert_eq!((ended[3], r.k, r.status), (0x09, 1, StepStatus::TERMINATED));
    assert_eq!(
        step(&mut s, 0, &[-1.25]).unwrap(),
        ended,
        "the retry: the same status"
    );
    let r = StepReply::decode(&step(&mut s, 1, &[1.0]).unwrap()).unwrap();
    assert_eq!((r.x, r.status), (vec![-0.25, 10.0], StepStatus::EMPTY));
    drop(s);
    assert_eq!(b.steps, 2);
}

#[test]
fn the_cache_keeps_the_last_replies_only_and_reset_clears_it() {
    let mut b = Counter::default();
    let mut s = Lockstep::new(&mut b, "c", 2).unwrap();
    s.answer(SimLeaf::Reset, b"").unwrap();
    for k in 0..3 {
        step(&mut s, k, &[1.0]).unwrap();
    }
    assert!(step(&mut s, 2, &[1.0]).is_ok(), "cached");
    assert!(step(&mut s, 1, &[1.0]).is_ok(), "cached");
    assert_eq!(
        code(step(&mut s, 0, &[1.0])),
        ErrorCode::OutOfOrder,
        "evicted"
    );
    s.answer(SimLeaf::Reset, b"{}").unwrap();
    assert_eq!(s.k(), 0);
    // After a reset, k = 0 is stepped afresh (not answered from the old cache).
    let r = StepReply::decode(&step(&mut s, 0, &[2.0]).unwrap()).unwrap();
    assert_eq!(r.x, vec![2.0, 10.0]);
    assert_eq!(s.stats().cache_hits, 2);
    assert_eq!(s.stats().resets, 2);
}

#[test]
fn bad_requests_get_typed_errors_and_change_nothing() {
    let mut b = Counter::default();
    let mut s = Lockstep::new(&mut b, "c", 4).unwrap();
    s.answer(SimLeaf::Reset, b"").unwrap();
    assert_eq!(code(step(&mut s, 0, &[1.0, 2.0])), ErrorCode::Dimension);
    assert_eq!(code(step(&mut s, 0, &[])), ErrorCode::Dimension);
    assert_eq!(code(step(&mut s, 0, &[f64::NAN])), ErrorCode::BadRequest);
    assert_eq!(
        code(step(&mut s, 0, &[f64::INFINITY])),
        ErrorCode::BadRequest
    );
    assert_eq!(
        code(s.answer(SimLeaf::Step, b"KB\x01")),
        ErrorCode::BadRequest
    );
    let mut long = StepRequest { k: 0, u: vec![1.0] }.encode();
    long.push(0);
    assert_eq!(code(s.answer(SimLeaf::Step, &long)), ErrorCode::BadRequest);
    assert_eq!(
        code(s.answer(SimLeaf::Reset, b"{nope")),
        ErrorCode::BadRequest
    );
    assert_eq!(
        code(s.answer(SimLeaf::Reset, br#"{"x0": [1]}"#)),
        ErrorCode::Dimension
    );
    assert_eq!(
        code(s.answer(SimLeaf::Reset, br#"{"x0": [1, 2], "y": 1}"#)),
        ErrorCode::BadRequest
    );
    assert_eq!(
        code(s.answer(SimLeaf::Reset, br#"{"seed": 99}"#)),
        ErrorCode::Unsupported
    );
    assert_eq!(code(s.answer(SimLeaf::State, b"")), ErrorCode::Unsupported);
    assert_eq!((s.k(), s.stats().steps, s.stats().errors), (0, 0, 11));
    // A backend returning a non-finite state: sim_failure, k does not advance.
    assert_eq!(code(step(&mut s, 0, &[1.5])), ErrorCode::SimFailure);
    assert_eq!(s.k(), 0);
    assert_eq!(
        code(s.refuse(ErrorReply::new(ErrorCode::TooLarge, "big"))),
        ErrorCode::TooLarge
    );
    assert_eq!(s.stats().errors, 13);
    drop(s);
    assert_eq!(b.steps, 1, "only the failing step reached the backend");
}

#[test]
fn collect_answers_chunks_and_leaves_no_lockstep_state() {
    let mut b = Counter::default();
    let mut s = Lockstep::new(&mut b, "c", 4).unwrap();
    s.answer(SimLeaf::Reset, b"").unwrap();
    step(&mut s, 0, &[1.0]).unwrap();
    let req = br#"{"seed": 3, "block": 1, "block_windows": 4, "windows": 3, "steps": 2}"#;
    let chunks = s.answer_collect(req).unwrap();
    let c = crate::codec::CollectChunk::decode(&chunks[0]).unwrap();
    assert_eq!(
        (chunks.len(), c.first, c.windows, c.nx, c.nu),
        (1, 4, 3, 2, 1)
    );
    // x_{k+1} = x_k + u_k from the Counter's reset state [0, 10].
    for w in 0..3 {
        let (x, u) = (&c.x[w * 6..w * 6 + 6], &c.u[w * 2..w * 2 + 2]);
        assert_eq!(&x[..2], &[0.0, 10.0]);
        assert_eq!(x[4], u[0] + u[1]);
        assert!(u.iter().all(|v| v.abs() <= 2.0));
    }
    assert_eq!(
        s.answer_collect(req).unwrap(),
        chunks,
        "same request, same bytes"
    );
    assert_eq!(s.stats().collected_windows, 6);
    // The backend was reset for every window: stepping needs a reset first.
    assert_eq!(
        (s.k(), code(step(&mut s, 0, &[1.0]))),
        (0, ErrorCode::OutOfOrder)
    );
    assert_eq!(
        s.answer_collect(b"{").unwrap_err().code,
        ErrorCode::BadRequest
    );
    assert_eq!(code(s.answer(SimLeaf::Collect, req)), ErrorCode::Internal);
    s.set_free_run(true);
    assert_eq!(s.answer_collect(req).unwrap_err().code, ErrorCode::Busy);
    assert_eq!(s.stats().errors, 4);
}

#[test]
fn inconsistent_info_is_refused() {
    struct NoBounds(Counter);
    impl SimBackend for NoBounds {
        fn info(&self) -> SimInfo {
            SimInfo {
                u_min: vec![],
                ..self.0.info()
            }
        }
        fn reset(&mut self, r: &ResetRequest) -> std::result::Result<Vec<f64>, SimError> {
            self.0.reset(r)
        }
        fn step(&mut self, u: &[f64]) -> std::result::Result<Vec<f64>, SimError> {
            self.0.step(u)
        }
    }
    let mut b = NoBounds(Counter::default());
    assert!(matches!(
        Lockstep::new(&mut b, "c", 4),
        Err(Error::Config(_))
    ));
}
