//! The model store: serves every model directory under a store folder at `…/models/{name}` as a
//! small archive (JSON header + the files), and unpacks such archives on the client side.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use serde::{Deserialize, Serialize};
use zenoh::Session;

use super::{key_tail, serve_queries, Inbox};
use crate::client::Client;
use crate::error::{Error, ErrorCode, ErrorReply, Result};
use crate::keyexpr::{validate_chunk, Keys, Role};

/// Magic bytes of a model archive.
pub const ARCHIVE_MAGIC: [u8; 4] = *b"KBM1";
/// Largest model archive served or accepted (256 MiB).
pub const MAX_ARCHIVE: usize = 256 << 20;

/// One file of an archive.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ArchiveFile {
    /// File name inside the model directory (no path separators).
    pub name: String,
    /// Size in bytes.
    pub size: u64,
}

/// The JSON header of a model archive.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ArchiveHeader {
    /// Model name.
    pub name: String,
    /// The model's `config.json` (kind, dims, training metadata).
    pub config: serde_json::Value,
    /// The files that follow the header, in order.
    pub files: Vec<ArchiveFile>,
}

fn safe_file_name(n: &str) -> bool {
    !n.is_empty() && n != "." && n != ".." && !n.contains(['/', '\\']) && !n.starts_with('.')
}

/// Packs the regular files of `dir` (not hidden ones) into an archive:
/// `KBM1`, `u32` LE header length, JSON header, then the files' bytes in header order.
pub fn pack(name: &str, dir: &Path) -> Result<Vec<u8>> {
    let io = |p: &Path, e| Error::Io {
        path: p.to_path_buf(),
        source: e,
    };
    let config_path = dir.join("config.json");
    let config: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&config_path).map_err(|e| io(&config_path, e))?)
            .map_err(|e| Error::Config(format!("{}: {e}", config_path.display())))?;
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .map_err(|e| io(dir, e))?
        .filter_map(|e| e.ok())
        .filter(|e| e.file_type().map(|t| t.is_file()).unwrap_or(false))
        .filter_map(|e| e.file_name().into_string().ok())
        .filter(|n| safe_file_name(n))
        .collect();
    names.sort();
    let mut files = Vec::new();
    let mut body = Vec::new();
    for n in &names {
        let p = dir.join(n);
        let b = std::fs::read(&p).map_err(|e| io(&p, e))?;
        files.push(ArchiveFile {
            name: n.clone(),
            size: b.len() as u64,
        });
        body.extend_from_slice(&b);
    }
    let header = serde_json::to_vec(&ArchiveHeader {
        name: name.to_string(),
        config,
        files,
    })
    .map_err(|e| Error::Config(e.to_string()))?;
    let mut out = Vec::with_capacity(8 + header.len() + body.len());
    out.extend_from_slice(&ARCHIVE_MAGIC);
    out.extend_from_slice(&(header.len() as u32).to_le_bytes());
    out.extend_from_slice(&header);
    out.extend_from_slice(&body);
    if out.len() > MAX_ARCHIVE {
        return Err(Error::protocol(
            ErrorCode::TooLarge,
            format!("model '{name}' is {} bytes", out.len()),
        ));
    }
    Ok(out)
}

/// Unpacks an archive into `dir/{name}` (written to a temporary folder, then renamed). Every
/// part is checked before anything is written: a bad archive leaves `dir` as it was.
pub fn unpack(bytes: &[u8], dir: &Path) -> Result<(ArchiveHeader, PathBuf)> {
    let (header, bodies) = parse(bytes)?;
    let final_dir = write(&header, &bodies, dir)?;
    Ok((header, final_dir))
}

/// [`unpack`] of the archive of model `name` into `dir/{name}`: the archive of another model is
/// refused before anything is written (else a store answering for `a` with model `b` would
/// replace `dir/b`).
pub fn unpack_model(bytes: &[u8], dir: &Path, name: &str) -> Result<PathBuf> {
    let (header, bodies) = parse(bytes)?;
    if header.name != name {
        return Err(bad_archive(&format!(
            "asked for model '{name}', got '{}'",
            header.name
        )));
    }
    write(&header, &bodies, dir)
}

