//! Golden vectors of every binary message, written by hand from PROTOCOL.md, and the decoder's
//! answers to malformed input.

use super::*;
use crate::error::{Error, ErrorCode, Result};

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

// Golden vectors: written by hand from the layout in PROTOCOL.md (1.5 = 0x3FF8000000000000,
// -2.0 = 0xC000000000000000, 0.02 = 0x3F947AE147AE147B), not produced by the encoder.
#[test]
fn golden_step_request() {
    let m = StepRequest { k: 3, u: vec![1.5] };
    assert_eq!(
        hex(&m.encode()),
        "4b420101\
         0300000000000000\
         01000000\
         000000000000f83f"
    );
    assert_eq!(StepRequest::decode(&m.encode()).unwrap(), m);
}

#[test]
fn golden_step_reply() {
    let m = StepReply {
        k: 4,
        t: 0.02,
        x: vec![1.5, -2.0],
        status: StepStatus::EMPTY,
    };
    assert_eq!(
        hex(&m.encode()),
        "4b420102\
         0400000000000000\
         7b14ae47e17a943f\
         02000000\
         000000000000f83f\
         00000000000000c0"
    );
    assert_eq!(StepReply::decode(&m.encode()).unwrap(), m);
}

#[test]
fn golden_step_reply_with_status() {
    // terminated | clipped = 0b101: type 0x09, the 0x02 body, then the status byte.
    let m = StepReply {
        k: 4,
        t: 0.02,
        x: vec![1.5, -2.0],
        status: StepStatus::TERMINATED | StepStatus::CLIPPED,
    };
    let b = m.encode();
    assert_eq!(
        hex(&b),
        "4b420109\
         0400000000000000\
         7b14ae47e17a943f\
         02000000\
         000000000000f83f\
         00000000000000c0\
         05"
    );
    let r = StepReply::decode(&b).unwrap();
    assert_eq!(r, m);
    assert!(r.status.terminated() && !r.status.truncated() && r.status.clipped());
    assert_eq!(r.status.names(), ["terminated", "clipped"]);
    // Every flag alone and together round-trips, each through its own byte.
    for bits in 1..=StepStatus::KNOWN_BITS {
        let status = StepStatus::from_bits(bits).unwrap();
        let m = StepReply {
            status,
            ..m.clone()
        };
        let b = m.encode();
        assert_eq!((b[3], b[b.len() - 1]), (0x09, bits));
        assert_eq!(StepReply::decode(&b).unwrap(), m);
    }
    assert_eq!(
        StepStatus::new(true, true, true).bits(),
        StepStatus::KNOWN_BITS
    );
    assert_eq!(StepStatus::new(false, true, false), StepStatus::TRUNCATED);
}

#[test]
fn step_reply_status_is_refused_typed_when_malformed() {
    let code = |b: &[u8]| match StepReply::decode(b) {
        Err(Error::Protocol { code, .. }) => code,
        other => panic!("expected a protocol error, got {other:?}"),
    };
    let with = StepReply {
        k: 9,
        t: 0.5,
        x: vec![1.5],
        status: StepStatus::TRUNCATED,
    }
    .encode();
    let plain = StepReply {
        status: StepStatus::EMPTY,
        ..StepReply::decode(&with).unwrap()
    }
    .encode();
    // No prefix of a 0x09 reply decodes, in particular not the one without its status byte.
    for n in 0..with.len() {
        assert_eq!(code(&with[..n]), ErrorCode::BadRequest, "{n}-byte prefix");
    }
    // A 0x09 reply with an empty status (one encoding per reply) or unknown bits: bad_request.
    for s in [0u8, 0x08, 0x80, 0xff] {
        let mut b = with.clone();
        *b.last_mut().unwrap() = s;
        assert_eq!(code(&b), ErrorCode::BadRequest, "status byte 0x{s:02x}");
    }
    assert_eq!(StepStatus::from_bits(0x08), None);
    // A 0x02 reply followed by a status byte is trailing bytes, not a status.
    let mut b = plain.clone();
    b.push(1);
    assert_eq!(code(&b), ErrorCode::BadRequest);
    let mut b = with.clone();
    b.push(0);
    assert_eq!(code(&b), ErrorCode::BadRequest);
    // Another version of either layout is version_mismatch, named.
    for m in [&plain, &with] {
        let mut b = m.clone();
        b[2] = 2;
        match StepReply::decode(&b) {
            Err(Error::Protocol { code, message }) => {
                assert_eq!(code, ErrorCode::VersionMismatch);
                assert!(message.contains("protocol version 2"), "{message}");
            }
            other => panic!("expected version_mismatch, got {other:?}"),
        }
    }
    // Fuzz-style: every single-byte change of the 0x09 reply decodes or is refused typed
    // (never a panic), and one that decodes re-encodes to the same bytes.
    for i in 0..with.len() {
        for v in [0x01u8, 0x02, 0x08, 0x80, 0xff] {
            let mut b = with.clone();
            b[i] ^= v;
            match StepReply::decode(&b) {
                Ok(r) => assert_eq!(r.encode(), b, "byte {i} ^ 0x{v:02x}"),
                Err(Error::Protocol { code, .. }) => assert!(
                    matches!(
                        code,
                        ErrorCode::BadRequest | ErrorCode::VersionMismatch | ErrorCode::TooLarge
                    ),
                    "byte {i} ^ 0x{v:02x}: {code:?}"
                ),
                Err(other) => panic!("byte {i} ^ 0x{v:02x}: untyped {other:?}"),
            }
        }
    }
}

