//! `robocal-dataset/1` (JSON Lines) and `robocal-calibration/1` file types, reader, writer
//! and the append-only acquisition [`Journal`].
//!
//! The contract is `docs/dataset-format.md` (copied from the shared docs). Files use mm,
//! degrees, seconds; quaternions are `[w, x, y, z]`. Unknown fields are kept in `extra`
//! so a read → write round trip preserves them. The library works in mm and radians:
//! convert joint angles with [`q_rad`] at the file edge.
//!
//! Reading is strict: errors name the file, the line and the field
//! (`train.jsonl:17: field "q": expected an array of 6 numbers, got [...]`); the only
//! tolerated damage is a torn last line (no newline, not valid JSON), which is dropped
//! with a [`LoadWarning`] (also logged with `tracing`).

pub mod calibration;
pub mod camera;
mod check;
pub mod endoscope;
pub mod error;
pub mod io;
pub mod journal;
pub mod reference;
pub mod summary;
pub mod types;

pub use calibration::{read_calibration, write_calibration, CalibrationKind, CALIBRATION_FORMAT};
pub use camera::{
    CameraCalBlock, CameraHeader, HandEyeBlock, IntrinsicsBlock, PoseWithStd, TargetHeader,
};
pub use check::QUAT_NORM_TOL;
pub use error::{DatasetError, LoadWarning, Location};
pub use io::{
    dataset_parses_on_this_thread, parse_dataset, preset_dof, q_rad, read_dataset, write_dataset,
    Loaded, DATASET_FORMAT, EVENT_KINDS, NO_ROBOT_MODEL,
};
pub use journal::Journal;
pub use summary::Summary;
pub use types::*;
