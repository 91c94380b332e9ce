//! The NDI driver's error type.

use crate::error::{DeviceError, ErrorKind};

/// Everything that can go wrong talking to an NDI tracker.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// No complete reply within the deadline.
    #[error("no reply to `{command}` within {timeout_ms} ms")]
    Timeout {
        /// The command (without CRC).
        command: String,
        /// The deadline (ms).
        timeout_ms: u64,
    },
    /// The link closed or failed.
    #[error("link lost during `{command}`: {source}")]
    Disconnected {
        /// The command in flight.
        command: String,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// Opening the link failed.
    #[error("cannot open {target}: {message}")]
    Open {
        /// Address or serial path.
        target: String,
        /// Why.
        message: String,
    },
    /// A reply whose CRC does not match.
    #[error("bad reply CRC to `{command}`: sent {sent:04X}, computed {computed:04X}")]
    BadCrc {
        /// The command.
        command: String,
        /// CRC found on the wire.
        sent: u16,
        /// CRC of the bytes received.
        computed: u16,
    },
    /// Bytes that do not follow the protocol.
    #[error("malformed reply to `{command}`: {detail}")]
    Malformed {
        /// The command.
        command: String,
        /// What was wrong.
        detail: String,
    },
    /// The device answered `ERRORxx`.
    #[error("device refused `{command}`: ERROR{code:02X} ({})", crate::ndi::frame::error_description(*code))]
    Device {
        /// The command.
        command: String,
        /// NDI error code.
        code: u8,
    },
    /// A caller error (bad ROM size, unknown tool).
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
}

impl DeviceError for Error {
    fn kind(&self) -> ErrorKind {
        match self {
            Error::Timeout { .. } => ErrorKind::Timeout,
            Error::Disconnected { .. } | Error::Open { .. } => ErrorKind::Disconnected,
            Error::BadCrc { .. } | Error::Malformed { .. } => ErrorKind::Protocol,
            Error::Device { .. } => ErrorKind::DeviceRejected,
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