fn bad_archive(m: &str) -> Error {
    Error::protocol(ErrorCode::BadRequest, format!("model archive: {m}"))
}

/// An archive's header and the bytes of each of its files (in header order), every one checked.
fn parse(bytes: &[u8]) -> Result<(ArchiveHeader, Vec<&[u8]>)> {
    let bad = bad_archive;
    if bytes.len() < 8 || bytes[..4] != ARCHIVE_MAGIC {
        return Err(bad("missing KBM1 magic"));
    }
    let hl = u32::from_le_bytes([bytes[4], bytes[5], bytes[6], bytes[7]]) as usize;
    let rest = &bytes[8..];
    if rest.len() < hl {
        return Err(bad("truncated header"));
    }
    let header: ArchiveHeader =
        serde_json::from_slice(&rest[..hl]).map_err(|e| bad(&format!("header: {e}")))?;
    validate_chunk("model name", &header.name)?;
    // Every file is checked before anything is written.
    let mut body = &rest[hl..];
    let mut bodies = Vec::with_capacity(header.files.len());
    for f in &header.files {
        if !safe_file_name(&f.name) {
            return Err(bad(&format!("unsafe file name {:?}", f.name)));
        }
        let n = usize::try_from(f.size).unwrap_or(usize::MAX);
        if body.len() < n {
            return Err(bad("truncated body"));
        }
        bodies.push(&body[..n]);
        body = &body[n..];
    }
    if !body.is_empty() {
        return Err(bad("trailing bytes"));
    }
    Ok((header, bodies))
}

/// Writes a parsed archive as the folder `dir/{name}`, atomically.
fn write(header: &ArchiveHeader, bodies: &[&[u8]], dir: &Path) -> Result<PathBuf> {
    let final_dir = dir.join(&header.name);
    koopman::fsutil::write_dir_atomic(&final_dir, |tmp| {
        header
            .files
            .iter()
            .zip(bodies)
            .try_for_each(|(f, bytes)| koopman::fsutil::write_atomic(&tmp.join(&f.name), bytes))
    })?;
    Ok(final_dir)
}

/// Fetches model `name` from the session's model store into `dir/{name}`.
pub fn fetch(client: &Client, name: &str, dir: &Path, timeout: Duration) -> Result<PathBuf> {
    let key = client.keys.model(name)?;
    let bytes = client.query(&key, Vec::new(), timeout, &format!("model store ({name})"))?;
    std::fs::create_dir_all(dir).map_err(|e| Error::Io {
        path: dir.to_path_buf(),
        source: e,
    })?;
    unpack_model(&bytes, dir, name)
}

