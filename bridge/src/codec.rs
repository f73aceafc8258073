//! Compact little-endian binary codec of the hot-path messages (step, state, command, solve,
//! collect chunks), each framed by the magic `KB`, the protocol version and a message type byte.

use crate::error::{Error, ErrorCode, Result};

/// Protocol version carried by every binary message and by `info`.
pub const PROTOCOL_VERSION: u8 = 1;
/// The two magic bytes that open every binary message.
pub const MAGIC: [u8; 2] = *b"KB";
/// The largest vector length a message may carry (guards allocations on hostile input).
pub const MAX_VECTOR_LEN: usize = 1 << 20;

/// The message type byte (4th byte of the header).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum MsgType {
    /// [`StepRequest`].
    StepRequest = 0x01,
    /// [`StepReply`].
    StepReply = 0x02,
    /// [`StateMsg`].
    State = 0x03,
    /// [`CommandMsg`].
    Command = 0x04,
    /// [`SolveRequest`].
    SolveRequest = 0x05,
    /// [`SolveReply`].
    SolveReply = 0x06,
    /// [`CollectChunk`].
    CollectChunk = 0x07,
}

/// `step` query: apply `u` at step `k` (`u_k` held over `[t_k, t_k + dt)`).
#[derive(Clone, Debug, PartialEq)]
pub struct StepRequest {
    /// The step index of the state the input is applied to.
    pub k: u64,
    /// The input `u_k`, `nu` values.
    pub u: Vec<f64>,
}

/// `step` reply: the state after the step.
#[derive(Clone, Debug, PartialEq)]
pub struct StepReply {
    /// `k + 1`.
    pub k: u64,
    /// Simulation time `t_{k+1}` in seconds.
    pub t: f64,
    /// The state `x_{k+1}`, `nx` values.
    pub x: Vec<f64>,
}

/// Free-run `state` publication.
#[derive(Clone, Debug, PartialEq)]
pub struct StateMsg {
    /// Publication sequence number (0, 1, 2, … without gaps at the sender).
    pub seq: u64,
    /// Step index.
    pub k: u64,
    /// Simulation time in seconds.
    pub t: f64,
    /// The state, `nx` values.
    pub x: Vec<f64>,
    /// The input that was held over `[t_{k-1}, t_k)` to reach this state (`nu` values; empty
    /// for the first state after a reset), so that a recorder pairs transitions exactly.
    pub u: Vec<f64>,
}

/// Free-run `command` publication.
#[derive(Clone, Debug, PartialEq)]
pub struct CommandMsg {
    /// Sequence number at the sender.
    pub seq: u64,
    /// The step index of the state this command answers.
    pub k: u64,
    /// The input, `nu` values.
    pub u: Vec<f64>,
}

/// `solve` query of the MPC service.
#[derive(Clone, Debug, PartialEq)]
pub struct SolveRequest {
    /// Model name in the service's store; empty = the service's default model.
    pub model: String,
    /// Current state, `nx` values.
    pub x: Vec<f64>,
    /// Reference: one state (`nx`) or a stacked horizon (`H·nx`).
    pub reference: Vec<f64>,
}

/// Status of a solve.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum SolveStatus {
    /// Solved to tolerance.
    Solved = 0,
    /// Stopped at an iteration or time limit; `u` is feasible but not proven optimal.
    Suboptimal = 1,
    /// The solver failed; `u` is a fallback plan (previous plan shifted, clamped to the bounds).
    Fallback = 2,
    /// Optimal to reduced accuracy.
    Inaccurate = 3,
}

/// `solve` reply.
#[derive(Clone, Debug, PartialEq)]
pub struct SolveReply {
    /// Solver status.
    pub status: SolveStatus,
    /// Solver iterations.
    pub iterations: u32,
    /// Solve time inside the service in nanoseconds.
    pub solve_time_ns: u64,
    /// The input sequence, `H·nu` values, first input first.
    pub u: Vec<f64>,
}

/// One reply of a `collect` query: windows `first .. first + windows` of the collection,
/// chunk `chunk` of the `chunks` replies that together hold the requested block.
#[derive(Clone, Debug, PartialEq)]
pub struct CollectChunk {
    /// The block index of the request.
    pub block: u64,
    /// This chunk's index (0-based).
    pub chunk: u32,
    /// How many chunks the block has.
    pub chunks: u32,
    /// The collection index of the chunk's first window.
    pub first: u64,
    /// Windows in this chunk.
    pub windows: u32,
    /// Transitions per window T.
    pub steps: u32,
    /// State dimension.
    pub nx: u32,
    /// Input dimension.
    pub nu: u32,
    /// States `[windows, steps + 1, nx]`, row-major.
    pub x: Vec<f64>,
    /// Inputs `[windows, steps, nu]`, row-major.
    pub u: Vec<f64>,
}

struct Writer(Vec<u8>);

