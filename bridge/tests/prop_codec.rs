//! Property tests of the binary codec (`bridge::codec`): every decoder refuses arbitrary,
//! truncated and mutated bytes with a typed `bad_request`/`version_mismatch`/`too_large` error
//! and never panics, and decode ∘ encode is the identity (bit for bit, NaNs included).

use bridge::codec::{
    CommandMsg, SolveReply, SolveRequest, SolveStatus, StateMsg, StepReply, StepRequest,
    StepStatus, MAGIC, PROTOCOL_VERSION,
};
use bridge::{Error, ErrorCode};
use proptest::prelude::*;

/// Runs every decoder on `b`; each result must be `Ok` or a typed protocol error.
fn decode_all(b: &[u8]) {
    fn typed<T>(what: &str, r: bridge::Result<T>) {
        if let Err(e) = r {
            match e {
                Error::Protocol { code, .. } => assert!(
                    matches!(
                        code,
                        ErrorCode::BadRequest | ErrorCode::VersionMismatch | ErrorCode::TooLarge
                    ),
                    "{what}: unexpected code {code:?}"
                ),
                other => panic!("{what}: untyped error {other:?}"),
            }
        }
    }
    typed("step request", StepRequest::decode(b));
    typed("step reply", StepReply::decode(b));
    typed("state", StateMsg::decode(b));
    typed("command", CommandMsg::decode(b));
    typed("solve request", SolveRequest::decode(b));
    typed("solve reply", SolveReply::decode(b));
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn vec_f64() -> impl Strategy<Value = Vec<f64>> {
    prop::collection::vec(any::<f64>(), 0..24)
}

/// A valid encoding of one of the six messages.
fn encoded() -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        (any::<u64>(), vec_f64()).prop_map(|(k, u)| StepRequest { k, u }.encode()),
        (
            any::<u64>(),
            any::<f64>(),
            vec_f64(),
            0..=StepStatus::KNOWN_BITS
        )
            .prop_map(|(k, t, x, s)| StepReply {
                k,
                t,
                x,
                status: StepStatus::from_bits(s).unwrap_or_default()
            }
            .encode()),
        (
            any::<u64>(),
            any::<u64>(),
            any::<f64>(),
            vec_f64(),
            vec_f64()
        )
            .prop_map(|(seq, k, t, x, u)| StateMsg { seq, k, t, x, u }.encode()),
        (any::<u64>(), any::<u64>(), vec_f64())
            .prop_map(|(seq, k, u)| CommandMsg { seq, k, u }.encode()),
        ("[a-z0-9_-]{0,16}", vec_f64(), vec_f64(), vec_f64()).prop_map(
            |(model, x, reference, feedforward)| SolveRequest {
                model,
                x,
                reference,
                feedforward
            }
            .encode()
        ),
        (0u8..4, any::<u32>(), any::<u64>(), vec_f64()).prop_map(
            |(s, iterations, solve_time_ns, u)| {
                let status = [
                    SolveStatus::Solved,
                    SolveStatus::Suboptimal,
                    SolveStatus::Fallback,
                    SolveStatus::Inaccurate,
                ][s as usize];
                SolveReply {
                    status,
                    iterations,
                    solve_time_ns,
                    u,
                }
                .encode()
            }
        ),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_bytes_never_panic(b in prop::collection::vec(any::<u8>(), 0..512)) {
        decode_all(&b);
    }

    #[test]
    fn arbitrary_bodies_behind_a_valid_header_never_panic(
        t in 0u8..10,
        body in prop::collection::vec(any::<u8>(), 0..256),
    ) {
        let mut b = MAGIC.to_vec();
        b.push(PROTOCOL_VERSION);
        b.push(t);
        b.extend(body);
        decode_all(&b);
    }

    #[test]
    fn truncated_and_mutated_messages_are_refused_or_decoded(
        b in encoded(),
        cut in any::<prop::sample::Index>(),
        flips in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..4),
    ) {
        // Every strict prefix is refused (the decoders check the whole payload).
        let n = cut.index(b.len());
        for d in [StepRequest::decode(&b[..n]).is_err(), StepReply::decode(&b[..n]).is_err(),
                  StateMsg::decode(&b[..n]).is_err(), CommandMsg::decode(&b[..n]).is_err(),
                  SolveRequest::decode(&b[..n]).is_err(), SolveReply::decode(&b[..n]).is_err()] {
            prop_assert!(d, "a {n}-byte prefix of a {}-byte message decoded", b.len());
        }
        decode_all(&b[..n]);
        let mut m = b.clone();
        for (i, v) in flips {
            let i = i.index(m.len());
            m[i] ^= v.max(1);
        }
        decode_all(&m);
        // One byte too many: trailing bytes are refused.
        let mut long = b.clone();
        long.push(0);
        for d in [StepRequest::decode(&long).is_err(), StepReply::decode(&long).is_err(),
                  StateMsg::decode(&long).is_err(), CommandMsg::decode(&long).is_err(),
                  SolveRequest::decode(&long).is_err(), SolveReply::decode(&long).is_err()] {
            prop_assert!(d, "a message with a trailing byte decoded");
        }
    }

    #[test]
    fn step_messages_round_trip(k in any::<u64>(), t in any::<f64>(), u in vec_f64(),
                                s in 0..=StepStatus::KNOWN_BITS) {
        let r = StepRequest::decode(&StepRequest { k, u: u.clone() }.encode()).unwrap();
        prop_assert_eq!((r.k, bits(&r.u)), (k, bits(&u)));
        let status = StepStatus::from_bits(s).unwrap();
        let b = StepReply { k, t, x: u.clone(), status }.encode();
        prop_assert_eq!(b[3], if s == 0 { 0x02 } else { 0x09 });
        let r = StepReply::decode(&b).unwrap();
        prop_assert_eq!((r.k, r.t.to_bits(), bits(&r.x)), (k, t.to_bits(), bits(&u)));
        prop_assert_eq!(r.status, status);
    }

    #[test]
    fn state_and_command_round_trip(seq in any::<u64>(), k in any::<u64>(), t in any::<f64>(),
                                    x in vec_f64(), u in vec_f64()) {
        let m = StateMsg { seq, k, t, x: x.clone(), u: u.clone() };
        let r = StateMsg::decode(&m.encode()).unwrap();
        prop_assert_eq!((r.seq, r.k, r.t.to_bits()), (seq, k, t.to_bits()));
        prop_assert_eq!((bits(&r.x), bits(&r.u)), (bits(&x), bits(&u)));
        let r = CommandMsg::decode(&CommandMsg { seq, k, u: u.clone() }.encode()).unwrap();
        prop_assert_eq!((r.seq, r.k, bits(&r.u)), (seq, k, bits(&u)));
    }

    #[test]
    fn solve_messages_round_trip(model in "\\PC{0,20}", x in vec_f64(), reference in vec_f64(),
                                 feedforward in vec_f64(),
                                 iterations in any::<u32>(), ns in any::<u64>(), s in 0u8..4) {
        let q = SolveRequest { model: model.clone(), x: x.clone(), reference: reference.clone(),
                               feedforward: feedforward.clone() };
        let r = SolveRequest::decode(&q.encode()).unwrap();
        prop_assert_eq!(r.model, model);
        prop_assert_eq!((bits(&r.x), bits(&r.reference)), (bits(&x), bits(&reference)));
        prop_assert_eq!(bits(&r.feedforward), bits(&feedforward));
        let status = [SolveStatus::Solved, SolveStatus::Suboptimal, SolveStatus::Fallback,
                      SolveStatus::Inaccurate][s as usize];
        let m = SolveReply { status, iterations, solve_time_ns: ns, u: x.clone() };
        let r = SolveReply::decode(&m.encode()).unwrap();
        prop_assert_eq!((r.status, r.iterations, r.solve_time_ns, bits(&r.u)),
                        (status, iterations, ns, bits(&x)));
    }
}

#[test]
fn a_huge_declared_length_is_refused_without_allocating() {
    // k, then n = u32::MAX: refused as too large (or truncated), never a 32 GiB allocation.
    let mut b = StepRequest { k: 7, u: vec![] }.encode();
    let n = b.len();
    b[n - 4..].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(StepRequest::decode(&b).is_err());
    decode_all(&b);
}
