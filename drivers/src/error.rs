//! The shared error vocabulary of every device.
//!
//! Each device family has its own `thiserror` enum (e.g. `rtde::Error`, `bcap::Error`) with
//! named fields; each implements [`DeviceError`] so that the acquisition engine can decide
//! retry / skip / abort from the [`ErrorKind`] alone. Trait methods return [`DriverError`],
//! which keeps the kind, the device name, a message and the original error as its source.

use std::fmt;

/// What kind of failure a device error is, independent of the vendor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub enum ErrorKind {
    /// No answer within the deadline (request or stream). Usually worth a retry.
    Timeout,
    /// The link broke (connection reset, closed, serial port gone). Reconnect, then retry.
    Disconnected,
    /// Bytes that do not follow the protocol (bad CRC, bad frame, unexpected reply).
    Protocol,
    /// A valid answer in which the device said no (error code, `ER` reply, HRESULT).
    DeviceRejected,
    /// The quantity is outside the sensor's range (laser window, tracker volume).
    OutOfRange,
    /// The tracked tool is not visible / missing in this frame.
    NotVisible,
    /// The arm is in a protective or emergency stop.
    SafetyStop,
    /// A safety wrapper refused the command before it reached the device.
    SafetyViolation,
    /// The caller asked for something invalid (wrong joint count, NaN target).
    InvalidArgument,
    /// The device or driver does not support this operation.
    Unsupported,
    /// Anything else.
    Other,
}

impl ErrorKind {
    /// Whether repeating the same request (after a reconnect for `Disconnected`) may succeed.
    pub fn is_transient(self) -> bool {
        matches!(
            self,
            ErrorKind::Timeout
                | ErrorKind::Disconnected
                | ErrorKind::Protocol
                | ErrorKind::NotVisible
        )
    }
    /// Whether the link itself is in doubt (reconnect before retrying).
    pub fn needs_reconnect(self) -> bool {
        matches!(self, ErrorKind::Disconnected | ErrorKind::Timeout)
    }
}

impl fmt::Display for ErrorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = match self {
            ErrorKind::Timeout => "timeout",
            ErrorKind::Disconnected => "disconnected",
            ErrorKind::Protocol => "protocol",
            ErrorKind::DeviceRejected => "device-rejected",
            ErrorKind::OutOfRange => "out-of-range",
            ErrorKind::NotVisible => "not-visible",
            ErrorKind::SafetyStop => "safety-stop",
            ErrorKind::SafetyViolation => "safety-violation",
            ErrorKind::InvalidArgument => "invalid-argument",
            ErrorKind::Unsupported => "unsupported",
            ErrorKind::Other => "other",
        };
        f.write_str(s)
    }
}

/// Implemented by every device-specific error enum.
pub trait DeviceError: std::error::Error + Send + Sync + 'static {
    /// The vendor-independent kind of this error.
    fn kind(&self) -> ErrorKind;
}

/// The error every capability trait returns.
#[derive(Debug)]
pub struct DriverError {
    /// Vendor-independent kind.
    pub kind: ErrorKind,
    /// Which device (e.g. `ur5e@127.0.0.1:30004`).
    pub device: String,
    /// Human message.
    pub message: String,
    /// The device-specific error, when there is one.
    pub source: Option<Box<dyn std::error::Error + Send + Sync + 'static>>,
}

impl DriverError {
    /// A new error without a source.
    pub fn new(kind: ErrorKind, device: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            kind,
            device: device.into(),
            message: message.into(),
            source: None,
        }
    }
    /// Wrap a device-specific error, keeping its kind.
    pub fn from_device<E: DeviceError>(device: impl Into<String>, err: E) -> Self {
        Self {
            kind: err.kind(),
            device: device.into(),
            message: err.to_string(),
            source: Some(Box::new(err)),
        }
    }
    /// The vendor-independent kind.
    pub fn kind(&self) -> ErrorKind {
        self.kind
    }
}

impl fmt::Display for DriverError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} ({}): {}", self.device, self.kind, self.message)
    }
}

impl std::error::Error for DriverError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        self.source
            .as_deref()
            .map(|e| e as &(dyn std::error::Error + 'static))
    }
}

/// Result of every capability-trait call.
pub type DriverResult<T> = Result<T, DriverError>;
