//! The calibrate commands as library calls: options structs in, typed results out, files
//! written from the results. `src/cli/calibrate/` parses the arguments into the options and
//! prints the results; tests and other stages may call these directly.
pub mod correct;
pub mod kinematics;
pub mod pivot;
pub mod robot_world;
pub mod tool;
