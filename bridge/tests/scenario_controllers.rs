//! The keys of several controllers on one simulator: labels distinct per simulator, and what each
//! baseline controller (`controller = "feedforward"`, `"zero-input"`) needs and refuses.

use bridge::scenario::{Controller, Scenario};

/// A scenario with the `[[control]]` entries `entries` (TOML) for simulator `pend`.
fn with(entries: &str) -> bridge::error::Result<Scenario> {
    Scenario::parse(&format!(
        "name = \"demo\"\n[[sims]]\nid = \"pend\"\nenv = \"damped-pendulum\"\n\
         [collect]\ntrain_windows = 10\nval_windows = 2\ntest_windows = 2\n\
         [train]\nconfig = {{ iterations = 5 }}\n{entries}"
    ))
}

const MPC: &str = "[[control]]\nx0 = [1.0, 0.0]\nreference = [0.0, 0.0]\nsteps = 5\n";
const PLAN: &str = "[[control]]\nx0 = [1.0, 0.0]\nreference_file = \"r.npy\"\n\
                    feedforward_file = \"u.npy\"\nsteps = 5\n";

#[test]
fn a_simulators_several_entries_need_distinct_labels() {
    let e = with(&format!("{MPC}{MPC}")).unwrap_err().to_string();
    assert!(e.contains("distinct `label`"), "{e}");
    let one = format!("{MPC}label = \"a\"\n{MPC}label = \"a\"\n");
    assert!(with(&one).unwrap_err().to_string().contains("distinct"));
    let two = format!("{MPC}{MPC}label = \"b\"\n");
    assert!(with(&two).is_err(), "the first entry needs its label too");
    let s = with(&format!("{MPC}label = \"a\"\n{MPC}label = \"b\"\n")).unwrap();
    assert_eq!(s.control.len(), 2);
    let e = with(&format!("{MPC}label = \"a b\"\n"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("label"), "{e}");
}

#[test]
fn a_baseline_controller_gets_what_it_needs_and_nothing_of_the_mpc() {
    let s = with(&format!("{MPC}controller = \"zero-input\"\n")).unwrap();
    assert_eq!(s.control[0].controller, Controller::ZeroInput);
    assert_eq!(with(MPC).unwrap().control[0].controller, Controller::Mpc);
    let e = with(&format!("{MPC}controller = \"feedforward\"\n"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("needs `feedforward_file`"), "{e}");
    let s = with(&format!("{PLAN}controller = \"feedforward\"\n")).unwrap();
    assert_eq!(s.control[0].controller, Controller::Feedforward);
    let e = with(&format!(
        "{MPC}controller = \"zero-input\"\noffset_free = {{ mode = \"integral\" }}\n"
    ))
    .unwrap_err()
    .to_string();
    assert!(e.contains("offset_free"), "{e}");
    assert!(with(&format!("{MPC}controller = \"pid\"\n")).is_err());
    // A tracking task's baseline is its replay row.
    let e = with("[[control]]\nreferences = \"r.npz\"\ncontroller = \"zero-input\"\n")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("`controller` is not a key of a tracking task"),
        "{e}"
    );
}

#[test]
fn a_single_loop_takes_a_perturbation_checked_when_read() {
    let s = with(&format!("{MPC}perturbation = {{ command_gain = 0.9 }}\n")).unwrap();
    let p = s.control[0].perturbation.as_ref().unwrap().for_reference(0);
    assert_eq!(p.command_gain, Some(0.9));
    for bad in [
        "command_gain = 0.0",
        "command_gain = -1.0",
        "mass_scale = 0.0",
    ] {
        let e = with(&format!("{MPC}perturbation = {{ {bad} }}\n"))
            .unwrap_err()
            .to_string();
        let key = bad.split(' ').next().unwrap();
        assert!(e.contains(&format!("perturbation.{key}")), "{bad}: {e}");
    }
}
