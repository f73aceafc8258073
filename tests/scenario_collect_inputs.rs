//! A simulator's own collect inputs (`[[sims]] collect_inputs`, issue 25) end to end over Zenoh:
//! two built-in pendulums collect their windows themselves under one adapter policy; the second
//! one's own inputs replace the shared ones in its `collect` requests and nowhere else; inputs a
//! simulator cannot collect with fail before anything starts, naming it.

mod common;

const TWO: &str = r#"
name = "own-inputs"
[[sims]]
id = "shared"
env = "damped-pendulum"
[[sims]]
id = "own"
env = "damped-pendulum"
collect_inputs = { kind = "uniform", low = 0.7, high = 0.7 }
[collect]
policy = { kind = "adapter", inputs = { kind = "uniform", low = -0.3, high = 0.3 }, block = 4 }
train_windows = 6
val_windows = 2
test_windows = 2
steps = 5
seed = 3
"#;

#[test]
fn a_simulators_own_inputs_replace_the_shared_ones_in_its_requests_only() {
    let dir = common::scratch("own-inputs");
    let sc = dir.join("own.toml");
    std::fs::write(&sc, TWO).unwrap();
    let out = dir.join("out");
    common::run_scenario(&sc, &out, &[]);
    let (shared, own) = (
        common::collected(&out, "shared", "train"),
        common::collected(&out, "own", "train"),
    );
    assert_eq!((shared.n, own.n), (6, 6));
    // Its own bounds U(0.7, 0.7): every input exactly 0.7 (ignored, they would be within ±0.3).
    assert!(own.u.iter().all(|&u| u == 0.7), "{:?}", own.u);
    assert_eq!(own.meta.region.as_ref().unwrap().u_low, Some(vec![0.7]));
    // The other keeps the shared policy: varied inputs within ±0.3.
    assert!(shared.u.iter().all(|u| u.abs() <= 0.3), "{:?}", shared.u);
    assert!(shared.u.iter().any(|&u| u != shared.u[0]));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn inputs_a_simulator_cannot_collect_with_fail_before_anything_starts() {
    let dir = common::scratch("own-inputs-bad");
    for (i, (to, expect)) in [
        (
            "collect_inputs = { kind = \"expert\" }",
            "[[sims]] 'own': collect_inputs = adapter-{\"kind\":\"expert\"}: the built-in system \
             'damped-pendulum' draws uniform inputs only",
        ),
        ("collect_inputs = { kind = \"uniform\", pace = 1 }", "pace"),
    ]
    .into_iter()
    .enumerate()
    {
        let sc = dir.join(format!("bad{i}.toml"));
        let text = TWO.replace(
            "collect_inputs = { kind = \"uniform\", low = 0.7, high = 0.7 }",
            to,
        );
        std::fs::write(&sc, text).unwrap();
        let out = dir.join(format!("out{i}"));
        let stderr = common::run_scenario_refused(&sc, &out, &format!("case {i}"));
        assert!(stderr.contains(expect), "case {i}: {stderr}");
        assert!(!out.join("data").exists(), "case {i} collected");
    }
    std::fs::remove_dir_all(&dir).ok();
}
