//! Compact little-endian binary codec of the hot-path messages (step, state, command, solve,
//! collect chunks), each framed by the magic `KB`, the protocol version and a message type byte.

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
    /// [`SolveRequest`] with a feed-forward (its own type, so that no prefix of it is a valid
    /// request without one).
    SolveRequestFeedforward = 0x08,
    /// [`StepReply`] with a non-empty [`StepStatus`] (its own type, so that a peer that knows
    /// only `0x02` refuses it by its type instead of misreading it).
    StepReplyStatus = 0x09,
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
    /// What the simulator says about this step (an episode end, a clipped input); empty for a
    /// `reset` reply and for simulators that report nothing. On the wire a reply with a
    /// non-empty status has type `0x09` and a `u8` after `x`; one without it is the original
    /// `0x02` layout.
    pub status: StepStatus,
}

/// The status a simulator reports with a step: a set of flags (PROTOCOL.md §4, `0x09`). The
/// simulator keeps stepping whatever it says; what to do about it is the caller's choice.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct StepStatus(u8);

impl StepStatus {
    /// No flag: the plain step reply.
    pub const EMPTY: StepStatus = StepStatus(0);
    /// Bit 0: the simulator's task says the episode has ended at this state (a fall, a
    /// Gymnasium `terminated`). Set on every step while it holds.
    pub const TERMINATED: StepStatus = StepStatus(1);
    /// Bit 1: the episode was cut by a limit outside the task (a Gymnasium time limit,
    /// `truncated`).
    pub const TRUNCATED: StepStatus = StepStatus(2);
    /// Bit 2: the simulator clipped the input of this step into its bounds before applying it.
    pub const CLIPPED: StepStatus = StepStatus(4);
    /// Every bit this protocol version defines; the others must be 0.
    pub const KNOWN_BITS: u8 = 0b111;

    /// The status with exactly the given flags.
    pub fn new(terminated: bool, truncated: bool, clipped: bool) -> Self {
        StepStatus(u8::from(terminated) | u8::from(truncated) << 1 | u8::from(clipped) << 2)
    }
    /// The status of the wire byte `b`; `None` when a bit outside [`Self::KNOWN_BITS`] is set.
    pub fn from_bits(b: u8) -> Option<Self> {
        (b & !Self::KNOWN_BITS == 0).then_some(StepStatus(b))
    }
    /// The wire byte.
    pub fn bits(self) -> u8 {
        self.0
    }
    /// No flag set.
    pub fn is_empty(self) -> bool {
        self.0 == 0
    }
    /// The flags set in `self` or in `other`.
    pub fn union(self, other: StepStatus) -> Self {
        StepStatus(self.0 | other.0)
    }
    /// Every flag of `other` is set in `self`.
    pub fn contains(self, other: StepStatus) -> bool {
        self.0 & other.0 == other.0
    }
    /// The episode has ended at this state ([`Self::TERMINATED`]).
    pub fn terminated(self) -> bool {
        self.contains(Self::TERMINATED)
    }
    /// The episode was cut by a limit ([`Self::TRUNCATED`]).
    pub fn truncated(self) -> bool {
        self.contains(Self::TRUNCATED)
    }
    /// The input was clipped ([`Self::CLIPPED`]).
    pub fn clipped(self) -> bool {
        self.contains(Self::CLIPPED)
    }
    /// The names of the set flags (`terminated`, `truncated`, `clipped`), in bit order.
    pub fn names(self) -> Vec<&'static str> {
        [
            (self.terminated(), "terminated"),
            (self.truncated(), "truncated"),
            (self.clipped(), "clipped"),
        ]
        .into_iter()
        .filter_map(|(on, n)| on.then_some(n))
        .collect()
    }
}

impl std::ops::BitOr for StepStatus {
    type Output = StepStatus;
    fn bitor(self, rhs: StepStatus) -> StepStatus {
        StepStatus(self.0 | rhs.0)
    }
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
    /// Reference: one state (`nx`) or a stacked horizon (`H·nx`); with a `feedforward`, the
    /// planned state at the current step (`nx`).
    pub reference: Vec<f64>,
    /// The plan's feed-forward inputs at the current and the next H−1 steps (`H·nu`), or empty.
    /// When given, the service plans the deviation from them (error-state MPC: the model's own
    /// rollout of the plan is the reference, so its bias along the plan cancels). On the wire a
    /// request with one has type `0x08` and the vector after `reference`; one without it is the
    /// original `0x05` layout.
    pub feedforward: Vec<f64>,
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

mod frame;
mod messages;
#[cfg(test)]
mod tests;
