//! The one integration-test binary (see `Cargo.toml`: `autotests = false`).
//! Each area adds a module here.
mod acquire;
mod bad_input;
mod camera_calib;
mod camera_charuco;
mod camera_run;
mod camera_session;
mod cli;
mod dataset;
mod diagnose;
mod e2e;
mod import;
mod laser;
mod laser_world;
mod model;
mod navchain;
mod plan;
mod rcm;
mod real_handeye;
mod report;
mod run_integrity;
mod session;
mod soak;
mod solve;
mod wire_cell;
mod world_vs_model;
