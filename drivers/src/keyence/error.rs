//! The KEYENCE driver's error type.

use crate::error::{DeviceError, ErrorKind};

/// Everything that can go wrong talking to a DL-RS1A.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// No reply within the deadline.
    #[error("no reply to {command} within {timeout_ms} ms")]
    Timeout {
        /// Command.
        command: String,
        /// Deadline (ms).
        timeout_ms: u64,
    },
    /// The serial link failed or closed.
    #[error("serial link lost during {command}: {source}")]
    Disconnected {
        /// Command.
        command: String,
        /// Cause.
        #[source]
        source: std::io::Error,
    },
    /// Opening the port failed.
    #[error("cannot open {path}: {message}")]
    Open {
        /// Port path.
        path: String,
        /// Why.
        message: String,
    },
    /// A reply that does not follow the protocol.
    #[error("malformed reply to {command}: {detail}")]
    Malformed {
        /// Command.
        command: String,
        /// What was wrong.
        detail: String,
    },
    /// `ER,<cmd>,<nn>`.
    #[error("DL-RS1A refused {command}: ER {code:02} ({})", crate::keyence::frame::error_description(*code))]
    Device {
        /// Command.
        command: String,
        /// Error number.
        code: u8,
    },
    /// `+EEE.EE`: the amplifier reports an error state.
    #[error("amplifier {amplifier:02} is in an error state (+EEE.EE)")]
    AmplifierError {
        /// Amplifier index.
        amplifier: usize,
    },
    /// Caller error (no such amplifier in the reply, bad parameter).
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
}

impl DeviceError for Error {
    fn kind(&self) -> ErrorKind {
        match self {
            Error::Timeout { .. } => ErrorKind::Timeout,
            Error::Disconnected { .. } | Error::Open { .. } => ErrorKind::Disconnected,
            Error::Malformed { .. } => ErrorKind::Protocol,
            Error::Device { .. } | Error::AmplifierError { .. } => ErrorKind::DeviceRejected,
            Error::InvalidArgument(_) => ErrorKind::InvalidArgument,
        }
    }
}

impl crate::link::FromLinkError for Error {
    fn timeout(command: String, timeout_ms: u64) -> Self {
        Error::Timeout {
            command,
            timeout_ms,
        }
    }
    fn disconnected(command: String, source: std::io::Error) -> Self {
        Error::Disconnected { command, source }
    }
}
