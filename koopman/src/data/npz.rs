//! `.npz` reading and writing of [`Dataset`]s: members `x.npy [n, T+1, nx]`, `u.npy [n, T, nu]`
//! (`<f8`) and `meta.json`, stored uncompressed; a sidecar `<stem>.json` beside the archive holds
//! the same metadata for tools that do not open archives. Both are written atomically.

use super::npy;
use super::{Dataset, DatasetMeta, Pairing};
use crate::fsutil::{write_atomic, write_atomic_with};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// The JSON stored as `meta.json` in the archive and as the sidecar: metadata plus dimensions.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NpzMeta {
    /// Number of windows n.
    pub n: usize,
    /// Transitions per window T.
    pub steps: usize,
    /// State dimension.
    pub nx: usize,
    /// Input dimension.
    pub nu: usize,
    /// The dataset metadata.
    #[serde(flatten)]
    pub meta: DatasetMeta,
}

/// The sidecar path of an archive: `dir/name.npz` → `dir/name.json`.
pub fn sidecar_path(path: &Path) -> PathBuf {
    path.with_extension("json")
}

impl Dataset {
    /// Writes the dataset to `path` (`.npz`) and its metadata to the sidecar
    /// [`sidecar_path`]`(path)`, both atomically. The dataset is validated first.
    pub fn save_npz(&self, path: &Path) -> Result<()> {
        self.validate()?;
        let meta = NpzMeta {
            n: self.n,
            steps: self.steps,
            nx: self.nx,
            nu: self.nu,
            meta: self.meta.clone(),
        };
        let meta_json = serde_json::to_vec_pretty(&meta)
            .map_err(|e| Error::format(path, format!("cannot encode metadata: {e}")))?;
        let x = npy::encode(&[self.n, self.steps + 1, self.nx], &self.x);
        let u = npy::encode(&[self.n, self.steps, self.nu], &self.u);
        write_npz(
            path,
            &[("x.npy", &x), ("u.npy", &u), ("meta.json", &meta_json)],
        )?;
        write_atomic(&sidecar_path(path), &meta_json)
    }

    /// Reads a dataset written by [`Dataset::save_npz`] or by numpy (`np.savez(path, x=..., u=...)`).
    /// Metadata comes from the `meta.json` member, else from the sidecar, else defaults (`env`
    /// "unknown", dt 0, names `x0..`, `u0..`, pairing `aligned`, seed 0). Shapes must be `x [n, T+1, nx]`,
    /// `u [n, T, nu]`; values must be finite.
    pub fn load_npz(path: &Path) -> Result<Dataset> {
        let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
        let mut zip = zip::ZipArchive::new(std::io::BufReader::new(file))
            .map_err(|e| Error::format(path, format!("not a readable .npz (zip) archive: {e}")))?;
        let x = read_array(&mut zip, path, "x.npy")?;
        let u = read_array(&mut zip, path, "u.npy")?;
        if x.shape.len() != 3 {
            return Err(Error::format(
                path,
                format!("x must be 3-D [n, T+1, nx], got shape {:?}", x.shape),
            ));
        }
        if u.shape.len() != 3 {
            return Err(Error::format(
                path,
                format!("u must be 3-D [n, T, nu], got shape {:?}", u.shape),
            ));
        }
        let (n, t1, nx) = (x.shape[0], x.shape[1], x.shape[2]);
        let (nu_n, steps, nu) = (u.shape[0], u.shape[1], u.shape[2]);
        if nu_n != n {
            return Err(Error::dimension("windows in u (vs x)", n, nu_n));
        }
        if t1 != steps + 1 {
            return Err(Error::dimension(
                "states per window in x (T+1, T from u)",
                steps + 1,
                t1,
            ));
        }
        let stored: Option<NpzMeta> = match read_member(&mut zip, path, "meta.json")? {
            Some(bytes) => Some(serde_json::from_slice(&bytes).map_err(|e| {
                Error::format(path, format!("member meta.json is not valid metadata: {e}"))
            })?),
            None => match std::fs::read(sidecar_path(path)) {
                Ok(bytes) => serde_json::from_slice(&bytes).ok(),
                Err(_) => None,
            },
        };
        let meta = match stored {
            Some(m) => {
                if (m.n, m.steps, m.nx, m.nu) != (n, steps, nx, nu) {
                    return Err(Error::format(
                        path,
                        format!(
                            "metadata says n={}, T={}, nx={}, nu={} but the arrays are \
                             x {:?}, u {:?}",
                            m.n, m.steps, m.nx, m.nu, x.shape, u.shape
                        ),
                    ));
                }
                if m.meta.input_names.len() != nu || m.meta.state_names.len() != nx {
                    return Err(Error::format(
                        path,
                        format!(
                            "metadata names {} states and {} inputs ({:?}) but the arrays \
                             have nx={nx}, nu={nu}",
                            m.meta.state_names.len(),
                            m.meta.input_names.len(),
                            m.meta.input_names
                        ),
                    ));
                }
                m.meta
            }
            None => DatasetMeta {
                env: "unknown".into(),
                dt: 0.0,
                state_names: (0..nx).map(|i| format!("x{i}")).collect(),
                input_names: (0..nu).map(|i| format!("u{i}")).collect(),
                pairing: Pairing::Aligned,
                seed: 0,
                source: format!("{} (no metadata)", path.display()),
                policy: "unknown".into(),
                region: None,
                window_flags: None,
            },
        };
        let data = Dataset {
            n,
            steps,
            nx,
            nu,
            x: x.data,
            u: u.data,
            meta,
        };
        data.validate()
            .map_err(|e| Error::format(path, e.to_string()))?;
        Ok(data)
    }
}

