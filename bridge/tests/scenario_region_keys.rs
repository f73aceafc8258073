//! The initial-state box keys that `[[sims]]` and `[collect]` share (declared once, in
//! `bridge/src/scenario/data_region.rs`): both tables take them at their top level, echo them
//! where they always stood (the serialised form is what report.json and the data-reuse key
//! hold), and refuse an unknown key with serde's message naming it and every valid key.

use bridge::scenario::Scenario;

/// A box on both tables (one form each) and a simulator's own input bounds.
const BOTH: &str = r#"
name = "region"
[[sims]]
id = "pend"
env = "damped-pendulum"
x0_center = [0.0, 0.0]
x0_radius = 0.5
u_low = -1.0
u_high = [1.0]
[collect]
policy = { kind = "uniform" }
train_windows = 10
val_windows = 2
test_windows = 2
x0_low = [-1, -2]
x0_high = [1, 2]
"#;

#[test]
fn both_tables_take_the_box_at_their_top_level_and_echo_it_where_it_always_stood() {
    let s = Scenario::parse(BOTH).unwrap();
    // The serialised form (report.json, the data-reuse key): the keys in declaration order,
    // absent ones left out.
    assert_eq!(
        serde_json::to_string(&s.sims[0]).unwrap(),
        r#"{"id":"pend","env":"damped-pendulum","command":null,"x0_center":[0.0,0.0],"x0_radius":0.5,"u_low":-1.0,"u_high":[1.0]}"#
    );
    assert_eq!(
        serde_json::to_string(&s.collect).unwrap(),
        r#"{"policy":{"kind":"uniform"},"train_windows":10,"val_windows":2,"test_windows":2,"steps":15,"seed":42,"x0_low":[-1.0,-2.0],"x0_high":[1.0,2.0]}"#
    );
    let (sim, collect) = (
        (vec![-0.5, -0.5], vec![0.5, 0.5]),
        (vec![-1.0, -2.0], vec![1.0, 2.0]),
    );
    assert_eq!(s.sims[0].x0_box_in("t").unwrap(), Some(sim.clone()));
    assert_eq!(s.sim_region(0).unwrap().x0_box, Some(sim));
    assert_eq!(s.collect.x0_box().unwrap(), Some(collect));
    assert_eq!(s.sims[0].x0_keys(), ["x0_center", "x0_center"]);
    assert_eq!(s.collect.x0_keys(), ["x0_low", "x0_high"]);
    let mut bad = s.collect.clone();
    bad.x0_radius = Some(bridge::messages::InputBound::All(1.0));
    let e = bad.x0_box().unwrap_err().to_string();
    assert!(
        e.contains("[collect]: give the initial-state box either"),
        "{e}"
    );
}

#[test]
fn an_unknown_key_in_either_table_is_refused_naming_it_and_the_valid_keys() {
    // A typo of a box key, in each table: serde's own message, every valid key named.
    for (table, after, own) in [
        ("[[sims]]", "env = \"damped-pendulum\"\n", "`u_high`"),
        ("[collect]", "test_windows = 2\n", "`train_windows`"),
    ] {
        let text = BOTH.replacen(after, &format!("{after}x0_centre = [0.0, 0.0]\n"), 1);
        let e = Scenario::parse(&text).unwrap_err().to_string();
        assert!(
            e.contains("unknown field `x0_centre`, expected one of")
                && ["`x0_low`", "`x0_high`", "`x0_center`", "`x0_radius`", own]
                    .iter()
                    .all(|k| e.contains(k)),
            "{table}: {e}"
        );
    }
    // u_low/u_high are [[sims]] keys only: [collect]'s input bounds are its policy's.
    let text = BOTH.replace("test_windows = 2\n", "test_windows = 2\nu_low = -1.0\n");
    let e = Scenario::parse(&text).unwrap_err().to_string();
    assert!(
        e.contains("unknown field `u_low`") && e.contains("`policy`"),
        "{e}"
    );
}
