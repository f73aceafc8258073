//! The one way koopbridge writes files: content goes to a temporary name unique to the call in
//! the same folder, is flushed to disk, and is renamed over the final name, then the folder is
//! flushed too — so a crash never leaves a half-written file, and concurrent writers of one
//! path never share a temporary file (every reader sees one whole version).

use crate::{Error, Result};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

mod temp_dir;
pub use temp_dir::TempDir;

/// Writes `bytes` to `path` atomically (unique temporary file + fsync + rename + fsync of the
/// folder), creating the parent folder if needed.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic_with(path, |f| f.write_all(bytes))
}

/// Like [`write_atomic`], with the content produced by `fill` writing into the temporary file
/// (for streaming writers). On any failure the old content of `path` stays and no temporary
/// file is left.
pub fn write_atomic_with(
    path: &Path,
    fill: impl FnOnce(&mut std::fs::File) -> std::io::Result<()>,
) -> Result<()> {
    let tmp = temp_path(path)?;
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        fill(&mut f)?;
        f.flush()?;
        f.sync_all()
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(Error::io(path, e));
    }
    commit(&tmp, path)
}

/// Writes a whole folder atomically: `fill` writes the files into a fresh temporary folder
/// beside `dest` (a [`TempDir`]); then every file and the folder are flushed and the folder
/// replaces `dest` ([`commit_dir`]). On failure, or a panic in `fill`, nothing is left but the
/// old `dest`.
pub fn write_dir_atomic(dest: &Path, fill: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let tmp = TempDir::beside(dest)?;
    fill(tmp.path())?;
    tmp.commit().map(drop)
}

/// A name beside `path` unique to this call (process id, thread and a counter), hidden
/// (leading dot) and ending in `.tmp`, for content that [`commit`] or [`commit_dir`] moves to
/// `path` later. Creates the parent folder if needed.
pub fn temp_path(path: &Path) -> Result<PathBuf> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let dir = parent(path);
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    let name = path
        .file_name()
        .ok_or_else(|| Error::InvalidArgument(format!("{} is not a file path", path.display())))?;
    let thread: String = format!("{:?}", std::thread::current().id())
        .chars()
        .filter(char::is_ascii_digit)
        .collect();
    Ok(dir.join(format!(
        ".{}.{}-{thread}-{}.tmp",
        name.to_string_lossy(),
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    )))
}

/// Moves the finished file `tmp` (from [`temp_path`]) to `path`: fsync of the file, rename,
/// fsync of the folder. Removes `tmp` on failure.
pub fn commit(tmp: &Path, path: &Path) -> Result<()> {
    let done = std::fs::File::open(tmp)
        .and_then(|f| f.sync_all())
        .and_then(|()| std::fs::rename(tmp, path));
    if let Err(e) = done {
        let _ = std::fs::remove_file(tmp);
        return Err(Error::io(path, e));
    }
    sync_dir(&parent(path))
}

/// Moves the finished folder `tmp` (from [`temp_path`]) to `dest`: fsync of its files and of
/// itself, removal of whatever was at `dest`, rename, fsync of the parent folder.
pub fn commit_dir(tmp: &Path, dest: &Path) -> Result<()> {
    for e in std::fs::read_dir(tmp).map_err(|e| Error::io(tmp, e))? {
        let p = e.map_err(|e| Error::io(tmp, e))?.path();
        if p.is_file() {
            std::fs::File::open(&p)
                .and_then(|f| f.sync_all())
                .map_err(|e| Error::io(&p, e))?;
        }
    }
    sync_dir(tmp)?;
    match std::fs::remove_dir_all(dest) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => return Err(Error::io(dest, e)),
    }
    std::fs::rename(tmp, dest).map_err(|e| Error::io(dest, e))?;
    sync_dir(&parent(dest))
}

fn parent(path: &Path) -> PathBuf {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Flushes a folder's entries (so that a rename inside it survives a crash).
fn sync_dir(dir: &Path) -> Result<()> {
    std::fs::File::open(dir)
        .and_then(|f| f.sync_all())
        .map_err(|e| Error::io(dir, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("koopman-fsutil-{name}-{}", std::process::id()));
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
}
