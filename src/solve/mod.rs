//! Identification: the nominal fit (base + tool only), full kinematic identification
//! (MDH + Hayati, base, tool) with automatic identifiability, robust loss, covariance,
//! bootstrap over random subsets (seed 001 §4.3), tool calibrations (pivot, guide tool,
//! tool with the identified arm) and the accuracy metrics of seed 001 §3.
//!
//! **Units inside: millimetres and radians.** Files use mm and degrees; the conversion
//! happens where a [`crate::dataset::CalibrationFile`] is written or read.
//!
//! Every calibration is a pure problem object ([`lm::LsqProblem`]: parameters, residuals,
//! analytic Jacobian) whose Jacobian is tested against finite differences.

pub mod axxb;
pub mod bootstrap;
pub mod calfile;
pub mod camera;
pub mod correct;
pub mod identifiability;
pub mod inference;
pub mod kinematics;
pub mod laser;
pub mod lm;
pub mod metrics;
pub mod nominal;
pub mod obs;
pub mod pivot_robust;
pub mod predict;
pub mod rcm;
pub mod rigid;
pub mod so3;
pub mod stats;
pub mod tool;
pub mod tool_boot;

pub use obs::PoseObs;

/// Errors of the identification code.
#[derive(Debug, thiserror::Error)]
pub enum SolveError {
    /// Not enough usable data for the requested fit.
    #[error("{what}: need at least {need} usable measurements, got {got}")]
    TooFewData {
        what: String,
        need: usize,
        got: usize,
    },
    /// The data cannot determine the unknowns (collinear points, no rotation, ...).
    #[error("degenerate data: {0}")]
    Degenerate(String),
    /// The kinematic model could not be built or updated.
    #[error("model: {0}")]
    Model(#[from] crate::model::ModelError),
    /// The solver failed (non-finite values, no convergence).
    #[error("solver: {0}")]
    Solver(String),
    /// Invalid input or option.
    #[error("{0}")]
    Invalid(String),
}
