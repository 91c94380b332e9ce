//! Error types of the kinematic model and its inverse kinematics.
use thiserror::Error;

/// What can go wrong building or editing a [`super::KinematicModel`].
#[derive(Debug, Error, Clone, PartialEq)]
#[non_exhaustive]
pub enum ModelError {
    /// `preset(name)` with a name that is not built in.
    #[error("unknown robot preset `{name}` (known: denso-vs060, ur5e, ur10e)")]
    UnknownPreset { name: String },
    /// A chain without any movable joint.
    #[error("the kinematic chain has no movable joint")]
    EmptyChain,
    /// A joint whose numbers cannot describe a revolute joint.
    #[error("joint `{joint}`: {reason}")]
    InvalidJoint { joint: String, reason: String },
    /// URDF text that does not parse.
    #[error("URDF parse error: {message}")]
    Urdf { message: String },
    /// A link named as base or tip that the URDF does not have.
    #[error("URDF link `{link}` not found")]
    UrdfLinkNotFound { link: String },
    /// No joint path leads from the base link to the tip link.
    #[error("no joint path from `{base}` to `{tip}` in the URDF")]
    UrdfNoPath { base: String, tip: String },
    /// Only revolute, continuous and fixed joints are modelled.
    #[error("joint `{joint}` is of unsupported type {kind}")]
    UnsupportedJoint { joint: String, kind: String },
    /// A parameter name the model does not have.
    #[error("unknown model parameter `{name}`")]
    UnknownParam { name: String },
    /// A calibration parameter given in a unit that does not fit its quantity.
    #[error("parameter `{name}`: unit `{unit}` is not valid (expected {expected})")]
    BadUnit {
        name: String,
        unit: String,
        expected: String,
    },
    /// NaN or infinite number where a finite one is needed.
    #[error("parameter `{name}` is not finite")]
    NonFinite { name: String },
    /// A vector with the wrong number of entries.
    #[error("expected {expected} values, got {got}")]
    LengthMismatch { expected: usize, got: usize },
}

/// What can go wrong in inverse kinematics. Never NaN: a failure is one of these.
#[derive(Debug, Error, Clone, PartialEq)]
#[non_exhaustive]
pub enum IkError {
    /// The target is outside the workspace of every branch.
    #[error("target at [{x_mm:.3}, {y_mm:.3}, {z_mm:.3}] mm is unreachable: {reason}")]
    Unreachable {
        x_mm: f64,
        y_mm: f64,
        z_mm: f64,
        reason: String,
    },
    /// The target pose contains NaN or infinite numbers.
    #[error("target pose is not finite")]
    NonFiniteTarget,
    /// The model's geometry matches no built-in closed-form family (VS060, UR).
    #[error("no closed-form inverse kinematics for this {dof}-axis geometry")]
    NoClosedForm { dof: usize },
    /// Newton refinement on the calibrated model did not reach the tolerance on any branch.
    #[error("IK refinement did not converge (best: {pos_err_mm:.3e} mm, {rot_err_deg:.3e} deg)")]
    NotConverged { pos_err_mm: f64, rot_err_deg: f64 },
}
