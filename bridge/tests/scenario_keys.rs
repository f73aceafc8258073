//! Every table of the scenario schema refuses an unknown key when the file is read, naming the
//! key and the valid ones (scenarios/README.md): the test walks every table and inline table of
//! documents that together hold each table of the schema (each collection policy, both forms of
//! `[control]`), inserts an unknown key into one table at a time, and parses.

use std::collections::BTreeSet;

use bridge::scenario::Scenario;
use toml::Value;

const UNKNOWN: &str = "zz_not_a_setting";

/// One control entry with every sub-table, a uniform policy with bounds, training (a
/// simulator's own settings too), hooks, participants and `[full]`.
const EVERYTHING: &str = r#"
name = "keys"
description = "every table"
[[sims]]
id = "pend"
env = "damped-pendulum"
train_config = { n_mult = 2 }
[collect]
policy = { kind = "uniform", low = -1.0, high = [1.0] }
train_windows = 10
val_windows = 2
test_windows = 2
[train]
config = { iterations = 5, hidden = [8] }
[control]
sim = "pend"
x0 = [0.5, 0.0]
reference_file = "r.npy"
feedforward_file = "u.npy"
steps = 5
mpc = { horizon = 5, q = [1.0, 0.1] }
offset_free = { mode = "disturbance", radius = 0.3, gain = [0.1, 0.1], angles = [0] }
position_loop = { position = [0], velocity = [1], gain = 1.0 }
[[hooks]]
phase = "before-collect"
command = "true"
[[participants]]
id = "plan"
role = "planner"
command = ["true"]
[full]
train_windows = 20
train_config = { iterations = 50 }
"#;

/// `[[control]]` entries and a scripted policy.
const ARRAY: &str = r#"
name = "keys"
[[sims]]
id = "a"
env = "damped-pendulum"
[[sims]]
id = "b"
env = "damped-pendulum"
[collect]
policy = { kind = "scripted", inputs = [[1.0], [-1.0]] }
train_windows = 10
val_windows = 2
test_windows = 2
[train]
config = { seed = 3 }
[[control]]
sim = "a"
x0 = [0.5, 0.0]
reference = [0.0, 0.0]
steps = 5
[[control]]
sim = "b"
x0 = [0.5, 0.0]
reference = [0.0, 0.0]
steps = 5
mpc = { horizon = 4 }
"#;

/// The adapter policies (windows run by the simulators), both input policies; a simulator's
/// own inputs.
const ADAPTER_UNIFORM: &str = r#"
name = "keys"
[[sims]]
id = "pend"
env = "damped-pendulum"
collect_inputs = { kind = "uniform", low = -0.05, high = 0.05 }
[collect]
policy = { kind = "adapter", inputs = { kind = "uniform", low = -0.1, high = 0.1 }, block = 5 }
train_windows = 10
val_windows = 2
test_windows = 2
"#;

const ADAPTER_PLANNED: &str = r#"
name = "keys"
[[sims]]
id = "pend"
env = "damped-pendulum"
[collect]
policy = { kind = "adapter", inputs = { kind = "planned", windows_per_plan = 2, dither = 0.1 } }
train_windows = 10
val_windows = 2
test_windows = 2
"#;

/// Every table of the schema, named by its keys (array indices left out) and, for a tagged
/// table, its `kind`.
const SCHEMA: [&str; 20] = [
    "",
    "sims",
    "sims.collect_inputs(uniform)",
    "sims.train_config",
    "collect",
    "collect.policy(uniform)",
    "collect.policy(scripted)",
    "collect.policy(adapter)",
    "collect.policy.inputs(uniform)",
    "collect.policy.inputs(planned)",
    "train",
    "train.config",
    "control",
    "control.mpc",
    "control.offset_free",
    "control.position_loop",
    "hooks",
    "participants",
    "full",
    "full.train_config",
];

#[derive(Clone, Debug)]
enum Step {
    Key(String),
    Index(usize),
}

