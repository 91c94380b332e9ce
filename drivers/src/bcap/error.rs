//! The b-CAP driver's error enum.

use super::frame::hresult;
use crate::error::{DeviceError, ErrorKind};

/// Everything that can go wrong talking b-CAP. A negative HRESULT is the controller saying
/// no ([`BcapError::Hresult`]); it is kept apart from link failures.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BcapError {
    /// Could not open the connection.
    #[error("b-CAP: cannot connect to {addr}: {source}")]
    Connect {
        /// Address tried.
        addr: String,
        /// OS error.
        source: std::io::Error,
    },
    /// The link closed or failed.
    #[error("b-CAP: link broke: {detail}")]
    Disconnected {
        /// What happened.
        detail: String,
    },
    /// No reply within the deadline.
    #[error("b-CAP: no reply to {what} within {secs:.3} s")]
    Timeout {
        /// The request.
        what: String,
        /// Deadline (s).
        secs: f64,
    },
    /// Bytes that break the protocol, or a reply of the wrong shape.
    #[error("b-CAP: protocol error: {detail}")]
    Protocol {
        /// What is wrong.
        detail: String,
    },
    /// The controller answered with a failure HRESULT.
    #[error("b-CAP: {function} failed with HRESULT 0x{code:08x} ({name})", code = *.code as u32, name = hresult::name(*.code))]
    Hresult {
        /// The function / command.
        function: String,
        /// The HRESULT.
        code: i32,
    },
    /// Invalid request from the caller.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
}

impl DeviceError for BcapError {
    fn kind(&self) -> ErrorKind {
        match self {
            BcapError::Connect { .. } | BcapError::Disconnected { .. } => ErrorKind::Disconnected,
            BcapError::Timeout { .. } => ErrorKind::Timeout,
            BcapError::Protocol { .. } => ErrorKind::Protocol,
            BcapError::Hresult { code, .. } => match *code {
                hresult::E_TIMEOUT => ErrorKind::Timeout,
                hresult::E_SIM_PROTECTIVE_STOP => ErrorKind::SafetyStop,
                _ => ErrorKind::DeviceRejected,
            },
            BcapError::InvalidArgument(_) => ErrorKind::InvalidArgument,
        }
    }
}

impl BcapError {
    /// The HRESULT, when the controller refused.
    pub fn hresult(&self) -> Option<i32> {
        match self {
            BcapError::Hresult { code, .. } => Some(*code),
            _ => None,
        }
    }
}
