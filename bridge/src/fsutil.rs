//! The data root that confines every file path a network message names (atomic writes are
//! [`koopman::fsutil`]'s, re-exported here).

use std::path::{Path, PathBuf};

use crate::error::{Error, ErrorCode, ErrorReply, Result};

pub use koopman::fsutil::{write_atomic, write_atomic_with};

/// A folder that every file path named by a peer must resolve inside (symlinks followed).
///
/// A service that reads files a request names (the trainer's `{"path": …}` datasets) resolves
/// each one with [`DataRoot::resolve`]; anything outside is refused with
/// [`ErrorCode::Forbidden`], whose message names no file, so that a peer learns nothing about
/// what exists outside the root.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DataRoot {
    root: PathBuf,
}

impl DataRoot {
    /// The data root `dir`, created if missing, with every symlink of its own path resolved.
    pub fn new(dir: &Path) -> Result<Self> {
        let io = |e| Error::Io {
            path: dir.to_path_buf(),
            source: e,
        };
        std::fs::create_dir_all(dir).map_err(io)?;
        Ok(DataRoot {
            root: std::fs::canonicalize(dir).map_err(io)?,
        })
    }

    /// The root itself (canonical).
    pub fn path(&self) -> &Path {
        &self.root
    }

    /// `path` with every symlink resolved, if it names something strictly inside the root; a
    /// relative `path` is taken relative to the root. A file that does not exist (yet) resolves
    /// through its folder, so that reading it later fails as a missing file, not here; a
    /// dangling symlink is refused. `what` names the path in the `forbidden` error (e.g.
    /// "dataset path"); the error never names the path itself.
    pub fn resolve(&self, what: &str, path: &Path) -> std::result::Result<PathBuf, ErrorReply> {
        let forbidden = || {
            ErrorReply::new(
                ErrorCode::Forbidden,
                format!("{what}: only files inside this service's data root may be named"),
            )
        };
        let joined = self.root.join(path);
        let resolved = match std::fs::canonicalize(&joined) {
            Ok(p) => p,
            Err(_) => {
                let name = joined.file_name().ok_or_else(forbidden)?;
                let parent = joined.parent().ok_or_else(forbidden)?;
                let p = std::fs::canonicalize(parent)
                    .map_err(|_| forbidden())?
                    .join(name);
                // Not there: it must not be a (dangling) symlink either, whose target could
                // appear later outside the root.
                if std::fs::symlink_metadata(&p).is_ok() {
                    return Err(forbidden());
                }
                p
            }
        };
        if resolved.starts_with(&self.root) && resolved != self.root {
            Ok(resolved)
        } else {
            Err(forbidden())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn data_root_accepts_inside_and_refuses_everything_else_naming_no_file() {
        let base = std::env::temp_dir().join(format!("kb-dataroot-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&base);
        let outside = base.join("outside");
        std::fs::create_dir_all(&outside).unwrap();
        std::fs::write(outside.join("secret.npz"), b"x").unwrap();
        let root = DataRoot::new(&base.join("root")).unwrap();
        std::fs::create_dir_all(root.path().join("sim")).unwrap();
        std::fs::write(root.path().join("sim/train.npz"), b"x").unwrap();
        let good = root.path().join("sim/train.npz");

        // Inside: absolute, relative, with a `..` that stays inside, and a file not there yet.
        assert_eq!(root.resolve("dataset path", &good).unwrap(), good);
        assert_eq!(
            root.resolve("dataset path", Path::new("sim/train.npz"))
                .unwrap(),
            good
        );
        assert_eq!(
            root.resolve("dataset path", &root.path().join("sim/../sim/train.npz"))
                .unwrap(),
            good
        );
        assert_eq!(
            root.resolve("dataset path", Path::new("sim/later.npz"))
                .unwrap(),
            root.path().join("sim/later.npz")
        );

        // A symlink inside the root that points outside, to a file and to a folder.
        std::os::unix::fs::symlink(outside.join("secret.npz"), root.path().join("link.npz"))
            .unwrap();
        std::os::unix::fs::symlink(&outside, root.path().join("dir")).unwrap();
        // A dangling symlink whose target could be created later.
        std::os::unix::fs::symlink(outside.join("nothing.npz"), root.path().join("dangling"))
            .unwrap();
        let refused = [
            PathBuf::from("/etc/passwd"),
            PathBuf::from("/etc/no-such-file"),
            PathBuf::from("../outside/secret.npz"),
            root.path().join("../outside/secret.npz"),
            root.path().join("sim/../../outside/secret.npz"),
            PathBuf::from("link.npz"),
            PathBuf::from("dir/secret.npz"),
            PathBuf::from("dangling"),
            PathBuf::from(".."),
            PathBuf::from("/"),
            root.path().to_path_buf(),
            PathBuf::from(""),
        ];
        for p in &refused {
            let e = root.resolve("dataset path", p).unwrap_err();
            assert_eq!(e.code, ErrorCode::Forbidden, "{p:?}: {e:?}");
            for word in ["passwd", "secret", "outside", "etc", "link", "dangling"] {
                assert!(!e.message.contains(word), "{p:?}: {}", e.message);
            }
        }
        let _ = std::fs::remove_dir_all(&base);
    }
}
