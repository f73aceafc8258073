//! Encoding and decoding of `.npy` version 1.0 arrays of little-endian f64 (`<f8`, C order),
//! the member format of numpy's `.npz` files.

/// A decoded array: its shape and its values in C (row-major) order.
#[derive(Clone, Debug, PartialEq)]
pub struct NpyArray {
    /// The shape, outermost dimension first.
    pub shape: Vec<usize>,
    /// `shape.iter().product()` values.
    pub data: Vec<f64>,
}

const MAGIC: &[u8; 6] = b"\x93NUMPY";

/// Encodes `data` with the given shape as a `.npy` v1.0 file (`<f8`, C order); the header is
/// padded with spaces so that the data starts at a multiple of 64 bytes, as numpy does.
pub fn encode(shape: &[usize], data: &[f64]) -> Vec<u8> {
    debug_assert_eq!(shape.iter().product::<usize>(), data.len());
    let dims = match shape.len() {
        1 => format!("({},)", shape[0]),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let mut header = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': {dims}, }}");
    let unpadded = MAGIC.len() + 2 + 2 + header.len() + 1;
    let pad = (64 - unpadded % 64) % 64;
    header.push_str(&" ".repeat(pad));
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + 8 * data.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// Decodes a `.npy` file of version 1.0, 2.0 or 3.0 holding `<f8` or `<f4` values in C order
/// (f4 is widened to f64). Every malformation is a message, never a panic.
pub fn decode(bytes: &[u8]) -> std::result::Result<NpyArray, String> {
    if bytes.len() < 10 || &bytes[..6] != MAGIC {
        return Err("not a .npy array (bad magic bytes)".into());
    }
    let major = bytes[6];
    let (hlen, start): (usize, usize) = match major {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            if bytes.len() < 12 {
                return Err("truncated .npy header".into());
            }
            (
                u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
                12,
            )
        }
        v => return Err(format!("unsupported .npy version {v}")),
    };
    let end = start
        .checked_add(hlen)
        .filter(|&e| e <= bytes.len())
        .ok_or("truncated .npy header")?;
    let header = std::str::from_utf8(&bytes[start..end]).map_err(|_| "header is not text")?;
    let descr = dict_value(header, "descr").ok_or("header has no 'descr'")?;
    let descr = descr.trim_matches(|c| c == '\'' || c == '"');
    let width = match descr {
        "<f8" | "f8" => 8,
        "<f4" | "f4" => 4,
        other => {
            return Err(format!(
                "unsupported dtype '{other}' (expected little-endian float64 '<f8')"
            ))
        }
    };
    let fortran = dict_value(header, "fortran_order").ok_or("header has no 'fortran_order'")?;
    if fortran.trim() != "False" {
        return Err("Fortran-ordered arrays are not supported (save with C order)".into());
    }
    let shape_text = dict_value(header, "shape").ok_or("header has no 'shape'")?;
    let inner = shape_text
        .trim()
        .strip_prefix('(')
        .and_then(|s| s.strip_suffix(')'))
        .ok_or("malformed 'shape'")?;
    let mut shape = Vec::new();
    for part in inner.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        shape.push(
            part.parse::<usize>()
                .map_err(|_| format!("malformed dimension '{part}' in 'shape'"))?,
        );
    }
    let count = shape
        .iter()
        .try_fold(1usize, |acc, &d| acc.checked_mul(d))
        .ok_or("shape too large")?;
    let body = &bytes[end..];
    let needed = count.checked_mul(width).ok_or("shape too large")?;
    if body.len() < needed {
        return Err(format!(
            "truncated data: shape {shape:?} needs {needed} bytes, the file has {}",
            body.len()
        ));
    }
    let data = if width == 8 {
        body[..needed]
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect()
    } else {
        body[..needed]
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")) as f64)
            .collect()
    };
    Ok(NpyArray { shape, data })
}

/// The raw text of `key`'s value in a Python dict literal header (up to the next top-level comma).
fn dict_value<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let pos = header
        .find(&format!("'{key}'"))
        .or_else(|| header.find(&format!("\"{key}\"")))?;
    let rest = &header[pos + key.len() + 2..];
    let rest = rest.trim_start().strip_prefix(':')?.trim_start();
    let mut depth = 0i32;
    for (i, c) in rest.char_indices() {
        match c {
            '(' | '[' => depth += 1,
            ')' | ']' => depth -= 1,
            ',' | '}' if depth == 0 => return Some(&rest[..i]),
            _ => {}
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_header_alignment() {
        for shape in [vec![3usize], vec![2, 3], vec![2, 0, 1], vec![4, 3, 2]] {
            let n: usize = shape.iter().product();
            let data: Vec<f64> = (0..n).map(|i| i as f64 * 0.5 - 1.25).collect();
            let bytes = encode(&shape, &data);
            let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
            assert_eq!((10 + hlen) % 64, 0);
            assert_eq!(bytes[10 + hlen - 1], b'\n');
            let back = decode(&bytes).unwrap();
            assert_eq!(back.shape, shape);
            assert_eq!(back.data, data);
        }
    }

    #[test]
    fn malformed_inputs_are_errors() {
        let good = encode(&[2, 2], &[1.0, 2.0, 3.0, 4.0]);
        assert!(decode(&good[..good.len() - 1])
            .unwrap_err()
            .contains("truncated"));
        assert!(decode(b"hello").is_err());
        let mut bad = good.clone();
        let text = String::from_utf8_lossy(&bad[10..]).replace("<f8", "<i8");
        bad.truncate(10);
        bad.extend_from_slice(text.as_bytes());
        assert!(decode(&bad).unwrap_err().contains("dtype"));
        assert!(decode(&good[..20]).is_err());
    }

    #[test]
    fn reads_a_header_written_the_numpy_way() {
        // A header exactly as numpy 1.x writes it for np.zeros((2, 1)), with f4 data.
        let header = "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 1), }";
        let mut h = header.to_string();
        while (10 + h.len() + 1) % 64 != 0 {
            h.push(' ');
        }
        h.push('\n');
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        bytes.extend_from_slice(&(h.len() as u16).to_le_bytes());
        bytes.extend_from_slice(h.as_bytes());
        bytes.extend_from_slice(&1.5f32.to_le_bytes());
        bytes.extend_from_slice(&(-2.0f32).to_le_bytes());
        let a = decode(&bytes).unwrap();
        assert_eq!(a.shape, vec![2, 1]);
        assert_eq!(a.data, vec![1.5, -2.0]);
    }
}
