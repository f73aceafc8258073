//! Encoding and decoding of each binary message (the layouts of PROTOCOL.md §4).

use super::frame::{bad, Reader, Writer};
use super::*;
use crate::error::Result;

impl StepRequest {
    /// Encodes: header, `k: u64`, `n: u32`, `u: n × f64`.
    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer::new(MsgType::StepRequest, 12 + 8 * self.u.len());
        w.u64(self.k);
        w.vec(&self.u);
        w.0
    }
    /// Decodes and checks the whole payload.
    pub fn decode(b: &[u8]) -> Result<Self> {
        let mut r = Reader::new(b, MsgType::StepRequest, "step request")?;
        let m = StepRequest {
            k: r.u64()?,
            u: r.vec()?,
        };
        r.finish()?;
        Ok(m)
    }
}

impl StepReply {
    /// Encodes: header, `k: u64`, `t: f64`, `n: u32`, `x: n × f64` (type `0x02`); with a
    /// non-empty status, type `0x09` and then `status: u8`.
    pub fn encode(&self) -> Vec<u8> {
        let t = if self.status.is_empty() {
            MsgType::StepReply
        } else {
            MsgType::StepReplyStatus
        };
        let mut w = Writer::new(t, 21 + 8 * self.x.len());
        w.u64(self.k);
        w.f64(self.t);
        w.vec(&self.x);
        if t == MsgType::StepReplyStatus {
            w.u8(self.status.bits());
        }
        w.0
    }
    /// Decodes and checks the whole payload (either type; a `0x09` reply must carry a
    /// non-empty status of known bits).
    pub fn decode(b: &[u8]) -> Result<Self> {
        let what = "step reply";
        let with_status = b.len() >= 4 && b[3] == MsgType::StepReplyStatus as u8;
        let t = if with_status {
            MsgType::StepReplyStatus
        } else {
            MsgType::StepReply
        };
        let mut r = Reader::new(b, t, what)?;
        let (k, t, x) = (r.u64()?, r.f64()?, r.vec()?);
        let status = if with_status {
            let s = r.u8()?;
            match StepStatus::from_bits(s) {
                Some(st) if !st.is_empty() => st,
                Some(_) => {
                    return Err(bad(
                        what,
                        "type 0x09 (with a status) but the status is empty (send type 0x02)",
                    ))
                }
                None => {
                    return Err(bad(
                        what,
                        format!(
                            "status 0x{s:02x} has bits this participant does not know (known: \
                             0x{:02x})",
                            StepStatus::KNOWN_BITS
                        ),
                    ))
                }
            }
        } else {
            StepStatus::EMPTY
        };
        r.finish()?;
        Ok(StepReply { k, t, x, status })
    }
}

impl StateMsg {
    /// Encodes: header, `seq: u64`, `k: u64`, `t: f64`, `n: u32`, `x: n × f64`, `m: u32`,
    /// `u: m × f64`.
    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer::new(MsgType::State, 32 + 8 * (self.x.len() + self.u.len()));
        w.u64(self.seq);
        w.u64(self.k);
        w.f64(self.t);
        w.vec(&self.x);
        w.vec(&self.u);
        w.0
    }
    /// Decodes and checks the whole payload.
    pub fn decode(b: &[u8]) -> Result<Self> {
        let mut r = Reader::new(b, MsgType::State, "state")?;
        let m = StateMsg {
            seq: r.u64()?,
            k: r.u64()?,
            t: r.f64()?,
            x: r.vec()?,
            u: r.vec()?,
        };
        r.finish()?;
        Ok(m)
    }
}

impl CommandMsg {
    /// Encodes: header, `seq: u64`, `k: u64`, `n: u32`, `u: n × f64`.
    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer::new(MsgType::Command, 20 + 8 * self.u.len());
        w.u64(self.seq);
        w.u64(self.k);
        w.vec(&self.u);
        w.0
    }
    /// Decodes and checks the whole payload.
    pub fn decode(b: &[u8]) -> Result<Self> {
        let mut r = Reader::new(b, MsgType::Command, "command")?;
        let m = CommandMsg {
            seq: r.u64()?,
            k: r.u64()?,
            u: r.vec()?,
        };
        r.finish()?;
        Ok(m)
    }
}

