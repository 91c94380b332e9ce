//! The one integration-test binary (see `Cargo.toml`: `autotests = false`).
//! Each area adds a module here.
mod model;
mod dataset;
mod cli;
mod plan;
mod laser;
mod solve;
mod acquire;
mod diagnose;
mod laser_world;
mod world_vs_model;
mod report;
mod e2e;
mod wire_cell;
