//! The error type of the `bridge` crate and the typed error codes that travel in error replies.

use serde::{Deserialize, Serialize};

/// Machine-readable error code carried by every error reply (JSON `{"code": …, "message": …}`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ErrorCode {
    /// The payload could not be decoded (wrong magic, truncated, bad JSON, ...).
    BadRequest,
    /// The payload was encoded with another protocol version.
    VersionMismatch,
    /// The payload is larger than the service accepts.
    TooLarge,
    /// A vector has the wrong length (e.g. `u` with the wrong `nu`).
    Dimension,
    /// A step request whose `k` is neither the next step nor a cached one.
    OutOfOrder,
    /// A retried step `k` with a different input than the one already applied.
    Conflict,
    /// The simulator itself failed (diverged, non-finite state, backend error).
    SimFailure,
    /// The named object (model, job, dataset) does not exist.
    NotFound,
    /// The service is at its concurrency limit or in a mode that forbids the request.
    Busy,
    /// The request is valid but not supported by this participant.
    Unsupported,
    /// The request names something this participant may not touch (e.g. a dataset path outside
    /// the trainer's data root); the message names no file.
    Forbidden,
    /// A planner found no trajectory (the message names the pass and each solver's status).
    Infeasible,
    /// An unexpected failure inside the service.
    Internal,
}

impl std::fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = serde_json::to_value(self)
            .ok()
            .and_then(|v| v.as_str().map(str::to_owned))
            .unwrap_or_else(|| format!("{self:?}"));
        f.write_str(&s)
    }
}

/// The body of every error reply: a code and a human-readable message.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ErrorReply {
    /// What kind of error.
    pub code: ErrorCode,
    /// What went wrong, for a human.
    pub message: String,
}

impl ErrorReply {
    /// A new error reply.
    pub fn new(code: ErrorCode, message: impl Into<String>) -> Self {
        ErrorReply {
            code,
            message: message.into(),
        }
    }

    /// The JSON bytes sent with `reply_err`.
    pub fn to_json(&self) -> Vec<u8> {
        serde_json::to_vec(self).unwrap_or_else(|_| b"{\"code\":\"internal\"}".to_vec())
    }

    /// Parses an error reply body; anything unparseable becomes an `internal` error quoting it.
    pub fn from_json(bytes: &[u8]) -> Self {
        serde_json::from_slice(bytes).unwrap_or_else(|_| {
            ErrorReply::new(
                ErrorCode::Internal,
                format!(
                    "unparseable error reply: {}",
                    String::from_utf8_lossy(&bytes[..bytes.len().min(200)])
                ),
            )
        })
    }
}

/// Everything that can go wrong in `bridge`.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Zenoh itself failed (session, declaration, transport).
    #[error("zenoh: {0}")]
    Zenoh(String),
    /// A remote participant answered with a typed error.
    #[error("{who} replied {}: {}", .reply.code, .reply.message)]
    Remote {
        /// Which participant (key expression or name).
        who: String,
        /// The error it sent.
        reply: ErrorReply,
    },
    /// A payload could not be decoded or is inconsistent.
    #[error("{code}: {message}")]
    Protocol {
        /// The code an error reply would carry.
        code: ErrorCode,
        /// What is wrong.
        message: String,
    },
    /// A participant did not answer in time.
    #[error("timeout after {after_ms} ms waiting for {who} ({what})")]
    Timeout {
        /// Which participant.
        who: String,
        /// What was asked.
        what: String,
        /// How long we waited.
        after_ms: u64,
    },
    /// A participant's liveliness token disappeared (it died or left).
    #[error("{0} is gone (its liveliness token disappeared)")]
    Gone(String),
    /// A configuration or scenario problem.
    #[error("configuration: {0}")]
    Config(String),
    /// An error from the mathematics crate.
    #[error(transparent)]
    Koopman(#[from] koopman::Error),
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file concerned.
        path: std::path::PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// The operation was stopped on request.
    #[error("stopped")]
    Stopped,
}

/// Shorthand for `std::result::Result<T, bridge::Error>`.
pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    /// A protocol (decode/validation) error.
    pub fn protocol(code: ErrorCode, message: impl Into<String>) -> Self {
        Error::Protocol {
            code,
            message: message.into(),
        }
    }

    /// Wraps any Zenoh error.
    pub fn zenoh(e: impl std::fmt::Display) -> Self {
        Error::Zenoh(e.to_string())
    }

    /// The error reply a service sends for this error.
    pub fn to_reply(&self) -> ErrorReply {
        match self {
            Error::Protocol { code, message } => ErrorReply::new(*code, message.clone()),
            Error::Remote { reply, .. } => reply.clone(),
            Error::Koopman(e) => {
                let code = match e {
                    koopman::Error::Dimension { .. } => ErrorCode::Dimension,
                    koopman::Error::UnknownName { .. } => ErrorCode::NotFound,
                    koopman::Error::InvalidArgument(_) | koopman::Error::NonFinite(_) => {
                        ErrorCode::BadRequest
                    }
                    _ => ErrorCode::Internal,
                };
                ErrorReply::new(code, e.to_string())
            }
            other => ErrorReply::new(ErrorCode::Internal, other.to_string()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_code_round_trips_through_its_snake_case_name() {
        for (code, name) in [
            (ErrorCode::Forbidden, "forbidden"),
            (ErrorCode::Infeasible, "infeasible"),
            (ErrorCode::SimFailure, "sim_failure"),
        ] {
            assert_eq!(code.to_string(), name);
            let body = format!(r#"{{"code":"{name}","message":"m"}}"#);
            assert_eq!(ErrorReply::from_json(body.as_bytes()).code, code);
        }
        // An unknown code is still an internal error quoting the body.
        let r = ErrorReply::from_json(br#"{"code":"nope","message":"m"}"#);
        assert_eq!(r.code, ErrorCode::Internal);
        assert!(r.message.contains("nope"), "{}", r.message);
    }
}
