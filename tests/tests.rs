//! The one integration-test binary (see `Cargo.toml`: `autotests = false`).
//! Each area adds a module here.
mod acquire;
mod bad_input;
mod bad_input_trust;
mod camera_calib;
mod camera_charuco;
mod camera_predict;
mod camera_run;
mod camera_session;
mod capture;
mod cell_safety;
mod cli;
mod common;
mod correct_tool;
mod dataset;
mod diagnose;
mod diagnose_predict;
mod e2e;
mod field_trust;
mod import;
mod laser;
mod laser_predict;
mod laser_seed;
mod laser_session;
mod laser_world;
mod live_session;
/// The diagnosis with and without the transmission error maps (shared with the examples).
#[path = "../examples/common/map_pair.rs"]
mod map_pair;
mod model;
mod navchain;
mod navchain_cmd;
mod navchain_compare;
mod opencv_left;
mod perf;
mod pivot;
mod plan;
mod pooled_real;
mod predict_extrap;
mod rcm;
mod rcm_images;
mod rcm_session;
/// The RCM image trials (an evaluation harness kept beside the examples).
#[path = "../examples/common/rcm_trials.rs"]
mod rcm_trials;
mod real_handeye;
mod real_narrow_workspace;
mod real_serial_robots;
mod real_transmission_map;
mod realcam_io;
mod report;
mod run_integrity;
mod session;
mod soak;
mod solve;
mod teach_board;
mod wire_cell;
mod world_vs_model;
