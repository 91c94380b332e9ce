//! The diagnosis' error types where its results cross a module boundary: the setup fits
//! ([`FitError`]: `fit::fit_nominal`, `transfer::refit_setup`), the nonparametric
//! correction's file form ([`RbfFileError`], turned into the effect reader's error) and the
//! plots ([`PlotError`]). The stage runners (`stage`, `camera_stage`) and the diagnosis
//! itself still return `anyhow` errors: they are the top of the `diagnose` command.
use std::path::PathBuf;

/// Why a setup fit (tracker ← base, marker position) failed.
#[derive(Debug, thiserror::Error)]
pub enum FitError {
    /// Fewer poses than the fit's unknowns need.
    #[error("{what} at least {need} measured poses, got {got}")]
    TooFewPoses {
        /// What needs them ("need", "re-registering a setup needs").
        what: &'static str,
        /// Poses needed.
        need: usize,
        /// Poses given.
        got: usize,
    },
    /// The rigid registration that starts the fit failed.
    #[error("cannot register {what} to the robot base: {why}")]
    Register {
        /// What was registered ("the tracker", "the new setup").
        what: &'static str,
        /// The registration's error.
        why: String,
    },
    /// The fit diverged (`what` says where).
    #[error("{0}")]
    NotFinite(&'static str),
    /// A parameter of the model could not be freed or fixed.
    #[error(transparent)]
    Model(#[from] crate::model::ModelError),
}

/// Why the file form of a nonparametric correction cannot be read (the key is named).
#[derive(Debug, thiserror::Error)]
pub enum RbfFileError {
    /// The length scale is missing, not a number or not positive.
    #[error("bad \"length_scale_deg\"")]
    LengthScale,
    /// A table is missing.
    #[error("missing \"{0}\"")]
    Missing(String),
    /// A row of a table is not an array.
    #[error("bad row in \"{0}\"")]
    Row(String),
    /// A number of a table is not a finite number.
    #[error("bad number in \"{0}\"")]
    Number(String),
    /// The weights do not match the centres.
    #[error("weights must be one [x, y, z] per centre")]
    Weights,
}

/// A plot that could not be drawn or written.
#[derive(Debug, thiserror::Error)]
#[error("plot {}: {why}", path.display())]
pub struct PlotError {
    /// The SVG file.
    pub path: PathBuf,
    /// The plotting library's error.
    pub why: String,
}
