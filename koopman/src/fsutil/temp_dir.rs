//! A temporary folder beside its destination that removes itself unless it was committed, so
//! that no error path or panic of whatever fills it leaves it behind, and the atomic folder
//! write built on it.

use std::path::{Path, PathBuf};

use super::{commit_dir, temp_path};
use crate::{Error, Result};

/// A fresh hidden folder beside `dest` (named by [`temp_path`]), removed with everything in it
/// when dropped, unless [`TempDir::commit`] moved it to `dest`.
#[derive(Debug)]
pub struct TempDir {
    path: PathBuf,
    dest: PathBuf,
}

impl TempDir {
    /// Creates the empty temporary folder for `dest` (and `dest`'s parent folder if needed).
    pub fn beside(dest: &Path) -> Result<Self> {
        let path = temp_path(dest)?;
        std::fs::create_dir(&path).map_err(|e| Error::io(&path, e))?;
        Ok(TempDir {
            path,
            dest: dest.to_path_buf(),
        })
    }

    /// The temporary folder, to fill.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Moves the filled folder to its destination with [`commit_dir`] and returns that path.
    /// On failure the destination keeps what it had and the temporary folder is removed.
    pub fn commit(self) -> Result<PathBuf> {
        commit_dir(&self.path, &self.dest)?;
        // After the rename nothing is left at `self.path`: dropping removes nothing.
        Ok(self.dest.clone())
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        // Gone already after a commit; otherwise removed with its content. A failure here (maybe
        // while unwinding) has nowhere to go: the name is hidden and unique to this call.
        let _ = std::fs::remove_dir_all(&self.path);
    }
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