impl Writer {
    fn new(t: MsgType, cap: usize) -> Self {
        let mut v = Vec::with_capacity(4 + cap);
        v.extend_from_slice(&MAGIC);
        v.push(PROTOCOL_VERSION);
        v.push(t as u8);
        Writer(v)
    }
    fn u8(&mut self, v: u8) {
        self.0.push(v);
    }
    fn u16(&mut self, v: u16) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn vec(&mut self, v: &[f64]) {
        self.u32(v.len() as u32);
        for x in v {
            self.f64(*x);
        }
    }
}

struct Reader<'a> {
    b: &'a [u8],
    what: &'static str,
}

fn bad(what: &str, msg: impl std::fmt::Display) -> Error {
    Error::protocol(ErrorCode::BadRequest, format!("{what}: {msg}"))
}

impl<'a> Reader<'a> {
    fn new(bytes: &'a [u8], t: MsgType, what: &'static str) -> Result<Self> {
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
    fn take(&mut self, n: usize) -> Result<&'a [u8]> {
        if self.b.len() < n {
            return Err(bad(self.what, "truncated"));
        }
        let (h, t) = self.b.split_at(n);
        self.b = t;
        Ok(h)
    }
    fn u8(&mut self) -> Result<u8> {
        Ok(self.take(1)?[0])
    }
    fn u16(&mut self) -> Result<u16> {
        Ok(u16::from_le_bytes(
            self.take(2)?.try_into().unwrap_or([0; 2]),
        ))
    }
    fn u32(&mut self) -> Result<u32> {
        Ok(u32::from_le_bytes(
            self.take(4)?.try_into().unwrap_or([0; 4]),
        ))
    }
    fn u64(&mut self) -> Result<u64> {
        Ok(u64::from_le_bytes(
            self.take(8)?.try_into().unwrap_or([0; 8]),
        ))
    }
    fn f64(&mut self) -> Result<f64> {
        Ok(f64::from_le_bytes(
            self.take(8)?.try_into().unwrap_or([0; 8]),
        ))
    }
    fn vec(&mut self) -> Result<Vec<f64>> {
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
    fn finish(self) -> Result<()> {
        if self.b.is_empty() {
            Ok(())
        } else {
            Err(bad(self.what, format!("{} trailing bytes", self.b.len())))
        }
    }
}

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
    /// Encodes: header, `k: u64`, `t: f64`, `n: u32`, `x: n × f64`.
    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer::new(MsgType::StepReply, 20 + 8 * self.x.len());
        w.u64(self.k);
        w.f64(self.t);
        w.vec(&self.x);
        w.0
    }
    /// Decodes and checks the whole payload.
    pub fn decode(b: &[u8]) -> Result<Self> {
        let mut r = Reader::new(b, MsgType::StepReply, "step reply")?;
        let m = StepReply {
            k: r.u64()?,
            t: r.f64()?,
            x: r.vec()?,
        };
        r.finish()?;
        Ok(m)
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
    /// Encodes: header, `len: u16`, model name (UTF-8), `n: u32`, `x`, `m: u32`, `reference`.
    pub fn encode(&self) -> Vec<u8> {
        let name = self.model.as_bytes();
        let mut w = Writer::new(
            MsgType::SolveRequest,
            10 + name.len() + 8 * (self.x.len() + self.reference.len()),
        );
        w.u16(name.len().min(u16::MAX as usize) as u16);
        w.0.extend_from_slice(&name[..name.len().min(u16::MAX as usize)]);
        w.vec(&self.x);
        w.vec(&self.reference);
        w.0
    }
    /// Decodes and checks the whole payload.
    pub fn decode(b: &[u8]) -> Result<Self> {
        let mut r = Reader::new(b, MsgType::SolveRequest, "solve request")?;
        let len = r.u16()? as usize;
        let model = std::str::from_utf8(r.take(len)?)
            .map_err(|_| bad("solve request", "model name is not UTF-8"))?
            .to_string();
        let m = SolveRequest {
            model,
            x: r.vec()?,
            reference: r.vec()?,
        };
        r.finish()?;
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

#[cfg(test)]
mod tests {
    use super::*;

    fn hex(b: &[u8]) -> String {
        b.iter().map(|x| format!("{x:02x}")).collect()
    }

    // Golden vectors: written by hand from the layout in PROTOCOL.md (1.5 = 0x3FF8000000000000,
    // -2.0 = 0xC000000000000000, 0.02 = 0x3F947AE147AE147B), not produced by the encoder.
    #[test]
    fn golden_step_request() {
        let m = StepRequest { k: 3, u: vec![1.5] };
        assert_eq!(
            hex(&m.encode()),
            "4b420101\
             0300000000000000\
             01000000\
             000000000000f83f"
        );
        assert_eq!(StepRequest::decode(&m.encode()).unwrap(), m);
    }

    #[test]
    fn golden_step_reply() {
        let m = StepReply {
            k: 4,
            t: 0.02,
            x: vec![1.5, -2.0],
        };
        assert_eq!(
            hex(&m.encode()),
            "4b420102\
             0400000000000000\
             7b14ae47e17a943f\
             02000000\
             000000000000f83f\
             00000000000000c0"
        );
        assert_eq!(StepReply::decode(&m.encode()).unwrap(), m);
    }

    #[test]
    fn golden_state_and_command() {
        let s = StateMsg {
            seq: 1,
            k: 2,
            t: 0.02,
            x: vec![-2.0],
            u: vec![1.5],
        };
        assert_eq!(
            hex(&s.encode()),
            "4b420103\
             0100000000000000\
             0200000000000000\
             7b14ae47e17a943f\
             01000000\
             00000000000000c0\
             01000000\
             000000000000f83f"
        );
        assert_eq!(StateMsg::decode(&s.encode()).unwrap(), s);
        let c = CommandMsg {
            seq: 7,
            k: 2,
            u: vec![1.5, -2.0],
        };
        assert_eq!(
            hex(&c.encode()),
            "4b420104\
             0700000000000000\
             0200000000000000\
             02000000\
             000000000000f83f\
             00000000000000c0"
        );
        assert_eq!(CommandMsg::decode(&c.encode()).unwrap(), c);
    }

    #[test]
    fn golden_solve() {
        let q = SolveRequest {
            model: "ab".into(),
            x: vec![1.5],
            reference: vec![],
        };
        assert_eq!(
            hex(&q.encode()),
            "4b420105\
             0200\
             6162\
             01000000\
             000000000000f83f\
             00000000"
        );
        assert_eq!(SolveRequest::decode(&q.encode()).unwrap(), q);
        let r = SolveReply {
            status: SolveStatus::Suboptimal,
            iterations: 9,
            solve_time_ns: 256,
            u: vec![-2.0],
        };
        assert_eq!(
            hex(&r.encode()),
            "4b420106\
             01\
             09000000\
             0001000000000000\
             01000000\
             00000000000000c0"
        );
        assert_eq!(SolveReply::decode(&r.encode()).unwrap(), r);
    }

    #[test]
    fn golden_collect_chunk() {
        let m = CollectChunk {
            block: 2,
            chunk: 1,
            chunks: 3,
            first: 8,
            windows: 1,
            steps: 1,
            nx: 1,
            nu: 1,
            x: vec![1.5, -2.0],
            u: vec![0.02],
        };
        assert_eq!(
            hex(&m.encode()),
            "4b420107\
             0200000000000000\
             01000000\
             03000000\
             0800000000000000\
             01000000\
             01000000\
             01000000\
             01000000\
             02000000\
             000000000000f83f\
             00000000000000c0\
             01000000\
             7b14ae47e17a943f"
        );
        assert_eq!(CollectChunk::decode(&m.encode()).unwrap(), m);
        // Inconsistent counts and chunk indices are refused, typed.
        for bad in [
            CollectChunk { nx: 2, ..m.clone() },
            CollectChunk {
                u: vec![],
                ..m.clone()
            },
            CollectChunk {
                chunk: 3,
                ..m.clone()
            },
        ] {
            match CollectChunk::decode(&bad.encode()) {
                Err(Error::Protocol { code, .. }) => assert_eq!(code, ErrorCode::BadRequest),
                other => panic!("expected bad_request, got {other:?}"),
            }
        }
    }

    #[test]
    fn malformed_payloads_give_typed_errors() {
        let good = StepRequest {
            k: 1,
            u: vec![0.5, 0.25],
        }
        .encode();
        let code = |r: Result<StepRequest>| match r {
            Err(Error::Protocol { code, .. }) => code,
            other => panic!("expected a protocol error, got {other:?}"),
        };
        assert_eq!(code(StepRequest::decode(&[])), ErrorCode::BadRequest);
        assert_eq!(
            code(StepRequest::decode(b"{\"k\":1}")),
            ErrorCode::BadRequest
        );
        let mut v = good.clone();
        v[2] = 9;
        assert_eq!(code(StepRequest::decode(&v)), ErrorCode::VersionMismatch);
        let mut v = good.clone();
        v[3] = MsgType::State as u8;
        assert_eq!(code(StepRequest::decode(&v)), ErrorCode::BadRequest);
        for cut in 4..good.len() {
            assert_eq!(
                code(StepRequest::decode(&good[..cut])),
                ErrorCode::BadRequest
            );
        }
        let mut v = good.clone();
        v.push(0);
        assert_eq!(code(StepRequest::decode(&v)), ErrorCode::BadRequest);
        let mut v = good[..12].to_vec();
        v.extend_from_slice(&u32::MAX.to_le_bytes());
        assert_eq!(code(StepRequest::decode(&v)), ErrorCode::TooLarge);
        assert!(SolveReply::decode(&[0x4b, 0x42, 1, 6, 7, 0, 0, 0, 0]).is_err());
    }
}