/// Reads the named `.npy` members of an `.npz` archive (numpy's or ours), each `None` when the
/// archive has no such member; errors name the file and the member.
pub fn read_npz_arrays(path: &Path, names: &[&str]) -> Result<Vec<Option<npy::NpyArray>>> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut zip = zip::ZipArchive::new(std::io::BufReader::new(file))
        .map_err(|e| Error::format(path, format!("not a readable .npz (zip) archive: {e}")))?;
    names
        .iter()
        .map(|name| {
            read_member(&mut zip, path, name)?
                .map(|b| {
                    npy::decode(&b).map_err(|m| Error::format(path, format!("member {name}: {m}")))
                })
                .transpose()
        })
        .collect()
}

/// Writes an uncompressed `.npz` (zip) archive of the given members (name, bytes; arrays made
/// with [`npy::encode`]) to `path`, atomically.
pub fn write_npz(path: &Path, members: &[(&str, &[u8])]) -> Result<()> {
    let large = members
        .iter()
        .any(|(_, b)| b.len() as u64 >= u32::MAX as u64);
    write_atomic_with(path, |file| {
        let mut zip = zip::ZipWriter::new(std::io::BufWriter::new(file));
        let opts = zip::write::SimpleFileOptions::default()
            .compression_method(zip::CompressionMethod::Stored)
            .large_file(large);
        for (name, bytes) in members {
            zip.start_file(*name, opts).map_err(std::io::Error::other)?;
            zip.write_all(bytes)?;
        }
        zip.finish().map_err(std::io::Error::other)?.flush()
    })
}

fn read_member<R: std::io::Read + std::io::Seek>(
    zip: &mut zip::ZipArchive<R>,
    path: &Path,
    name: &str,
) -> Result<Option<Vec<u8>>> {
    let mut f = match zip.by_name(name) {
        Ok(f) => f,
        Err(zip::result::ZipError::FileNotFound) => return Ok(None),
        Err(e) => return Err(Error::format(path, format!("member {name}: {e}"))),
    };
    // The declared size only sizes the buffer (capped: a corrupt header must not abort).
    let mut bytes = Vec::with_capacity((f.size() as usize).min(1 << 28));
    f.read_to_end(&mut bytes).map_err(|e| {
        Error::format(
            path,
            format!("member {name} is unreadable (truncated?): {e}"),
        )
    })?;
    Ok(Some(bytes))
}

