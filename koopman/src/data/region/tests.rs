//! Tests of data regions through the whole split generation (bit-for-bit defaults, windows inside
//! the region, refusals).

use super::*;
use crate::data::{generate_splits, SplitSpec, Splits};
use crate::systems::by_name;
use std::f64::consts::PI;

/// FNV-1a over the bits of the values (the golden values below were computed with numpy
/// from the files `koopbridge data gen` wrote before regions existed).
fn fnv(parts: &[&[f64]]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for v in parts.iter().flat_map(|p| p.iter()) {
        h ^= v.to_bits();
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

fn small(region: Option<DataRegion>) -> SplitSpec {
    SplitSpec {
        windows: 90,
        train: 70,
        val: 10,
        test: 10,
        region,
        ..SplitSpec::default()
    }
}

/// The double-pendulum control task's region (issue 12 §3).
fn task_region() -> DataRegion {
    DataRegion {
        x0_low: Some(vec![-0.2, -1.0, -2.0, -2.0]),
        x0_high: Some(vec![1.4, 0.2, 2.0, 2.0]),
        u_low: Some(vec![-40.0, -40.0]),
        u_high: Some(vec![40.0, 40.0]),
    }
}

#[test]
fn default_generation_is_bitwise_unchanged() {
    let golden = [
        ("double", 0x3d3d_ef82_29cd_c7ba_u64),
        ("damped", 0x3a5d_bbc3_3a58_ed92),
        ("polynomial", 0x62c8_0187_d64c_ad89),
    ];
    for (env, want) in golden {
        let s = by_name(env).unwrap();
        let sp = generate_splits(s.as_ref(), &small(None)).unwrap();
        assert_eq!(fnv(&[&sp.train.x, &sp.train.u]), want, "{env} moved");
        assert_eq!(sp.train.meta.region, None);
        let json = serde_json::to_string(&sp.train.meta).unwrap();
        assert!(!json.contains("region"), "{json}");
    }
    // A region equal to SPEC's own box draws the same numbers in the same order.
    let s = by_name("double").unwrap();
    let spec_box = DataRegion {
        x0_low: Some(vec![-0.1 * PI, -0.1 * PI, -1.0, -1.0]),
        x0_high: Some(vec![0.1 * PI, 0.1 * PI, 1.0, 1.0]),
        u_low: Some(vec![-6.0, -6.0]),
        u_high: Some(vec![6.0, 6.0]),
    };
    let sp = generate_splits(s.as_ref(), &small(Some(spec_box))).unwrap();
    assert_eq!(fnv(&[&sp.train.x, &sp.train.u]), golden[0].1);
}

#[test]
fn every_window_starts_in_the_region_with_inputs_in_bounds() {
    let s = by_name("double").unwrap();
    let region = task_region();
    let spec = SplitSpec {
        windows: 600,
        train: 400,
        val: 100,
        test: 100,
        ..small(Some(region.clone()))
    };
    let sp = generate_splits(s.as_ref(), &spec).unwrap();
    let (lo, hi) = (region.x0_low.unwrap(), region.x0_high.unwrap());
    let (mut beyond_spec, mut big_input) = (0, 0);
    let mut y = [0.0; 4];
    for d in [&sp.train, &sp.val, &sp.test] {
        assert_eq!(d.meta.region, Some(task_region()));
        for i in 0..d.n {
            let x0 = d.state(i, 0);
            for k in 0..4 {
                assert!(lo[k] <= x0[k] && x0[k] <= hi[k], "window {i}: {x0:?}");
            }
            beyond_spec += usize::from(x0[0] > 0.1 * PI);
            for t in 0..d.steps {
                let u = d.input(i, t);
                assert!(u.iter().all(|v| v.abs() <= 40.0), "{u:?}");
                big_input += usize::from(u.iter().any(|v| v.abs() > 6.0));
                // Still the true system, aligned pairing.
                s.step(d.state(i, t), u, &mut y);
                assert_eq!(&y[..], d.state(i, t + 1));
            }
        }
    }
    // The region is used, not SPEC's box (θ1 > 0.1π for ~60% of the windows, |u| > 6 for
    // ~98% of the steps).
    assert!(beyond_spec > 250, "{beyond_spec}");
    assert!(big_input > 8000, "{big_input}");
    // The region survives the files.
    let dir = std::env::temp_dir().join(format!("koopman-region-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    sp.save(&dir).unwrap();
    assert_eq!(Splits::load(&dir).unwrap(), sp);
    let side = std::fs::read_to_string(dir.join("train.json")).unwrap();
    assert!(
        side.contains("\"region\"") && side.contains("\"x0_high\""),
        "{side}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn from_parts_builds_checks_and_refuses() {
    let s = by_name("double").unwrap();
    let s = s.as_ref();
    let v = |x: &[f64]| Some(x.to_vec());
    assert_eq!(
        DataRegion::from_parts(s, (None, None), (None, None), None).unwrap(),
        None
    );
    let r = DataRegion::from_parts(s, (None, None), (None, None), Some(40.0))
        .unwrap()
        .unwrap();
    assert_eq!(
        (r.u_low, r.u_high, r.x0_low),
        (v(&[-40.0, -40.0]), v(&[40.0, 40.0]), None)
    );
    let x0 = (v(&[-0.2, -1.0, -2.0, -2.0]), v(&[1.4, 0.2, 2.0, 2.0]));
    let ok = DataRegion::from_parts(s, x0.clone(), (None, None), Some(40.0)).unwrap();
    assert_eq!(ok, Some(task_region()));
    let bad: Vec<(_, _, Option<f64>)> = vec![
        // wrong lengths
        ((v(&[0.0; 3]), v(&[1.0; 3])), (None, None), None),
        (x0.clone(), (v(&[-1.0]), v(&[1.0])), None),
        // crossed bounds
        (
            (v(&[0.0, 1.0, 0.0, 0.0]), v(&[1.0, 0.5, 1.0, 1.0])),
            (None, None),
            None,
        ),
        (x0.clone(), (v(&[1.0, 1.0]), v(&[-1.0, 2.0])), None),
        // NaN and infinity
        (
            (v(&[f64::NAN, 0.0, 0.0, 0.0]), v(&[1.0; 4])),
            (None, None),
            None,
        ),
        (
            x0.clone(),
            (v(&[-1.0, -1.0]), v(&[1.0, f64::INFINITY])),
            None,
        ),
        ((None, None), (None, None), Some(f64::NAN)),
        ((None, None), (None, None), Some(-3.0)),
        // one side only, or both forms of the input range
        ((v(&[0.0; 4]), None), (None, None), None),
        ((None, None), (None, v(&[1.0, 1.0])), None),
        ((None, None), (v(&[-1.0, -1.0]), v(&[1.0, 1.0])), Some(2.0)),
    ];
    for (i, (x0, u, b)) in bad.into_iter().enumerate() {
        let err = DataRegion::from_parts(s, x0, u, b);
        assert!(err.is_err(), "case {i} accepted: {err:?}");
    }
    // A system without inputs takes no input range, and InRegion re-checks.
    let p = by_name("polynomial").unwrap();
    assert!(DataRegion::from_parts(p.as_ref(), (None, None), (None, None), Some(1.0)).is_err());
    let crossed = DataRegion {
        u_low: v(&[1.0, 1.0]),
        u_high: v(&[0.0, 0.0]),
        ..DataRegion::default()
    };
    assert!(InRegion::new(s, crossed.clone()).is_err());
    assert!(generate_splits(s, &small(Some(crossed))).is_err());
}
