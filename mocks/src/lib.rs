//! Simulated devices serving the real wire protocols over an independent physics world.
//!
//! The world holds the true robot (a URDF-style chain with its own forward kinematics,
//! never the root crate's model) and its hidden physical effects.
#![warn(missing_docs)]

pub mod bcap;
pub mod camera;
pub mod keyence;
pub mod navchain;
pub mod ndi;
pub mod rcm;
pub mod rcm_render;
pub mod scenario;
pub mod serve;
pub mod sim;
pub mod stated;
pub mod synth;
pub mod ur;
pub mod world;

pub use scenario::Scenario;
pub use world::WorldHandle;
