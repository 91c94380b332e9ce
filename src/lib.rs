//! robocal: plans poses, drives the calibration cell, identifies kinematic and hand-eye
//! parameters, then closes the loop by diagnosing the residual the model leaves.
//!
//! Units inside the library: lengths in millimetres, angles in radians, time in seconds.
//! Files use millimetres and degrees (see `dataset`), conversion happens at the file edge.
//!
//! Estimation code (`model`, `solve`, `diagnose`, `plan`) never depends on the simulator crate (`mocks/`):
//! only `cell::simulated` reaches the simulators, through their truth-free face
//! (`mocks/src/stated.rs`: what a scenario states, and its devices as driver traits); a test
//! there fails when any other file names them.
//!
//! Comments cite the five source documents as "seed 000" … "seed 004", with their own
//! section and equation numbers: `docs/seeds.md` says what each document is, which modules
//! implement it and what every cited section holds.

pub mod acquire;
pub mod calibrate;
pub mod capture;
pub mod cell;
pub mod cli;
pub mod dataset;
pub mod diagnose;
pub mod fsio;
pub mod import;
pub mod model;
pub mod navchain;
pub mod plan;
pub mod plausible;
pub mod register;
pub mod report;
pub mod schema;
pub mod session;
pub mod solve;

pub use cli::EXIT_USAGE;

/// The `robocal` command line as a library call, for tests and examples that drive a whole
/// command: `args` as the binary receives them (the first is the program name), parsed and run
/// in this thread (so per-thread counters see the work). Returns the process exit code: 0
/// success (a session: PASS), 1 error, 2 a session's FAIL / INCOMPLETE, 64 a command line that
/// does not parse, 130 stopped by Ctrl-C after a durable record.
pub fn main_with_args<I, T>(args: I) -> i32
where
    I: IntoIterator<Item = T>,
    T: Into<std::ffi::OsString> + Clone,
{
    cli::run(args)
}
