//! Property tests of the JSON messages: arbitrary and mutated bytes given to the services' JSON
//! parser (`services::parse_json`) for every request type give a value or a typed
//! `bad_request`, never a panic; valid requests round-trip; error replies always parse back.

use bridge::messages::{InfoReply, ResetRequest};
use bridge::services::mpc::{AttachRequest, ConfigureRequest};
use bridge::services::parse_json;
use bridge::services::recorder::RecordRequest;
use bridge::services::trainer::JobSpec;
use bridge::{ErrorCode, ErrorReply};
use proptest::prelude::*;

/// Parses `b` as every request type; each result must be a value or a `bad_request`.
fn parse_all(b: &[u8]) {
    fn typed<T>(r: Result<T, ErrorReply>) {
        if let Err(e) = r {
            assert_eq!(e.code, ErrorCode::BadRequest, "{}", e.message);
            assert!(e.message.contains("invalid JSON"), "{}", e.message);
        }
    }
    typed(parse_json::<ResetRequest>("reset", b));
    typed(parse_json::<JobSpec>("job", b));
    typed(parse_json::<ConfigureRequest>("configure", b));
    typed(parse_json::<AttachRequest>("attach", b));
    typed(parse_json::<RecordRequest>("record", b));
    typed(parse_json::<InfoReply>("info", b));
    // Any bytes as an error reply: always an ErrorReply (`internal` when unparseable).
    let _ = ErrorReply::from_json(b);
}

/// Valid request bodies of every kind, as JSON text.
fn valid_json() -> impl Strategy<Value = String> {
    let f = prop::num::f64::NORMAL | prop::num::f64::ZERO;
    prop_oneof![
        (
            any::<Option<u64>>(),
            prop::option::of(prop::collection::vec(f, 0..6))
        )
            .prop_map(|(seed, x0)| serde_json::to_string(&ResetRequest {
                seed,
                x0,
                perturbation: None
            })
            .unwrap()),
        ("[a-z0-9_-]{1,12}", "[ -~]{0,30}", "[a-z0-9_-]{1,12}").prop_map(|(m, p, r)| {
            serde_json::json!({"model": m, "train": {"path": p}, "val": {"recording": r},
                               "config": {"iterations": 10}})
            .to_string()
        }),
        ("[a-z0-9_-]{1,12}", any::<bool>()).prop_map(|(s, d)| {
            serde_json::json!({"sim": s, "model": "m", "reference": [0.0, 1.5], "detach": d})
                .to_string()
        }),
        ("start|stop", "[a-z0-9_-]{1,12}").prop_map(|(a, s)| {
            serde_json::json!({"action": a, "sim": s, "name": "rec", "window_steps": 15})
                .to_string()
        }),
        "[a-z0-9_-]{1,12}".prop_map(|m| serde_json::json!({"model": m}).to_string()),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1500, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_bytes_give_a_value_or_bad_request(b in prop::collection::vec(any::<u8>(), 0..300)) {
        parse_all(&b);
    }

    #[test]
    fn arbitrary_json_values_give_a_value_or_bad_request(text in "[\\[\\]{}\":,0-9a-z.eE+-]{0,120}") {
        parse_all(text.as_bytes());
    }

    #[test]
    fn mutated_and_truncated_requests_give_a_value_or_bad_request(
        text in valid_json(),
        cut in any::<prop::sample::Index>(),
        flips in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..4),
    ) {
        let b = text.as_bytes();
        parse_all(b);
        parse_all(&b[..cut.index(b.len())]);
        let mut m = b.to_vec();
        for (i, v) in flips {
            let i = i.index(m.len());
            m[i] ^= v.max(1);
        }
        parse_all(&m);
    }

    #[test]
    fn reset_requests_round_trip(seed in any::<Option<u64>>(),
                                 x0 in prop::option::of(prop::collection::vec(-1e300f64..1e300, 0..6))) {
        let r = ResetRequest { seed, x0, perturbation: None };
        let back: ResetRequest = parse_json("reset", serde_json::to_string(&r).unwrap().as_bytes()).unwrap();
        prop_assert_eq!(back, r);
    }

    #[test]
    fn error_replies_round_trip(message in "\\PC{0,60}", which in 0usize..4) {
        let code = [ErrorCode::BadRequest, ErrorCode::TooLarge, ErrorCode::Internal,
                    ErrorCode::VersionMismatch][which];
        let e = ErrorReply::new(code, message);
        prop_assert_eq!(ErrorReply::from_json(&e.to_json()), e);
    }
}

#[test]
fn unknown_fields_and_wrong_types_are_bad_requests() {
    let bad = |r: Result<(), ErrorReply>| assert_eq!(r.unwrap_err().code, ErrorCode::BadRequest);
    bad(parse_json::<ResetRequest>("reset", br#"{"seed": 1, "extra": 2}"#).map(drop));
    bad(parse_json::<ResetRequest>("reset", br#"{"seed": "one"}"#).map(drop));
    bad(parse_json::<JobSpec>(
        "job",
        br#"{"model": "m", "train": {"path": 3}, "val": {"path": "v"}}"#,
    )
    .map(drop));
    bad(parse_json::<RecordRequest>("record", br#"{"action": "start"}"#).map(drop));
    bad(parse_json::<ConfigureRequest>(
        "configure",
        br#"{"model": "m", "mpc": {"horizon": "long"}}"#,
    )
    .map(drop));
}
