//! Plausibility checks at the input boundaries (a silent wrong answer is worse
//! than an error). The strict readers check a file's structure and types; these check that
//! well-formed values can be right for the robot and cell they describe:
//! - [`dataset`]: joint angles inside the robot's limits and in degrees, positions in mm
//!   (compared with the nominal geometry), laser ranges within the sensor's window,
//!   plausible times and temperatures; a second file (held-out data, calibration) for the
//!   same robot model.
//! - [`calibration`]: calibration values finite, within reach of the nominal geometry.
//! - [`quat`]: every file quaternion unit and finite, and in the declared `[w, x, y, z]`
//!   order where the robot's rotations tell.
//! - [`limits`]: speed / acceleration caps finite, positive and within the cell's limit;
//!   timeouts finite and positive.
//!
//! Every error names the file, the line (where there is one), the field and the likely cause.
pub mod calibration;
pub mod dataset;
pub mod limits;
pub mod quat;

pub use dataset::{check_dataset, check_same_robot, load_checked, load_with_heldout};
