//! Tests of `[full]`: `control_defaults` reach the rows that take the defaults, only with
//! `--full`, and a bad one is refused when the file is read.

use super::Scenario;

/// Two tracking rows: `spec` writes its `mpc` and `q_from_data` itself, `rec` takes them from
/// `[control_defaults]`.
fn two_rows(full: &str) -> String {
    format!(
        "name = \"legs\"\n[[sims]]\nid = \"pend\"\nenv = \"damped-pendulum\"\n\
         [collect]\ntrain_windows = 10\nval_windows = 2\ntest_windows = 2\n\
         [train]\nconfig = {{ iterations = 5 }}\n\
         [control_defaults]\nreferences = \"r.npz\"\nerror_state = true\n\
         q_from_data = {{ states = [0] }}\nmpc = {{ horizon = 15, r = [1.0] }}\n\
         [[control]]\nlabel = \"spec\"\nerror_state = false\nq_from_data = {{}}\n\
         mpc = {{ horizon = 15 }}\n\
         [[control]]\nlabel = \"rec\"\n{full}"
    )
}

#[test]
fn full_control_defaults_reach_the_rows_that_take_the_defaults_and_only_with_full() {
    let text = two_rows(
        "[full]\ntrain_windows = 100\ncontrol_defaults = { mpc = { horizon = 15, r = [0.1] }, \
         q_from_data = { states = [0], also = [{ states = [1], scale = 0.1 }] } }\n",
    );
    let mut s = Scenario::parse(&text).unwrap();
    let (spec, rec) = (s.tracks[0].clone(), s.tracks[1].clone());
    assert_eq!(rec.mpc["r"], serde_json::json!([1.0]), "not before --full");
    assert!(rec.q_from_data.as_ref().unwrap().also.is_empty());
    s.apply_full();
    assert_eq!(s.collect.train_windows, 100);
    assert_eq!(s.tracks.len(), 2);
    let full_rec = &s.tracks[1];
    assert_eq!(full_rec.label.as_deref(), Some("rec"));
    assert_eq!(full_rec.mpc["r"], serde_json::json!([0.1]));
    assert_eq!(full_rec.q_from_data.as_ref().unwrap().also.len(), 1);
    assert!(full_rec.error_state, "a default --full does not name stays");
    // SPEC's row writes its keys itself: untouched.
    let full_spec = &s.tracks[0];
    assert_eq!(full_spec.mpc, spec.mpc);
    assert!(!full_spec.mpc.contains_key("r"));
    assert_eq!(full_spec.q_from_data, spec.q_from_data);
    assert!(!full_spec.error_state);
}

#[test]
fn a_file_without_control_defaults_gets_fulls_as_its_defaults() {
    let text = two_rows("[full]\ncontrol_defaults = { steps = 7 }\n");
    let text = text.replace("[control_defaults]\n", "[unused]\n");
    // Without [control_defaults] the rows lack `references`: give each its own.
    let text = text.replace("label = ", "references = \"r.npz\"\nlabel = ");
    let text = text.replace("[unused]\nreferences = \"r.npz\"\n", "");
    let text = text.replace(
        "error_state = true\nq_from_data = { states = [0] }\nmpc = { horizon = 15, r = [1.0] }\n",
        "",
    );
    let mut s = Scenario::parse(&text).unwrap_or_else(|e| panic!("{e}\n{text}"));
    assert_eq!(s.tracks[1].steps, None);
    s.apply_full();
    assert_eq!(s.tracks[0].steps, Some(7));
    assert_eq!(s.tracks[1].steps, Some(7));
}

#[test]
fn a_bad_full_control_default_is_refused_when_the_file_is_read() {
    let e = Scenario::parse(&two_rows("[full]\ncontrol_defaults = { wind = 1 }\n"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("with --full") && e.contains("wind"), "{e}");
    let e = Scenario::parse(&two_rows("[full]\ncontrol_defaults = 3\n"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("[full].control_defaults must be a table"), "{e}");
    // A setting the file's checks refuse (a negative group weight) is refused without
    // --full too.
    let e = Scenario::parse(&two_rows(
        "[full]\ncontrol_defaults = { q_from_data = { also = [{ states = [1], scale = -1.0 }] } }\n",
    ))
    .unwrap_err()
    .to_string();
    assert!(e.contains("with --full"), "{e}");
}
