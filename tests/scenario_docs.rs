//! `scenarios/README.md` is the scenario reference: every TOML example in it parses and passes
//! the checks `koopbridge run` makes against a damped-pendulum simulator's `info`; every
//! `TrainConfig` and `MpcConfig` field has a row; every scenario in `scenarios/` parses.

use bridge::messages::SimInfo;
use bridge::orchestrator::validate::{train_setting_names, validate_scenario};
use bridge::scenario::Scenario;

fn readme() -> String {
    std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/README.md")).unwrap()
}

/// The bodies of the ```toml blocks of `text`.
fn toml_blocks(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut cur: Option<String> = None;
    for line in text.lines() {
        match (&mut cur, line.trim_end()) {
            (None, "```toml") => cur = Some(String::new()),
            (Some(b), "```") => {
                out.push(std::mem::take(b));
                cur = None;
            }
            (Some(b), l) => {
                b.push_str(l);
                b.push('\n');
            }
            (None, _) => {}
        }
    }
    out
}

#[test]
fn every_example_parses_and_passes_the_checks() {
    let sys = koopman::systems::by_name("damped-pendulum").unwrap();
    let info = SimInfo::from_system(sys.as_ref());
    let blocks = toml_blocks(&readme());
    assert!(blocks.len() >= 3, "only {} examples", blocks.len());
    for b in &blocks {
        let mut sc = Scenario::parse(b).unwrap_or_else(|e| panic!("{e}\n{b}"));
        let infos = vec![&info; sc.sims.len()];
        validate_scenario(&sc, &infos).unwrap_or_else(|e| panic!("{e}\n{b}"));
        sc.apply_full();
        validate_scenario(&sc, &infos).unwrap_or_else(|e| panic!("--full: {e}\n{b}"));
    }
}

#[test]
fn every_setting_has_a_row() {
    let text = readme();
    let row = |name: &str| text.contains(&format!("| `{name}` |"));
    let mpc = serde_json::to_value(koopman::mpc::MpcConfig::default()).unwrap();
    let names: Vec<String> = train_setting_names()
        .into_iter()
        .chain(mpc.as_object().unwrap().keys().cloned())
        .collect();
    assert!(names.len() > 20);
    for n in names {
        assert!(row(&n), "scenarios/README.md has no row for `{n}`");
    }
    for key in [
        "name",
        "description",
        "id",
        "env",
        "command",
        "policy",
        "train_windows",
        "val_windows",
        "test_windows",
        "steps",
        "seed",
        "config",
        "x0",
        "reference",
        "sim",
        "mpc",
        "train_config",
        "\"uniform\"",
        "\"scripted\"",
        "reference_file",
        "phase",
        "role",
        "offset_free",
        "references",
        "survival",
        "continue_after_failure",
        "error_state",
        "label",
        "replay",
        "q_from_data",
        "onpolicy_steps",
        "perturbation",
        "aggregate",
    ] {
        assert!(row(key), "scenarios/README.md has no row for `{key}`");
    }
}

#[test]
fn the_shipped_scenarios_parse() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios");
    let mut n = 0;
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        if e.path().extension().is_some_and(|x| x == "toml") {
            Scenario::load(&e.path()).unwrap_or_else(|err| panic!("{}: {err}", e.path().display()));
            n += 1;
        }
    }
    assert!(n >= 2);
}

#[test]
fn the_g1s_full_budget_runs_the_spec_size_controller_beside_specs_row() {
    let file = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/g1-survival.toml");
    let mut sc = Scenario::load(std::path::Path::new(file)).unwrap();
    let r_of = |sc: &Scenario, label: Option<&str>| {
        let t = sc
            .tracks
            .iter()
            .find(|t| t.label.as_deref() == label)
            .unwrap();
        (t.mpc.get("r").cloned(), t.q_from_data.clone())
    };
    let (spec_before, rec_before) = (r_of(&sc, None), r_of(&sc, Some("error-state")));
    assert_eq!(rec_before.0.unwrap()[0], 1.0);
    sc.apply_full();
    assert_eq!(r_of(&sc, None), spec_before, "SPEC's row is as written");
    for label in ["error-state", "push", "mass", "friction", "mass-friction"] {
        let (r, q) = r_of(&sc, Some(label));
        assert_eq!(r.unwrap()[0], 0.1, "{label}");
        assert_eq!(q.unwrap().also[0].states, vec![1, 2, 4, 5, 7, 8], "{label}");
    }
}