/// Serves `store/{name}` at `…/models/{name}` until `stop` is set.
pub fn serve(
    session: &Session,
    keys: &Keys,
    id: &str,
    store: &Path,
    stop: &AtomicBool,
) -> Result<()> {
    let mut inbox = Inbox::new();
    inbox.declare(session, &keys.under(&["models", "*"]), ())?;
    tracing::info!("model store '{id}' serving {}", store.display());
    serve_queries(
        session,
        keys,
        Role::Models,
        id,
        &inbox,
        stop,
        |(), q, _body| {
            let name = key_tail(q, "model name")?;
            let dir = store.join(&name);
            if !dir.join("config.json").is_file() {
                return Err(ErrorReply::new(
                    ErrorCode::NotFound,
                    format!("no model '{name}' in this store"),
                ));
            }
            pack(&name, &dir).map_err(|e| e.to_reply())
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pack_unpack_round_trip_and_rejects_bad_archives() {
        let root = std::env::temp_dir().join(format!("kb-models-{}", std::process::id()));
        let src = root.join("src");
        std::fs::create_dir_all(&src).unwrap();
        std::fs::write(src.join("config.json"), br#"{"kind":"koopman","nx":2}"#).unwrap();
        std::fs::write(src.join("model.safetensors"), [1u8, 2, 3, 4, 5]).unwrap();
        let a = pack("m1", &src).unwrap();
        let (h, dir) = unpack(&a, &root.join("dst")).unwrap();
        assert_eq!(h.config["kind"], "koopman");
        assert_eq!(
            std::fs::read(dir.join("model.safetensors")).unwrap(),
            vec![1, 2, 3, 4, 5]
        );
        assert!(unpack(&a[..a.len() - 1], &root.join("dst")).is_err());
        assert!(unpack(b"nope", &root.join("dst")).is_err());
        let mut evil = a.clone();
        let s = String::from_utf8_lossy(&evil).replace("model.safetensors", "../../xxx.safeten");
        evil = s.into_bytes();
        assert!(unpack(&evil, &root.join("dst")).is_err());
        let _ = std::fs::remove_dir_all(&root);
    }

    /// An empty scratch folder for test `what` and the unpack target inside it.
    fn fresh(what: &str) -> (PathBuf, PathBuf) {
        let root = std::env::temp_dir().join(format!("kb-models-{what}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let dst = root.join("dst");
        (root, dst)
    }

    /// A model folder `root/{name}` with `config.json` and `weights`, packed.
    fn archive_of(root: &Path, name: &str, weights: &[u8]) -> Vec<u8> {
        let src = root.join(name);
        std::fs::create_dir_all(&src).unwrap();
        std::fs::write(src.join("config.json"), br#"{"kind":"koopman"}"#).unwrap();
        std::fs::write(src.join("weights"), weights).unwrap();
        pack(name, &src).unwrap()
    }

    /// Every entry under `dir` (hidden ones too) with its bytes, for before/after comparisons.
    fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
        let mut out = Vec::new();
        let mut stack = vec![dir.to_path_buf()];
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d).unwrap() {
                let p = e.unwrap().path();
                if p.is_dir() {
                    out.push((p.clone(), Vec::new()));
                    stack.push(p);
                } else {
                    out.push((p.clone(), std::fs::read(&p).unwrap()));
                }
            }
        }
        out.sort();
        out
    }

    #[test]
    fn a_truncated_archive_leaves_no_temporary_folder_and_the_target_untouched() {
        let (root, dst) = fresh("trunc");
        // The target already holds version 1 of m1; version 2 arrives cut at every length.
        unpack(&archive_of(&root.join("v1"), "m1", b"old weights"), &dst).unwrap();
        let before = snapshot(&dst);
        assert_eq!(before.len(), 3, "{before:?}"); // m1/, m1/config.json, m1/weights
        let v2 = archive_of(&root.join("v2"), "m1", &[7u8; 300]);
        for cut in 0..v2.len() {
            let err = unpack(&v2[..cut], &dst).expect_err("a truncated archive was unpacked");
            assert!(matches!(err, Error::Protocol { .. }), "cut {cut}: {err:?}");
            assert_eq!(
                snapshot(&dst),
                before,
                "cut {cut} changed the target folder"
            );
        }
        unpack(&v2, &dst).unwrap();
        assert_eq!(
            std::fs::read(dst.join("m1/weights")).unwrap(),
            vec![7u8; 300]
        );
        assert_eq!(snapshot(&dst).len(), 3);
        let _ = std::fs::remove_dir_all(&root);
    }

    #[test]
    fn the_archive_of_another_model_is_refused_before_anything_is_written() {
        let (root, dst) = fresh("name");
        unpack(&archive_of(&root.join("v1"), "b", b"b's own weights"), &dst).unwrap();
        let before = snapshot(&dst);
        // Asked for `a`, answered with a `b`: `dst/b` must not be replaced.
        let other = archive_of(&root.join("v2"), "b", b"someone else's weights");
        let err = unpack_model(&other, &dst, "a").expect_err("a wrong model was unpacked");
        assert!(
            err.to_string().contains("asked for model 'a', got 'b'"),
            "{err}"
        );
        assert_eq!(snapshot(&dst), before);
        let a = archive_of(&root.join("v3"), "a", b"a");
        assert_eq!(unpack_model(&a, &dst, "a").unwrap(), dst.join("a"));
        let _ = std::fs::remove_dir_all(&root);
    }
}
