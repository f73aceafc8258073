//! The framing every binary message shares: the `KB` + version + type header, little-endian
//! scalars and `u32`-counted `f64` vectors, written by [`Writer`] and checked by [`Reader`].

use super::{MsgType, MAGIC, MAX_VECTOR_LEN, PROTOCOL_VERSION};
use crate::error::{Error, ErrorCode, Result};

pub(super) struct Writer(pub(super) Vec<u8>);

impl Writer {
    pub(super) fn new(t: MsgType, cap: usize) -> Self {
        let mut v = Vec::with_capacity(4 + cap);
        v.extend_from_slice(&MAGIC);
        v.push(PROTOCOL_VERSION);
        v.push(t as u8);
        Writer(v)
    }
    pub(super) fn u8(&mut self, v: u8) {
        self.0.push(v);
    }
    pub(super) fn u16(&mut self, v: u16) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(super) fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(super) fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(super) fn f64(&mut self, v: f64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(super) fn vec(&mut self, v: &[f64]) {
        self.u32(v.len() as u32);
        for x in v {
            self.f64(*x);
        }
    }
}

pub(super) struct Reader<'a> {
    b: &'a [u8],
    what: &'static str,
}

pub(super) fn bad(what: &str, msg: impl std::fmt::Display) -> Error {
    Error::protocol(ErrorCode::BadRequest, format!("{what}: {msg}"))
}

impl<'a> Reader<'a> {
    pub(super) fn new(bytes: &'a [u8], t: MsgType, what: &'static str) -> Result<Self> {
        if bytes.len() < 4 {
            return Err(bad(
                what,
                format!("{} bytes, shorter than the 4-byte header", bytes.len()),
            ));
        }
        if bytes[..2] != MAGIC {
            return Err(bad(
                what,
                "does not start with the magic bytes \"KB\" (0x4B 0x42)",
            ));
        }
        if bytes[2] != PROTOCOL_VERSION {
            return Err(Error::protocol(
                ErrorCode::VersionMismatch,
                format!(
                    "{what}: protocol version {} but this participant speaks version {PROTOCOL_VERSION}",
                    bytes[2]
                ),
            ));
        }
        if bytes[3] != t as u8 {
            return Err(bad(
                what,
                format!(
                    "message type 0x{:02x}, expected 0x{:02x}",
                    bytes[3], t as u8
                ),
            ));
        }
        Ok(Reader {
            b: &bytes[4..],
            what,
        })
    }
    pub(super) fn take(&mut self, n: usize) -> Result<&'a [u8]> {
        if self.b.len() < n {
            return Err(bad(self.what, "truncated"));
        }
        let (h, t) = self.b.split_at(n);
        self.b = t;
        Ok(h)
    }
    pub(super) fn u8(&mut self) -> Result<u8> {
        Ok(self.take(1)?[0])
    }
    pub(super) fn u16(&mut self) -> Result<u16> {
        Ok(u16::from_le_bytes(
            self.take(2)?.try_into().unwrap_or([0; 2]),
        ))
    }
    pub(super) fn u32(&mut self) -> Result<u32> {
        Ok(u32::from_le_bytes(
            self.take(4)?.try_into().unwrap_or([0; 4]),
        ))
    }
    pub(super) fn u64(&mut self) -> Result<u64> {
        Ok(u64::from_le_bytes(
            self.take(8)?.try_into().unwrap_or([0; 8]),
        ))
    }
    pub(super) fn f64(&mut self) -> Result<f64> {
        Ok(f64::from_le_bytes(
            self.take(8)?.try_into().unwrap_or([0; 8]),
        ))
    }
    pub(super) fn vec(&mut self) -> Result<Vec<f64>> {
        let n = self.u32()? as usize;
        if n > MAX_VECTOR_LEN {
            return Err(Error::protocol(
                ErrorCode::TooLarge,
                format!(
                    "{}: vector of {n} values (limit {MAX_VECTOR_LEN})",
                    self.what
                ),
            ));
        }
        if self.b.len() < 8 * n {
            return Err(bad(
                self.what,
                format!(
                    "truncated: vector of {n} values needs {} bytes, {} left",
                    8 * n,
                    self.b.len()
                ),
            ));
        }
        (0..n).map(|_| self.f64()).collect()
    }
    pub(super) fn finish(self) -> Result<()> {
        if self.b.is_empty() {
            Ok(())
        } else {
            Err(bad(self.what, format!("{} trailing bytes", self.b.len())))
        }
    }
}
