//! `bridge` — everything Zenoh in koopbridge: key expressions, messages and their codec, the
//! services (trainer, model store, MPC, recorder), the lockstep/free-run orchestrator and a client.
//!
//! - [`session`]: opening a Zenoh session from CLI options;
//! - [`keyexpr`]: the protocol's key expressions;
//! - [`codec`]: binary hot-path messages; [`messages`]: JSON control-plane messages;
//! - [`adapter`]: the simulator side of the protocol (`SimBackend` + `serve`);
//! - [`client`]: queries with typed errors, liveliness tracking, simulator client.

pub mod adapter;
pub mod client;
pub mod codec;
pub mod collect;
pub mod error;
pub mod fsutil;
pub mod keyexpr;
pub mod messages;
pub mod orchestrator;
pub mod priority;
pub mod procs;
pub mod scenario;
pub mod services;
pub mod session;
pub mod sweep;

pub use error::{Error, ErrorCode, ErrorReply, Result};
pub use zenoh;
