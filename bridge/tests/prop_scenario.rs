//! Property tests of scenario parsing (`Scenario::parse`): arbitrary, truncated and mutated
//! TOML, including the project's own scenario files, gives a validated scenario or a typed
//! configuration error, never a panic; a parsed scenario's names are valid key chunks.

use bridge::keyexpr::validate_chunk;
use bridge::scenario::Scenario;
use bridge::Error;
use proptest::prelude::*;

const SCENARIOS: [&str; 2] = [
    include_str!("../../scenarios/damped-pendulum.toml"),
    include_str!("../../scenarios/damped-pendulum-fmu.toml"),
];

/// Parses `text`: a scenario whose names pass the key-chunk check, or a typed error.
fn parse_checked(text: &str) -> Result<Scenario, Error> {
    let r = Scenario::parse(text);
    match &r {
        Ok(s) => {
            validate_chunk("scenario name", &s.name).expect("a parsed scenario has a bad name");
            for sim in &s.sims {
                validate_chunk("sim id", &sim.id).expect("a parsed scenario has a bad sim id");
            }
        }
        Err(e) => assert!(
            matches!(e, Error::Config(_) | Error::Protocol { .. }),
            "untyped error: {e:?}"
        ),
    }
    r
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1000, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_text_gives_a_scenario_or_a_typed_error(text in "\\PC{0,200}") {
        let _ = parse_checked(&text);
    }

    #[test]
    fn toml_like_text_gives_a_scenario_or_a_typed_error(
        text in "(\\[\\[?[a-z]{1,8}\\]\\]?\n|[a-z_]{1,10} = (\"[a-z0-9 ]{0,8}\"|-?[0-9]{1,4}|\\[[0-9, .]{0,10}\\]|\\{ *[a-z]+ = [0-9]+ *\\})\n){0,12}"
    ) {
        let _ = parse_checked(&text);
    }

    #[test]
    fn mutated_project_scenarios_give_a_scenario_or_a_typed_error(
        which in 0usize..2,
        cut in any::<prop::sample::Index>(),
        flips in prop::collection::vec((any::<prop::sample::Index>(), 0x20u8..0x7f), 1..4),
    ) {
        let text = SCENARIOS[which];
        let k = cut.index(text.len());
        if text.is_char_boundary(k) {
            let _ = parse_checked(&text[..k]);
        }
        // Only ASCII bytes are replaced (by printable ASCII), so the text stays UTF-8.
        let mut b = text.as_bytes().to_vec();
        for (i, v) in flips {
            let i = i.index(b.len());
            if b[i].is_ascii() {
                b[i] = v;
            }
        }
        if let Ok(t) = std::str::from_utf8(&b) {
            let _ = parse_checked(t);
        }
    }
}

#[test]
fn the_project_scenarios_parse() {
    for text in SCENARIOS {
        parse_checked(text).unwrap();
    }
}
