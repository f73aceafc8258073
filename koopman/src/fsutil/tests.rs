//! Tests of the atomic writes: files and folders replaced whole or not at all, unique temporary
//! names, concurrent writers, panics while filling.

use super::*;

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("koopman-fsutil-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn writes_replaces_and_leaves_no_temporary_on_failure() {
    let dir = scratch("basic");
    let p = dir.join("sub").join("a.txt");
    write_atomic(&p, b"one").unwrap();
    write_atomic(&p, b"two").unwrap();
    assert_eq!(std::fs::read(&p).unwrap(), b"two");
    let err = write_atomic_with(&p, |_| Err(std::io::Error::other("disk full")));
    assert!(err.is_err());
    // The old content survives a failed write, and no temporary file is left behind.
    assert_eq!(std::fs::read(&p).unwrap(), b"two");
    assert_eq!(names(p.parent().unwrap()), ["a.txt"]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn temporary_names_are_unique_per_call() {
    let dir = scratch("names");
    let p = dir.join("a.json");
    let a = temp_path(&p).unwrap();
    let b = temp_path(&p).unwrap();
    let q = p.clone();
    let c = std::thread::spawn(move || temp_path(&q).unwrap())
        .join()
        .unwrap();
    assert!(a != b && b != c && a != c, "{a:?} {b:?} {c:?}");
    assert!(a
        .file_name()
        .unwrap()
        .to_string_lossy()
        .starts_with(".a.json."));
    assert_eq!(a.parent(), Some(dir.as_path()));
    let _ = std::fs::remove_dir_all(&dir);
}

/// Many threads write versions of one path at once while others read it: every read sees
/// one whole version (never a mix, never a short file), and no temporary file is left.
#[test]
fn concurrent_writers_of_one_path_never_expose_a_partial_version() {
    let dir = scratch("race");
    let p = dir.join("record.json");
    // Version v: 64 KiB of byte v, so a torn or mixed file is visible.
    let version = |v: u8| vec![v; 64 << 10];
    write_atomic(&p, &version(0)).unwrap();
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let readers: Vec<_> = (0..2)
        .map(|_| {
            let (p, stop) = (p.clone(), stop.clone());
            std::thread::spawn(move || {
                let mut reads = 0u64;
                while !stop.load(Ordering::Relaxed) {
                    let b = std::fs::read(&p).unwrap();
                    assert_eq!(b.len(), 64 << 10, "a short read of a whole version");
                    assert!(b.iter().all(|&x| x == b[0]), "a mixed version");
                    reads += 1;
                }
                reads
            })
        })
        .collect();
    let writers: Vec<_> = (1..=8u8)
        .map(|w| {
            let p = p.clone();
            std::thread::spawn(move || {
                for _ in 0..25 {
                    write_atomic(&p, &version(w)).unwrap();
                }
            })
        })
        .collect();
    for w in writers {
        w.join()
            .expect("a writer failed (a shared temporary name?)");
    }
    stop.store(true, Ordering::Relaxed);
    for r in readers {
        assert!(r.join().unwrap() > 0);
    }
    let last = std::fs::read(&p).unwrap();
    assert!((1..=8).contains(&last[0]) && last.iter().all(|&x| x == last[0]));
    assert_eq!(names(&dir), ["record.json"]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn folders_are_replaced_whole_or_not_at_all() {
    let dir = scratch("dir");
    let dest = dir.join("model");
    write_dir_atomic(&dest, |d| {
        write_atomic(&d.join("a"), b"1")?;
        write_atomic(&d.join("b"), b"2")
    })
    .unwrap();
    assert_eq!(names(&dest), ["a", "b"]);
    // A failing fill leaves the old folder as it was, and no temporary folder.
    let failed = write_dir_atomic(&dest, |d| {
        write_atomic(&d.join("c"), b"3")?;
        Err(Error::InvalidArgument("stop".into()))
    });
    assert!(failed.is_err());
    assert_eq!(names(&dest), ["a", "b"]);
    write_dir_atomic(&dest, |d| write_atomic(&d.join("c"), b"3")).unwrap();
    assert_eq!(names(&dest), ["c"]);
    assert_eq!(names(&dir), ["model"]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_panic_while_filling_a_folder_leaves_no_temporary_folder() {
    let dir = scratch("panic");
    let dest = dir.join("model");
    write_dir_atomic(&dest, |d| write_atomic(&d.join("a"), b"1")).unwrap();
    let unwound = std::panic::catch_unwind(|| {
        let _ = write_dir_atomic(&dest, |d| {
            write_atomic(&d.join("b"), b"2")?;
            panic!("a bug in the code filling the folder");
        });
    });
    assert!(unwound.is_err());
    assert_eq!(names(&dir), ["model"]);
    assert_eq!(names(&dest), ["a"]);
    assert_eq!(std::fs::read(dest.join("a")).unwrap(), b"1");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_temporary_folder_is_removed_unless_committed() {
    let dir = scratch("tempdir");
    let dest = dir.join("model");
    {
        let t = TempDir::beside(&dest).unwrap();
        write_atomic(&t.path().join("a"), b"1").unwrap();
        assert_eq!(names(&dir).len(), 1);
    }
    assert!(names(&dir).is_empty(), "{:?}", names(&dir));
    let t = TempDir::beside(&dest).unwrap();
    write_atomic(&t.path().join("b"), b"2").unwrap();
    assert_eq!(t.commit().unwrap(), dest);
    assert_eq!(names(&dir), ["model"]);
    assert_eq!(names(&dest), ["b"]);
    let _ = std::fs::remove_dir_all(&dir);
}