impl SolveRequest {
    /// Encodes: header (type `0x05`, or `0x08` with a feed-forward), `len: u16`, model name
    /// (UTF-8), `n: u32`, `x`, `m: u32`, `reference`, and for `0x08` `f: u32`, `feedforward`.
    pub fn encode(&self) -> Vec<u8> {
        let name = self.model.as_bytes();
        let t = if self.feedforward.is_empty() {
            MsgType::SolveRequest
        } else {
            MsgType::SolveRequestFeedforward
        };
        let mut w = Writer::new(
            t,
            14 + name.len() + 8 * (self.x.len() + self.reference.len() + self.feedforward.len()),
        );
        w.u16(name.len().min(u16::MAX as usize) as u16);
        w.0.extend_from_slice(&name[..name.len().min(u16::MAX as usize)]);
        w.vec(&self.x);
        w.vec(&self.reference);
        if t == MsgType::SolveRequestFeedforward {
            w.vec(&self.feedforward);
        }
        w.0
    }
    /// Decodes and checks the whole payload (either type; a `0x08` request must carry a
    /// non-empty feed-forward).
    pub fn decode(b: &[u8]) -> Result<Self> {
        let with_ff = b.len() >= 4 && b[3] == MsgType::SolveRequestFeedforward as u8;
        let t = if with_ff {
            MsgType::SolveRequestFeedforward
        } else {
            MsgType::SolveRequest
        };
        let mut r = Reader::new(b, t, "solve request")?;
        let len = r.u16()? as usize;
        let model = std::str::from_utf8(r.take(len)?)
            .map_err(|_| bad("solve request", "model name is not UTF-8"))?
            .to_string();
        let m = SolveRequest {
            model,
            x: r.vec()?,
            reference: r.vec()?,
            feedforward: if with_ff { r.vec()? } else { Vec::new() },
        };
        r.finish()?;
        if with_ff && m.feedforward.is_empty() {
            return Err(bad(
                "solve request",
                "type 0x08 (with a feed-forward) but the feed-forward is empty",
            ));
        }
        Ok(m)
    }
}

impl SolveReply {
    /// Encodes: header, `status: u8`, `iterations: u32`, `solve_time_ns: u64`, `n: u32`, `u`.
    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer::new(MsgType::SolveReply, 17 + 8 * self.u.len());
        w.u8(self.status as u8);
        w.u32(self.iterations);
        w.u64(self.solve_time_ns);
        w.vec(&self.u);
        w.0
    }
    /// Decodes and checks the whole payload.
    pub fn decode(b: &[u8]) -> Result<Self> {
        let mut r = Reader::new(b, MsgType::SolveReply, "solve reply")?;
        let status = match r.u8()? {
            0 => SolveStatus::Solved,
            1 => SolveStatus::Suboptimal,
            2 => SolveStatus::Fallback,
            3 => SolveStatus::Inaccurate,
            s => return Err(bad("solve reply", format!("unknown status {s}"))),
        };
        let m = SolveReply {
            status,
            iterations: r.u32()?,
            solve_time_ns: r.u64()?,
            u: r.vec()?,
        };
        r.finish()?;
        Ok(m)
    }
}

impl CollectChunk {
    /// Encodes: header, `block: u64`, `chunk: u32`, `chunks: u32`, `first: u64`,
    /// `windows: u32`, `steps: u32`, `nx: u32`, `nu: u32`, `x: vec`, `u: vec`.
    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer::new(
            MsgType::CollectChunk,
            48 + 8 * (self.x.len() + self.u.len()),
        );
        w.u64(self.block);
        w.u32(self.chunk);
        w.u32(self.chunks);
        w.u64(self.first);
        w.u32(self.windows);
        w.u32(self.steps);
        w.u32(self.nx);
        w.u32(self.nu);
        w.vec(&self.x);
        w.vec(&self.u);
        w.0
    }
    /// Decodes and checks the whole payload: `chunk < chunks`, and `x`/`u` hold exactly
    /// `windows·(steps+1)·nx` and `windows·steps·nu` values.
    pub fn decode(b: &[u8]) -> Result<Self> {
        let what = "collect chunk";
        let mut r = Reader::new(b, MsgType::CollectChunk, what)?;
        let m = CollectChunk {
            block: r.u64()?,
            chunk: r.u32()?,
            chunks: r.u32()?,
            first: r.u64()?,
            windows: r.u32()?,
            steps: r.u32()?,
            nx: r.u32()?,
            nu: r.u32()?,
            x: r.vec()?,
            u: r.vec()?,
        };
        r.finish()?;
        if m.chunk >= m.chunks {
            return Err(bad(
                what,
                format!("chunk {} of {} chunks", m.chunk, m.chunks),
            ));
        }
        let (n, t) = (u64::from(m.windows), u64::from(m.steps));
        let want_x = n * (t + 1) * u64::from(m.nx);
        let want_u = n * t * u64::from(m.nu);
        if m.x.len() as u64 != want_x || m.u.len() as u64 != want_u {
            return Err(bad(
                what,
                format!(
                    "{} windows of {} steps (nx {}, nu {}) need {want_x} and {want_u} values, got {} and {}",
                    m.windows,
                    m.steps,
                    m.nx,
                    m.nu,
                    m.x.len(),
                    m.u.len()
                ),
            ));
        }
        Ok(m)
    }
}
