//! Simulated NDI tracker (Polaris Vega over TCP, Polaris Spectra over a pty) speaking the
//! Combined API, fed by a [`TrackerSource`] (the world's tracker model, or fixed poses).
//!
//! The wire side ([`wire`]) is written independently of the driver's codec (its own CRC,
//! command parser and reply encoders), so that a bug shared by both cannot pass unseen;
//! the public client ndicapi / scikit-surgerynditracker checks this side in the peer tests.

pub mod device;
pub mod server;
pub mod wire;

pub use device::{NdiDevice, SimNdiConfig, StaticTracker, TrackerSource, WorldTracker};
pub use server::{serve_pty, serve_tcp, SimNdi};

use crate::serve::{Bind, Endpoint, ServeError};
use crate::world::{DeviceRef, WorldHandle};
use std::sync::Arc;

/// The Vega's TCP port.
pub const STANDARD_PORT: u16 = 8765;

fn world_source(world: &WorldHandle, device: &str) -> Result<Arc<dyn TrackerSource>, ServeError> {
    match world.device(device) {
        Some(DeviceRef::Tracker(index)) => Ok(Arc::new(WorldTracker {
            world: world.clone(),
            index,
            name: device.to_string(),
        })),
        _ => Err(ServeError::NoSuchDevice(device.to_string())),
    }
}

/// `sim serve` entry point for `ndi-tcp`: a Vega on `bind.addr(8765)` over tracker `device`.
pub async fn start(
    world: WorldHandle,
    device: &str,
    bind: &Bind,
) -> Result<Vec<Endpoint>, ServeError> {
    let source = world_source(&world, device)?;
    let sim = serve_tcp(source, SimNdiConfig::default(), bind.addr(STANDARD_PORT))
        .await
        .map_err(|source| ServeError::Io {
            device: device.to_string(),
            source,
        })?;
    Ok(vec![sim.into_endpoint(device, "ndi-tcp")])
}

/// `sim serve` entry point for `ndi-serial`: a serial Polaris on a new pty.
pub async fn start_serial(
    world: WorldHandle,
    device: &str,
    _bind: &Bind,
) -> Result<Vec<Endpoint>, ServeError> {
    let source = world_source(&world, device)?;
    let sim = serve_pty(source, SimNdiConfig::default()).map_err(|source| ServeError::Io {
        device: device.to_string(),
        source,
    })?;
    Ok(vec![sim.into_endpoint(device, "ndi-serial")])
}
