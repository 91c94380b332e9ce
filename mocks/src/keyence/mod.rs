//! Simulated KEYENCE DL-RS1A (IL-1000 amplifier, IL-600 head) on a pty, fed by a
//! [`LaserSource`] (the world's laser model, or scripted samples).
//!
//! Written independently of the driver's codec (its own line parser and value formatter).

pub mod device;
pub mod server;

pub use device::{
    DlRs1aDevice, LaserSample, LaserSource, SimKeyenceConfig, StaticLaser, WorldLaser,
};
pub use server::{serve_pty, SimKeyence};

use crate::serve::{Bind, Endpoint, ServeError};
use crate::world::{DeviceRef, WorldHandle};
use std::sync::Arc;

/// `sim serve` entry point for `dl-rs1a`: the laser `device` on a new pty.
pub async fn start(
    world: WorldHandle,
    device: &str,
    _bind: &Bind,
) -> Result<Vec<Endpoint>, ServeError> {
    let Some(DeviceRef::Laser(index)) = world.device(device) else {
        return Err(ServeError::NoSuchDevice(device.to_string()));
    };
    let source = Arc::new(WorldLaser {
        world: world.clone(),
        index,
        name: device.to_string(),
    });
    let sim = serve_pty(source, SimKeyenceConfig::default()).map_err(|source| ServeError::Io {
        device: device.to_string(),
        source,
    })?;
    Ok(vec![sim.into_endpoint(device, "dl-rs1a")])
}