fn read_array<R: std::io::Read + std::io::Seek>(
    zip: &mut zip::ZipArchive<R>,
    path: &Path,
    name: &str,
) -> Result<npy::NpyArray> {
    let bytes = read_member(zip, path, name)?
        .ok_or_else(|| Error::format(path, format!("archive has no member {name}")))?;
    npy::decode(&bytes).map_err(|m| Error::format(path, format!("member {name}: {m}")))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::generate;
    use crate::systems::by_name;

    fn tmpdir(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("koopman-npz-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn round_trip_keeps_every_bit_and_the_metadata() {
        let dir = tmpdir("rt");
        for env in ["double", "polynomial"] {
            let s = by_name(env).unwrap();
            let d = generate(s.as_ref(), 33, s.window_steps(), 5, Pairing::Reference).unwrap();
            let p = dir.join(format!("{env}.npz"));
            d.save_npz(&p).unwrap();
            assert!(sidecar_path(&p).exists());
            let back = Dataset::load_npz(&p).unwrap();
            assert_eq!(back, d);
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn missing_truncated_and_inconsistent_files_are_clear_errors() {
        let dir = tmpdir("bad");
        let missing = Dataset::load_npz(&dir.join("nope.npz")).unwrap_err();
        assert!(matches!(missing, Error::Io { .. }), "{missing}");

        let s = by_name("damped").unwrap();
        let d = generate(s.as_ref(), 20, 15, 5, Pairing::Aligned).unwrap();
        let p = dir.join("d.npz");
        d.save_npz(&p).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        for cut in [bytes.len() / 2, bytes.len() - 30, 100] {
            let t = dir.join(format!("cut{cut}.npz"));
            std::fs::write(&t, &bytes[..cut]).unwrap();
            let e = Dataset::load_npz(&t).unwrap_err();
            assert!(matches!(e, Error::Format { .. }), "cut {cut}: {e}");
        }

        // NaN in the data.
        let mut nan = d.clone();
        nan.x[5] = f64::NAN;
        assert!(matches!(
            nan.save_npz(&dir.join("nan.npz")),
            Err(Error::NonFinite(_))
        ));
        // Bypass save's validation: write the archive by hand with a NaN inside.
        let write_raw = |name: &str, x: (&[usize], &[f64]), u: (&[usize], &[f64])| {
            let p = dir.join(name);
            let f = std::fs::File::create(&p).unwrap();
            let mut z = zip::ZipWriter::new(f);
            let o = zip::write::SimpleFileOptions::default()
                .compression_method(zip::CompressionMethod::Stored);
            z.start_file("x.npy", o).unwrap();
            z.write_all(&npy::encode(x.0, x.1)).unwrap();
            z.start_file("u.npy", o).unwrap();
            z.write_all(&npy::encode(u.0, u.1)).unwrap();
            z.finish().unwrap();
            p
        };
        let p = write_raw(
            "rawnan.npz",
            (&[1, 2, 1], &[0.0, f64::NAN]),
            (&[1, 1, 1], &[0.0]),
        );
        let e = Dataset::load_npz(&p).unwrap_err();
        assert!(e.to_string().contains("non-finite"), "{e}");
        // Wrong shapes: T mismatch, window-count mismatch, wrong rank.
        let p = write_raw("t.npz", (&[1, 3, 1], &[0.0; 3]), (&[1, 1, 1], &[0.0]));
        assert!(matches!(
            Dataset::load_npz(&p),
            Err(Error::Dimension { .. })
        ));
        let p = write_raw("n.npz", (&[2, 2, 1], &[0.0; 4]), (&[1, 1, 1], &[0.0]));
        assert!(matches!(
            Dataset::load_npz(&p),
            Err(Error::Dimension { .. })
        ));
        let p = write_raw("rank.npz", (&[4], &[0.0; 4]), (&[1, 1, 1], &[0.0]));
        assert!(matches!(Dataset::load_npz(&p), Err(Error::Format { .. })));
        // A `u` whose width disagrees with the metadata (nu = 1 stored, 2 or 0 in the array).
        let meta_of = |nu: usize, inputs: Vec<String>| {
            let mut m = d.meta.clone();
            m.input_names = inputs;
            serde_json::to_vec(&NpzMeta {
                n: 1,
                steps: 1,
                nx: 2,
                nu,
                meta: m,
            })
            .unwrap()
        };
        for (width, meta, says) in [
            (2, meta_of(1, vec!["u".into()]), "nu=1"),
            (0, meta_of(1, vec!["u".into()]), "nu=1"),
            (1, meta_of(1, vec![]), "0 inputs"),
        ] {
            let p = dir.join(format!("width{width}-{says}.npz"));
            let u = vec![0.25; width];
            write_npz(
                &p,
                &[
                    ("x.npy", &npy::encode(&[1, 2, 2], &[0.0; 4])),
                    ("u.npy", &npy::encode(&[1, 1, width], &u)),
                    ("meta.json", &meta),
                ],
            )
            .unwrap();
            let e = Dataset::load_npz(&p).unwrap_err();
            assert!(matches!(e, Error::Format { .. }), "{e}");
            let msg = e.to_string();
            assert!(
                msg.contains(says) && msg.contains(&format!("{width}")),
                "{msg}"
            );
        }
        // Without metadata it loads with defaults.
        let p = write_raw("plain.npz", (&[1, 2, 1], &[0.0, 1.0]), (&[1, 1, 1], &[0.5]));
        let plain = Dataset::load_npz(&p).unwrap();
        assert_eq!(plain.meta.env, "unknown");
        assert_eq!(plain.x, vec![0.0, 1.0]);
        // Not a zip at all.
        let p = dir.join("text.npz");
        std::fs::write(&p, b"hello world").unwrap();
        assert!(matches!(Dataset::load_npz(&p), Err(Error::Format { .. })));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
