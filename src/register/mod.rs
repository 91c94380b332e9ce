//! Navigation registrations (seed 003, see docs/seeds.md): CT ↔ tracker from paired fiducials
//! (closed form, FRE / FLE / predicted TRE) or from a surface (trimmed point-to-plane ICP,
//! multi-start), tracker ↔ robot base from `AX = YB` (Shah, Li, the seed's Tsai route, joint
//! LM refinement), and the tracker's own stereo error model (depth error ∝ z²).
//!
//! Units inside: mm and radians. Files: mm and degrees (`registration.json`,
//! `robot_world.json`, CSV `name,x_mm,y_mm,z_mm`).
//!
//! The end-to-end error transfer to a CT target lives in [`crate::navchain`].

pub mod check;
pub mod file;
pub mod from_files;
pub mod icp;
pub mod mesh;
pub mod paired;
pub mod points;
pub mod robot_world;
pub mod run;
pub mod tracker_model;

pub use file::{RegistrationFile, REGISTRATION_FORMAT};
pub use paired::{register_paired, PairedOptions, PairedRegistration};
pub use points::{read_points_csv, write_points_csv, NamedPoint};
pub use tracker_model::StereoTrackerModel;

/// Errors of the registration code: each names the file / point / field and a likely cause.
#[derive(Debug, thiserror::Error)]
pub enum RegisterError {
    /// Bad input file content (file, line, message).
    #[error("{file}:{line}: {msg}")]
    Input {
        file: String,
        line: usize,
        msg: String,
    },
    /// The data cannot determine the transform (collinear, too few points, ...).
    #[error("degenerate registration: {0}")]
    Degenerate(String),
    /// The inputs are inconsistent (names, units, outliers).
    #[error("{0}")]
    Invalid(String),
    /// The solver did not converge.
    #[error("solver: {0}")]
    Solver(String),
    /// File I/O.
    #[error("{path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
}

pub(crate) fn io_err(path: &std::path::Path, source: std::io::Error) -> RegisterError {
    RegisterError::Io {
        path: path.display().to_string(),
        source,
    }
}

pub use crate::solve::so3::{left_jacobian as so3_left_jacobian, skew};
