//! robocal: plans poses, drives the calibration cell, identifies kinematic and hand-eye
//! parameters, then closes the loop by diagnosing the residual the model leaves.
//!
//! Units inside the library: lengths in millimetres, angles in radians, time in seconds.
//! Files use millimetres and degrees (see `dataset`), conversion happens at the file edge.
//!
//! Estimation code (`model`, `solve`, `diagnose`, `plan`) never depends on the simulator crate (`mocks/`);
//! only `cell` (dry runs) and `trials` (scoring against the simulated truth) wire the simulators in.

pub mod acquire;
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
pub mod trials;
