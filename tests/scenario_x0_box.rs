//! The data region of `[collect]` (issue 28 §2): an initial-state box on the built-in damped
//! pendulum, end to end over Zenoh. Every window starts in the box (drawn from its seed and sent
//! as `reset(x0)`), the data are bit-identical on a rerun with the same seed, the metadata
//! records the region; a box of the wrong dimension or an empty one fails before collection,
//! naming the key and the simulator, with nothing written.

mod common;

use koopman::data::DataRegion;

const BOXED: &str = r#"
name = "x0-box"
[[sims]]
id = "pend"
env = "damped-pendulum"
[collect]
policy = { kind = "uniform", low = -0.3, high = 0.3 }
train_windows = 12
val_windows = 4
test_windows = 4
steps = 6
seed = 11
x0_low = [0.5, -0.2]
x0_high = [0.9, 0.1]
"#;

#[test]
fn every_window_starts_in_the_box_and_reruns_bit_for_bit() {
    let dir = common::scratch("x0-box");
    let sc = dir.join("x0-box.toml");
    std::fs::write(&sc, BOXED).unwrap();
    let (a, b) = (dir.join("a"), dir.join("b"));
    common::run_scenario(&sc, &a, &[]);
    common::run_scenario(&sc, &b, &[]);
    let want = DataRegion {
        x0_low: Some(vec![0.5, -0.2]),
        x0_high: Some(vec![0.9, 0.1]),
        u_low: Some(vec![-0.3]),
        u_high: Some(vec![0.3]),
    };
    let mut firsts = Vec::new();
    for split in ["train", "val", "test"] {
        let (d, again) = (
            common::collected(&a, "pend", split),
            common::collected(&b, "pend", split),
        );
        // Two runs in fresh folders (nothing reused): the same bits.
        assert_eq!(d, again, "{split}: a rerun with the same seed differs");
        assert_eq!(d.meta.region.as_ref(), Some(&want), "{split}");
        let side = std::fs::read_to_string(a.join(format!("data/pend/{split}.json"))).unwrap();
        assert!(side.contains("\"x0_high\""), "{side}");
        for i in 0..d.n {
            let x0 = d.state(i, 0);
            assert!((0.5..=0.9).contains(&x0[0]), "{split} window {i}: {x0:?}");
            assert!((-0.2..=0.1).contains(&x0[1]), "{split} window {i}: {x0:?}");
            firsts.push(x0[0]);
        }
        assert!(d.u.iter().all(|u| u.abs() <= 0.3), "{:?}", d.u);
    }
    // The box is used, not the pendulum's own reset (SPEC's θ0 ~ U(±π) would leave it at once),
    // and every window has its own start.
    firsts.sort_by(f64::total_cmp);
    firsts.dedup();
    assert_eq!(firsts.len(), 20, "{firsts:?}");
    // The same region given as a centre and a radius is the same box, hence the same data.
    let around = BOXED.replace(
        "x0_low = [0.5, -0.2]\nx0_high = [0.9, 0.1]",
        "x0_center = [0.7, -0.05]\nx0_radius = [0.2, 0.15]",
    );
    let sc2 = dir.join("around.toml");
    std::fs::write(&sc2, around).unwrap();
    let c = dir.join("c");
    common::run_scenario(&sc2, &c, &[]);
    let (d, e) = (
        common::collected(&a, "pend", "train"),
        common::collected(&c, "pend", "train"),
    );
    let r = e.meta.region.clone().unwrap();
    for (got, want) in r.x0_low.unwrap().iter().zip([0.5, -0.2]) {
        assert!((got - want).abs() < 1e-12, "{got}");
    }
    for i in 0..d.n {
        for (p, q) in d.state(i, 0).iter().zip(e.state(i, 0)) {
            assert!((p - q).abs() < 1e-12, "window {i}: {p} vs {q}");
        }
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_bad_box_fails_before_collection_naming_it() {
    let dir = common::scratch("x0-bad");
    for (i, (from, to, expect)) in [
        (
            "x0_low = [0.5, -0.2]\nx0_high = [0.9, 0.1]",
            "x0_low = [0.5, -0.2, 0.0]\nx0_high = [0.9, 0.1, 0.1]",
            "x0_low has 3 values, simulator 'pend' has 2 states (theta, theta_dot)",
        ),
        (
            "x0_high = [0.9, 0.1]",
            "x0_high = [0.9, -0.3]",
            "x0_low[1] = -0.2 > x0_high[1] = -0.3",
        ),
        (
            "x0_low = [0.5, -0.2]\nx0_high = [0.9, 0.1]",
            "x0_center = [0.0, 0.0, 0.0]\nx0_radius = 0.1",
            "x0_center has 3 values, simulator 'pend' has 2 states",
        ),
        (
            "x0_high = [0.9, 0.1]",
            "x0_high = [0.9, nan]",
            "x0_high[1] is NaN",
        ),
        ("x0_high = [0.9, 0.1]", "", "x0_low and x0_high go together"),
    ]
    .into_iter()
    .enumerate()
    {
        let sc = dir.join(format!("bad{i}.toml"));
        std::fs::write(&sc, BOXED.replace(from, to)).unwrap();
        let out = dir.join(format!("out{i}"));
        let stderr = common::run_scenario_refused(&sc, &out, &format!("case {i}"));
        assert!(stderr.contains(expect), "case {i}: {stderr}");
        // Nothing collected, nothing half-written.
        assert!(!out.join("data/pend").exists(), "case {i} wrote data");
        assert!(!out.join("report.json").exists(), "case {i} wrote a report");
    }
    std::fs::remove_dir_all(&dir).ok();
}
