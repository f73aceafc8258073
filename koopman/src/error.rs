//! The one error type of the `koopman` crate: every fallible function returns [`Result`].

use std::path::PathBuf;

/// Everything that can go wrong in `koopman`, each with a message a user can act on.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file could not be read or written. The OS message is part of the display text and is
    /// deliberately not also exposed as `source()`, so that `anyhow`'s `{:#}` prints it once.
    #[error("{}: {cause}", path.display())]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The underlying I/O error.
        cause: std::io::Error,
    },
    /// A file exists but its content is not what was expected (truncated, wrong format, ...).
    #[error("{path}: {message}")]
    Format {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
    /// Array or vector sizes that do not fit together.
    #[error("dimension mismatch in {what}: expected {expected}, got {got}")]
    Dimension {
        /// Which quantity has the wrong size.
        what: String,
        /// The size that was expected.
        expected: usize,
        /// The size that was given.
        got: usize,
    },
    /// NaN or infinity where finite numbers are required.
    #[error("non-finite value in {0}")]
    NonFinite(String),
    /// An environment, model kind or other name that is not known.
    #[error("unknown {kind} '{name}' (known: {known})")]
    UnknownName {
        /// What kind of name (environment, model, ...).
        kind: &'static str,
        /// The name that was given.
        name: String,
        /// The accepted names, comma separated.
        known: String,
    },
    /// An argument outside its valid range or an inconsistent configuration.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// A numerical procedure failed (singular matrix, no convergence, infeasible problem, ...).
    #[error("numerical failure: {0}")]
    Numerical(String),
    /// A long computation was stopped on request.
    #[error("cancelled")]
    Cancelled,
}

/// Shorthand for `std::result::Result<T, koopman::Error>`.
pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    /// Wraps an I/O error with the path it concerns.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            cause: source,
        }
    }

    /// A format error for `path` with a message.
    pub fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Error::Format {
            path: path.into(),
            message: message.into(),
        }
    }

    /// A dimension mismatch.
    pub fn dimension(what: impl Into<String>, expected: usize, got: usize) -> Self {
        Error::Dimension {
            what: what.into(),
            expected,
            got,
        }
    }
}

/// Returns an error naming `what` if any value in `values` is NaN or infinite.
pub fn ensure_finite(what: &str, values: &[f64]) -> Result<()> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(Error::NonFinite(what.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn io_error_names_the_path_and_the_os_message_exactly_once_in_the_chain() {
        let os = std::io::Error::new(std::io::ErrorKind::NotFound, "no such file");
        let e = Error::io("data/x.npz", os);
        // Walk the chain as `anyhow`'s `{:#}` does: each level's Display, joined.
        let mut chain = vec![e.to_string()];
        let mut next = std::error::Error::source(&e);
        while let Some(s) = next {
            chain.push(s.to_string());
            next = s.source();
        }
        let full = chain.join(": ");
        assert_eq!(full, "data/x.npz: no such file");
    }
}
