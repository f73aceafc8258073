//! Property tests of dataset loading: truncated, mutated and arbitrary `.npz`/`.npy` bytes given
//! to `Dataset::load_npz` and `npy::decode` give an error or a dataset that passes its own
//! validation, never a panic; save ∘ load is the identity.

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};

use koopman::data::{npy, Dataset, DatasetMeta, Pairing};
use proptest::prelude::*;

/// A fresh file path in this test's own scratch folder (no sidecar next to it).
fn scratch_file() -> PathBuf {
    static N: AtomicUsize = AtomicUsize::new(0);
    let dir = std::env::temp_dir().join(format!("kb-prop-npz-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(format!("d{}.npz", N.fetch_add(1, Ordering::Relaxed)))
}

fn dataset(n: usize, steps: usize, nx: usize, nu: usize, seed: u64) -> Dataset {
    let mut s = seed | 1;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    Dataset {
        n,
        steps,
        nx,
        nu,
        x: (0..n * (steps + 1) * nx).map(|_| next()).collect(),
        u: (0..n * steps * nu).map(|_| next()).collect(),
        meta: DatasetMeta {
            env: "prop".into(),
            dt: 0.05,
            state_names: (0..nx).map(|i| format!("x{i}")).collect(),
            input_names: (0..nu).map(|i| format!("u{i}")).collect(),
            pairing: Pairing::Aligned,
            seed,
            source: "prop_npz".into(),
            policy: "uniform".into(),
            region: None,
            window_flags: None,
        },
    }
}

/// The bytes of a saved dataset (its sidecar removed, so only the archive speaks).
fn saved_bytes(d: &Dataset) -> Vec<u8> {
    let p = scratch_file();
    d.save_npz(&p).unwrap();
    let b = std::fs::read(&p).unwrap();
    let _ = std::fs::remove_file(&p);
    let _ = std::fs::remove_file(p.with_extension("json"));
    b
}

/// Loads `bytes` as an `.npz` file: an error, or a dataset that validates.
fn load(bytes: &[u8]) -> Result<Dataset, koopman::Error> {
    let p = scratch_file();
    std::fs::write(&p, bytes).unwrap();
    let r = Dataset::load_npz(&p);
    let _ = std::fs::remove_file(&p);
    if let Ok(d) = &r {
        d.validate()
            .expect("load_npz returned a dataset that does not validate");
        assert!(d.x.iter().chain(&d.u).all(|v| v.is_finite()));
    }
    r
}

fn dims() -> impl Strategy<Value = (usize, usize, usize, usize, u64)> {
    (1usize..5, 1usize..5, 1usize..4, 1usize..3, any::<u64>())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

    #[test]
    fn save_then_load_is_the_identity((n, steps, nx, nu, seed) in dims()) {
        let d = dataset(n, steps, nx, nu, seed);
        prop_assert_eq!(load(&saved_bytes(&d)).unwrap(), d);
    }

    #[test]
    fn truncated_archives_are_errors((n, steps, nx, nu, seed) in dims(), cut in any::<prop::sample::Index>()) {
        let b = saved_bytes(&dataset(n, steps, nx, nu, seed));
        let k = cut.index(b.len());
        prop_assert!(load(&b[..k]).is_err(), "a {k}-byte prefix of a {}-byte archive loaded", b.len());
    }

    #[test]
    fn mutated_archives_are_errors_or_valid(
        (n, steps, nx, nu, seed) in dims(),
        flips in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
    ) {
        let mut b = saved_bytes(&dataset(n, steps, nx, nu, seed));
        for (i, v) in flips {
            let i = i.index(b.len());
            b[i] ^= v.max(1);
        }
        let _ = load(&b);
    }

    #[test]
    fn arbitrary_bytes_are_errors(b in prop::collection::vec(any::<u8>(), 0..400)) {
        prop_assert!(load(&b).is_err());
    }

    #[test]
    fn npy_decode_never_panics(b in prop::collection::vec(any::<u8>(), 0..300)) {
        let _ = npy::decode(&b);
    }

    #[test]
    fn npy_round_trips_and_refuses_mutations(
        shape in prop::collection::vec(0usize..4, 1..4),
        cut in any::<prop::sample::Index>(),
        flip in (any::<prop::sample::Index>(), any::<u8>()),
    ) {
        let len: usize = shape.iter().product();
        let data: Vec<f64> = (0..len).map(|i| i as f64 * 0.5 - 1.0).collect();
        let b = npy::encode(&shape, &data);
        let a = npy::decode(&b).unwrap();
        prop_assert_eq!((&a.shape, &a.data), (&shape, &data));
        let k = cut.index(b.len());
        prop_assert!(npy::decode(&b[..k]).is_err(), "a {k}-byte prefix decoded");
        let mut m = b.clone();
        let i = flip.0.index(m.len());
        m[i] ^= flip.1.max(1);
        if let Ok(a) = npy::decode(&m) {
            prop_assert_eq!(a.data.len(), a.shape.iter().product::<usize>());
        }
    }
}