/// The path of every table in `v` (itself included), depth first.
fn tables(v: &Value, at: &mut Vec<Step>, out: &mut Vec<Vec<Step>>) {
    match v {
        Value::Table(t) => {
            out.push(at.clone());
            for (k, child) in t {
                at.push(Step::Key(k.clone()));
                tables(child, at, out);
                at.pop();
            }
        }
        Value::Array(a) => {
            for (i, child) in a.iter().enumerate() {
                at.push(Step::Index(i));
                tables(child, at, out);
                at.pop();
            }
        }
        _ => {}
    }
}

fn table_at<'v>(v: &'v mut Value, path: &[Step]) -> &'v mut toml::Table {
    let mut cur = v;
    for s in path {
        cur = match s {
            Step::Key(k) => &mut cur.as_table_mut().unwrap()[k.as_str()],
            Step::Index(i) => &mut cur.as_array_mut().unwrap()[*i],
        };
    }
    cur.as_table_mut().unwrap()
}

/// The schema name of the table at `path` in `doc`.
fn schema_name(doc: &Value, path: &[Step]) -> String {
    let mut doc = doc.clone();
    let keys: Vec<&str> = path
        .iter()
        .filter_map(|s| match s {
            Step::Key(k) => Some(k.as_str()),
            Step::Index(_) => None,
        })
        .collect();
    let t = table_at(&mut doc, path);
    match t.get("kind").and_then(Value::as_str) {
        Some(kind) => format!("{}({kind})", keys.join(".")),
        None => keys.join("."),
    }
}

#[test]
fn every_table_refuses_an_unknown_key_naming_it_and_the_valid_ones() {
    let mut covered = BTreeSet::new();
    for text in [EVERYTHING, ARRAY, ADAPTER_UNIFORM, ADAPTER_PLANNED] {
        Scenario::parse(text).unwrap_or_else(|e| panic!("the document itself: {e}\n{text}"));
        let doc: Value = toml::from_str(text).unwrap();
        let mut paths = Vec::new();
        tables(&doc, &mut Vec::new(), &mut paths);
        for path in paths {
            let name = schema_name(&doc, &path);
            let mut bad = doc.clone();
            let t = table_at(&mut bad, &path);
            let valid: Vec<String> = t.keys().filter(|k| *k != "kind").cloned().collect();
            t.insert(UNKNOWN.into(), Value::Integer(1));
            let bad_text = toml::to_string(&bad).unwrap();
            let err = match Scenario::parse(&bad_text) {
                Ok(_) => panic!("table '{name}' accepted the unknown key:\n{bad_text}"),
                Err(e) => e.to_string(),
            };
            assert!(
                err.contains(UNKNOWN),
                "'{name}': the key is not named: {err}"
            );
            assert!(
                valid.iter().any(|k| err.contains(k.as_str())) && !valid.is_empty(),
                "'{name}': no valid key ({valid:?}) named: {err}"
            );
            covered.insert(name);
        }
    }
    let schema: BTreeSet<String> = SCHEMA.iter().map(|s| s.to_string()).collect();
    assert_eq!(covered, schema, "the documents do not hold every table");
}

#[test]
fn the_uniform_bounds_are_checked_when_read() {
    let with =
        |policy: &str| EVERYTHING.replace(r#"kind = "uniform", low = -1.0, high = [1.0]"#, policy);
    for (policy, expect) in [
        (
            r#"kind = "uniform", low = 1.0, high = -1.0"#,
            "`low` 1 > `high` -1",
        ),
        (r#"kind = "uniform", low = [0.0, 0.0], high = [1.0]"#, ""),
        (
            r#"kind = "uniform", low = [0.0, 0.0], high = [1.0, 2.0, 3.0]"#,
            "`low` has 2 values and `high` 3",
        ),
        (r#"kind = "uniform", low = "x""#, "low"),
    ] {
        let r = Scenario::parse(&with(policy));
        if expect.is_empty() {
            // Two values for one input: a length is checked against `nu` with the simulators.
            r.unwrap();
        } else {
            let e = r.unwrap_err().to_string();
            assert!(e.contains(expect), "{policy}: {e}");
        }
    }
}
