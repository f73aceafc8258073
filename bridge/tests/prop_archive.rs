//! Property tests of model archives (`services::models::{pack, unpack}`): mutated, truncated and
//! hostile archives (file names with `..`, `/`, hidden names, bad model names) are refused with
//! a typed error and nothing is ever written outside the target folder; pack ∘ unpack is the
//! identity.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use bridge::services::models::{pack, unpack, ARCHIVE_MAGIC};
use bridge::Error;
use proptest::prelude::*;

/// A fresh `root/` holding only `root/target/` (where archives are unpacked).
fn fresh_root() -> PathBuf {
    static N: AtomicUsize = AtomicUsize::new(0);
    let root = std::env::temp_dir().join(format!(
        "kb-prop-archive-{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    ));
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(root.join("target")).unwrap();
    root
}

/// Every path under `dir`, relative to it.
fn tree(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            out.push(p.strip_prefix(dir).unwrap().to_path_buf());
            if p.is_dir() {
                stack.push(p);
            }
        }
    }
    out.sort();
    out
}

/// Unpacks `bytes` into `root/target` and checks: the error is typed, nothing appeared in
/// `root` but `target`, and a success landed in `target/{name}` (then `on_ok` sees that folder,
/// before the scratch folder is removed).
fn unpack_checked(bytes: &[u8]) -> Result<PathBuf, Error> {
    unpack_then(bytes, &|_| {})
}

fn unpack_then(bytes: &[u8], on_ok: &dyn Fn(&Path)) -> Result<PathBuf, Error> {
    let root = fresh_root();
    let target = root.join("target");
    let r = unpack(bytes, &target);
    let outside: Vec<_> = std::fs::read_dir(&root)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .filter(|n| n != "target")
        .collect();
    assert!(
        outside.is_empty(),
        "written outside the target folder: {outside:?}"
    );
    let r = match r {
        Ok((header, dir)) => {
            assert_eq!(dir, target.join(&header.name));
            for f in &header.files {
                assert!(dir.join(&f.name).is_file());
            }
            on_ok(&dir);
            Ok(dir)
        }
        Err(e) => {
            assert!(
                matches!(
                    e,
                    Error::Protocol { .. } | Error::Config(_) | Error::Io { .. }
                ),
                "untyped error: {e:?}"
            );
            // A failed unpack leaves no model folder (only hidden temporary ones, if any).
            for p in tree(&target) {
                let first = p
                    .components()
                    .next()
                    .unwrap()
                    .as_os_str()
                    .to_string_lossy()
                    .to_string();
                assert!(first.starts_with('.'), "a failed unpack left {p:?}");
            }
            Err(e)
        }
    };
    let _ = std::fs::remove_dir_all(&root);
    r
}

/// A packed model folder with `config.json` and `extra` files.
fn packed(name: &str, extra: &[(String, Vec<u8>)]) -> Vec<u8> {
    let root = fresh_root();
    let dir = root.join(name);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("config.json"), br#"{"kind": "koopman", "nx": 2}"#).unwrap();
    for (n, b) in extra {
        std::fs::write(dir.join(n), b).unwrap();
    }
    let b = pack(name, &dir).unwrap();
    let _ = std::fs::remove_dir_all(&root);
    b
}

/// An archive with a hand-written header (any file names, any model name).
fn raw_archive(name: &str, files: &[(String, Vec<u8>)]) -> Vec<u8> {
    let header = serde_json::json!({
        "name": name,
        "config": {},
        "files": files.iter().map(|(n, b)| serde_json::json!({"name": n, "size": b.len()})).collect::<Vec<_>>(),
    })
    .to_string();
    let mut out = ARCHIVE_MAGIC.to_vec();
    out.extend((header.len() as u32).to_le_bytes());
    out.extend(header.as_bytes());
    for (_, b) in files {
        out.extend(b);
    }
    out
}

fn files() -> impl Strategy<Value = Vec<(String, Vec<u8>)>> {
    prop::collection::vec(
        (
            "[a-z][a-z0-9_.]{0,10}",
            prop::collection::vec(any::<u8>(), 0..64),
        ),
        0..4,
    )
    .prop_map(|v| {
        let mut v: Vec<_> = v.into_iter().filter(|(n, _)| n != "config.json").collect();
        v.sort();
        v.dedup_by(|a, b| a.0 == b.0);
        v
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, ..ProptestConfig::default() })]

    #[test]
    fn pack_then_unpack_is_the_identity(name in "[a-z0-9_-]{1,16}", extra in files()) {
        let check = |dir: &Path| {
            for (n, b) in &extra {
                assert_eq!(&std::fs::read(dir.join(n)).unwrap(), b, "{n}");
            }
            assert!(dir.join("config.json").is_file());
        };
        prop_assert!(unpack_then(&packed(&name, &extra), &check).is_ok());
    }

    #[test]
    fn truncated_archives_are_refused(extra in files(), cut in any::<prop::sample::Index>()) {
        let b = packed("m", &extra);
        let k = cut.index(b.len());
        prop_assert!(unpack_checked(&b[..k]).is_err(), "a {k}-byte prefix unpacked");
    }

    #[test]
    fn mutated_archives_never_escape(
        extra in files(),
        flips in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..5),
    ) {
        let mut b = packed("m", &extra);
        for (i, v) in flips {
            let i = i.index(b.len());
            b[i] ^= v.max(1);
        }
        let _ = unpack_checked(&b);
    }

    #[test]
    fn hostile_names_are_refused(
        name in prop_oneof![Just("..".to_string()), Just("a/b".to_string()), Just("".to_string()),
                            Just(".hidden".to_string()), "[a-z]{1,8}"],
        file in prop_oneof![Just("../escape".to_string()), Just("/tmp/abs".to_string()),
                            Just("sub/file".to_string()), Just("..\\win".to_string()),
                            Just(".dot".to_string()), Just("..".to_string()), Just("".to_string())],
        body in prop::collection::vec(any::<u8>(), 0..32),
    ) {
        prop_assert!(unpack_checked(&raw_archive(&name, &[(file, body)])).is_err());
    }

    #[test]
    fn arbitrary_bytes_are_refused(b in prop::collection::vec(any::<u8>(), 0..300)) {
        prop_assert!(unpack_checked(&b).is_err());
    }
}
