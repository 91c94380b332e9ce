//! NDI Optotrak Certus through NDI's proprietary OAPI library, loaded at run time.
//!
//! The host-to-System-Control-Unit protocol of the Certus is not published; the only way to
//! talk to one is NDI's Optotrak Application Programmer's Interface (OAPI, `liboapi.so`),
//! which is not redistributable. With feature `optotrak` this module loads it at run time
//! (`libloading`) and drives the usual OAPI sequence:
//!
//! ```text
//! TransputerLoadSystem("system") -> TransputerInitializeSystem(0)
//! OptotrakLoadCameraParameters("standard")
//! RigidBodyAddFromFile(id, start marker, ".rig" file, quaternion flag)
//! OptotrakSetupCollection(...) -> OptotrakActivateMarkers()
//! DataGetLatestTransforms(&frame, &elements, &flags, buffer)   (per frame)
//! OptotrakDeActivateMarkers() -> TransputerShutdownSystem()
//! ```
//!
//! **Honesty note:** this code has never run against the real library or a Certus: the
//! library is not available to the project. The function names come from NDI's OAPI guide
//! (IL-1070086); the C signatures, the rigid-body flag value and the transform record layout
//! are written from that guide's sample code and are **unverified** here. Without the
//! library (or without the feature) every call fails with a clear
//! [`ErrorKind::Unsupported`](crate::ErrorKind::Unsupported) error naming what was tried.

use crate::error::{DeviceError, ErrorKind};

/// Errors of the Optotrak driver.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The crate was built without feature `optotrak`.
    #[error("Optotrak support is not compiled in: rebuild robocal with `--features robocal-drivers/optotrak` and install NDI's OAPI library (liboapi.so)")]
    NotCompiled,
    /// NDI's OAPI library could not be loaded.
    #[error("NDI's Optotrak OAPI library could not be loaded (tried {tried:?}): {message}. It is proprietary and not shipped with robocal; install NDI's ToolBench/OAPI and point `library` at liboapi.so")]
    LibraryMissing {
        /// Paths / names tried.
        tried: Vec<String>,
        /// Loader message for the last attempt.
        message: String,
    },
    /// The library lacks a function.
    #[error("OAPI library has no symbol `{0}`")]
    MissingSymbol(String),
    /// An OAPI call returned an error.
    #[error("OAPI {call} failed: {message}")]
    Call {
        /// Function.
        call: String,
        /// `OptotrakGetErrorString` text.
        message: String,
    },
}

impl DeviceError for Error {
    fn kind(&self) -> ErrorKind {
        match self {
            Error::NotCompiled | Error::LibraryMissing { .. } | Error::MissingSymbol(_) => {
                ErrorKind::Unsupported
            }
            Error::Call { .. } => ErrorKind::DeviceRejected,
        }
    }
}

/// Where to find the library and the system files.
#[derive(Debug, Clone)]
pub struct OptotrakConfig {
    /// Library path or name; `None` tries `liboapi.so` then `oapi.so` on the loader path.
    pub library: Option<String>,
    /// `.nif` system file name given to `TransputerLoadSystem` (default `system`).
    pub system_file: String,
    /// Camera parameter file (default `standard`).
    pub camera_file: String,
    /// Rigid-body files (`.rig`), one per tool, with the number of markers each uses.
    pub rigid_bodies: Vec<(String, u32)>,
    /// Frame rate (Hz).
    pub frame_hz: f32,
}

impl Default for OptotrakConfig {
    fn default() -> Self {
        Self {
            library: None,
            system_file: "system".into(),
            camera_file: "standard".into(),
            rigid_bodies: Vec::new(),
            frame_hz: 50.0,
        }
    }
}

/// Library names tried when no path is configured.
pub const DEFAULT_LIBRARIES: [&str; 2] = ["liboapi.so", "oapi.so"];

#[cfg(feature = "optotrak")]
mod oapi;
#[cfg(feature = "optotrak")]
pub use oapi::Optotrak;

/// Without feature `optotrak`: a stub whose constructor explains what is missing.
#[cfg(not(feature = "optotrak"))]
#[derive(Debug)]
pub struct Optotrak {
    _private: (),
}

#[cfg(not(feature = "optotrak"))]
impl Optotrak {
    /// Always [`Error::NotCompiled`].
    pub fn open(_config: &OptotrakConfig) -> Result<Self, Error> {
        Err(Error::NotCompiled)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn absent_library_gives_a_clear_unsupported_error() {
        let cfg = OptotrakConfig {
            library: Some("/nonexistent/liboapi.so".into()),
            ..OptotrakConfig::default()
        };
        let err = Optotrak::open(&cfg).unwrap_err();
        assert_eq!(err.kind(), ErrorKind::Unsupported);
        let msg = err.to_string();
        assert!(msg.contains("OAPI") || msg.contains("optotrak"), "{msg}");
    }
}
