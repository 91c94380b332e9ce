//! The UR driver's error enum.

use crate::error::{DeviceError, ErrorKind};

/// Which UR interface an error came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Interface {
    /// RTDE (30004).
    Rtde,
    /// Dashboard server (29999).
    Dashboard,
    /// Script interface (30003 / 30001 / 30002).
    Script,
}

impl std::fmt::Display for Interface {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Interface::Rtde => "RTDE",
            Interface::Dashboard => "dashboard",
            Interface::Script => "script interface",
        })
    }
}

/// Everything that can go wrong talking to a UR controller.
///
/// "The controller said no" ([`UrError::Rejected`], [`UrError::UnknownVariable`],
/// [`UrError::MoveAborted`]) is kept apart from "the link broke" ([`UrError::Disconnected`],
/// [`UrError::Timeout`], [`UrError::Protocol`]).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum UrError {
    /// Could not open the TCP connection.
    #[error("{interface}: cannot connect to {addr}: {source}")]
    Connect {
        /// Interface.
        interface: Interface,
        /// Address tried.
        addr: String,
        /// OS error.
        source: std::io::Error,
    },
    /// The connection closed or failed mid-session.
    #[error("{interface}: link broke: {detail}")]
    Disconnected {
        /// Interface.
        interface: Interface,
        /// What happened.
        detail: String,
    },
    /// No answer (or no stream sample) within the deadline.
    #[error("{interface}: no answer within {secs:.3} s while {what}")]
    Timeout {
        /// Interface.
        interface: Interface,
        /// What the client was waiting for.
        what: String,
        /// The deadline (s).
        secs: f64,
    },
    /// Bytes that break the protocol.
    #[error("{interface}: protocol error: {detail}")]
    Protocol {
        /// Interface.
        interface: Interface,
        /// What is wrong.
        detail: String,
    },
    /// A well-formed refusal from the controller.
    #[error("{interface}: controller refused `{what}`: {reply}")]
    Rejected {
        /// Interface.
        interface: Interface,
        /// The request.
        what: String,
        /// The controller's answer.
        reply: String,
    },
    /// An RTDE variable the controller does not know or will not share.
    #[error("RTDE: controller answered {answer} for variable `{name}`")]
    UnknownVariable {
        /// The variable.
        name: String,
        /// `NOT_FOUND` / `IN_USE`.
        answer: String,
    },
    /// The arm is in a protective / emergency stop.
    #[error("arm is in safety mode {safety_mode} ({name})")]
    SafetyStop {
        /// RTDE safety_mode integer.
        safety_mode: i32,
        /// Its name.
        name: &'static str,
    },
    /// The motion program ended before the arm reached the target.
    #[error("move aborted: {detail}")]
    MoveAborted {
        /// What was observed.
        detail: String,
    },
    /// The arm is not in a state that accepts motion (powered off, brakes on).
    #[error("arm not ready for motion: robot_mode {robot_mode}")]
    NotReady {
        /// RTDE robot_mode integer.
        robot_mode: i32,
    },
    /// Invalid request from the caller.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
}

impl DeviceError for UrError {
    fn kind(&self) -> ErrorKind {
        match self {
            UrError::Connect { .. } | UrError::Disconnected { .. } => ErrorKind::Disconnected,
            UrError::Timeout { .. } => ErrorKind::Timeout,
            UrError::Protocol { .. } => ErrorKind::Protocol,
            UrError::Rejected { .. }
            | UrError::UnknownVariable { .. }
            | UrError::MoveAborted { .. }
            | UrError::NotReady { .. } => ErrorKind::DeviceRejected,
            UrError::SafetyStop { .. } => ErrorKind::SafetyStop,
            UrError::InvalidArgument(_) => ErrorKind::InvalidArgument,
        }
    }
}

impl UrError {
    pub(crate) fn io(interface: Interface, e: std::io::Error) -> Self {
        use std::io::ErrorKind as K;
        match e.kind() {
            K::TimedOut | K::WouldBlock => UrError::Timeout {
                interface,
                what: e.to_string(),
                secs: 0.0,
            },
            _ => UrError::Disconnected {
                interface,
                detail: e.to_string(),
            },
        }
    }
}
