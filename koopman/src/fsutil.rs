//! The one way koopbridge writes files: content goes to a temporary name unique to the call in
//! the same folder, is flushed to disk, and is renamed over the final name, then the folder is
//! flushed too — so a crash never leaves a half-written file, and concurrent writers of one
//! path never share a temporary file (every reader sees one whole version).

use crate::{Error, Result};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

mod temp_dir;
pub use temp_dir::{write_dir_atomic, TempDir};

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
mod tests;