#[test]
fn golden_state_and_command() {
    let s = StateMsg {
        seq: 1,
        k: 2,
        t: 0.02,
        x: vec![-2.0],
        u: vec![1.5],
    };
    assert_eq!(
        hex(&s.encode()),
        "4b420103\
         0100000000000000\
         0200000000000000\
         7b14ae47e17a943f\
         01000000\
         00000000000000c0\
         01000000\
         000000000000f83f"
    );
    assert_eq!(StateMsg::decode(&s.encode()).unwrap(), s);
    let c = CommandMsg {
        seq: 7,
        k: 2,
        u: vec![1.5, -2.0],
    };
    assert_eq!(
        hex(&c.encode()),
        "4b420104\
         0700000000000000\
         0200000000000000\
         02000000\
         000000000000f83f\
         00000000000000c0"
    );
    assert_eq!(CommandMsg::decode(&c.encode()).unwrap(), c);
}

#[test]
fn golden_solve() {
    let q = SolveRequest {
        model: "ab".into(),
        x: vec![1.5],
        reference: vec![],
        feedforward: vec![],
    };
    assert_eq!(
        hex(&q.encode()),
        "4b420105\
         0200\
         6162\
         01000000\
         000000000000f83f\
         00000000"
    );
    assert_eq!(SolveRequest::decode(&q.encode()).unwrap(), q);
    // With a feed-forward: one more vector after the reference.
    let f = SolveRequest {
        model: "".into(),
        x: vec![],
        reference: vec![1.5],
        feedforward: vec![-2.0],
    };
    assert_eq!(
        hex(&f.encode()),
        "4b420108\
         0000\
         00000000\
         01000000\
         000000000000f83f\
         01000000\
         00000000000000c0"
    );
    assert_eq!(SolveRequest::decode(&f.encode()).unwrap(), f);
    // No prefix of it decodes (in particular not the one that ends before the feed-forward,
    // which would silently be a request without one), nor a 0x08 request with an empty one.
    let b = f.encode();
    for n in 0..b.len() {
        assert!(SolveRequest::decode(&b[..n]).is_err(), "{n}-byte prefix");
    }
    let mut empty = b[..b.len() - 12].to_vec();
    empty.extend_from_slice(&[0, 0, 0, 0]);
    assert!(SolveRequest::decode(&empty).is_err());
    // A 0x05 request with bytes after the reference is refused, not read as a feed-forward.
    let mut trailing = q.encode();
    trailing.extend_from_slice(&b[b.len() - 12..]);
    assert!(SolveRequest::decode(&trailing).is_err());
    let r = SolveReply {
        status: SolveStatus::Suboptimal,
        iterations: 9,
        solve_time_ns: 256,
        u: vec![-2.0],
    };
    assert_eq!(
        hex(&r.encode()),
        "4b420106\
         01\
         09000000\
         0001000000000000\
         01000000\
         00000000000000c0"
    );
    assert_eq!(SolveReply::decode(&r.encode()).unwrap(), r);
}

#[test]
fn golden_collect_chunk() {
    let m = CollectChunk {
        block: 2,
        chunk: 1,
        chunks: 3,
        first: 8,
        windows: 1,
        steps: 1,
        nx: 1,
        nu: 1,
        x: vec![1.5, -2.0],
        u: vec![0.02],
    };
    assert_eq!(
        hex(&m.encode()),
        "4b420107\
         0200000000000000\
         01000000\
         03000000\
         0800000000000000\
         01000000\
         01000000\
         01000000\
         01000000\
         02000000\
         000000000000f83f\
         00000000000000c0\
         01000000\
         7b14ae47e17a943f"
    );
    assert_eq!(CollectChunk::decode(&m.encode()).unwrap(), m);
    // Inconsistent counts and chunk indices are refused, typed.
    for bad in [
        CollectChunk { nx: 2, ..m.clone() },
        CollectChunk {
            u: vec![],
            ..m.clone()
        },
        CollectChunk {
            chunk: 3,
            ..m.clone()
        },
    ] {
        match CollectChunk::decode(&bad.encode()) {
            Err(Error::Protocol { code, .. }) => assert_eq!(code, ErrorCode::BadRequest),
            other => panic!("expected bad_request, got {other:?}"),
        }
    }
}

#[test]
fn malformed_payloads_give_typed_errors() {
    let good = StepRequest {
        k: 1,
        u: vec![0.5, 0.25],
    }
    .encode();
    let code = |r: Result<StepRequest>| match r {
        Err(Error::Protocol { code, .. }) => code,
        other => panic!("expected a protocol error, got {other:?}"),
    };
    assert_eq!(code(StepRequest::decode(&[])), ErrorCode::BadRequest);
    assert_eq!(
        code(StepRequest::decode(b"{\"k\":1}")),
        ErrorCode::BadRequest
    );
    let mut v = good.clone();
    v[2] = 9;
    assert_eq!(code(StepRequest::decode(&v)), ErrorCode::VersionMismatch);
    let mut v = good.clone();
    v[3] = MsgType::State as u8;
    assert_eq!(code(StepRequest::decode(&v)), ErrorCode::BadRequest);
    for cut in 4..good.len() {
        assert_eq!(
            code(StepRequest::decode(&good[..cut])),
            ErrorCode::BadRequest
        );
    }
    let mut v = good.clone();
    v.push(0);
    assert_eq!(code(StepRequest::decode(&v)), ErrorCode::BadRequest);
    let mut v = good[..12].to_vec();
    v.extend_from_slice(&u32::MAX.to_le_bytes());
    assert_eq!(code(StepRequest::decode(&v)), ErrorCode::TooLarge);
    assert!(SolveReply::decode(&[0x4b, 0x42, 1, 6, 7, 0, 0, 0, 0]).is_err());
}
