//! The library's error type: every failure names the file, frame or parameter it is about.

use std::path::PathBuf;

/// Errors returned by the depthmesh library.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file could not be opened, read or written.
    #[error("{path}: {error}")]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The underlying I/O error (shown in the message, so not chained as a source).
        error: std::io::Error,
    },
    /// A file was read but its content is not what it should be.
    #[error("{path}: {message}")]
    Format {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong, with a line or element number where one is known.
        message: String,
    },
    /// A parameter has a value that makes no sense.
    #[error("invalid {name}: {message}")]
    Parameter {
        /// The parameter (or flag) name.
        name: String,
        /// Why the value is rejected.
        message: String,
    },
    /// A compressed depth stream is truncated, corrupt or over its size limit.
    #[error("{codec} stream: {message}")]
    Codec {
        /// The codec whose stream it is (`rvl`, `png`, ...).
        codec: &'static str,
        /// What is wrong, with the byte offset or pixel count where one is known.
        message: String,
    },
}

impl Error {
    /// An I/O error about `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            error: source,
        }
    }

    /// A format error about `path`.
    pub fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Error::Format {
            path: path.into(),
            message: message.into(),
        }
    }

    /// A rejected parameter value.
    pub fn parameter(name: impl Into<String>, message: impl Into<String>) -> Self {
        Error::Parameter {
            name: name.into(),
            message: message.into(),
        }
    }

    /// A bad stream of the named codec.
    pub fn codec(codec: &'static str, message: impl Into<String>) -> Self {
        Error::Codec {
            codec,
            message: message.into(),
        }
    }
}

/// Result with the library's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;
