//! The devices a capture reads, from a device file (validated as `devices --probe` does):
//! the tracker with its tools, and the arm read-only (joint encoders).

use std::path::Path;
use std::sync::Arc;

use anyhow::{bail, Context as _};
use robocal_drivers::ndi::{NdiConfig, NdiTracker, ReplyMode};
use robocal_drivers::MarkerTracker;

use crate::acquire::device_check::{check_file, tool_roms, CheckedDevices};
use crate::acquire::devices::{DeviceEntry, Protocol, Role};

/// The device file, checked.
pub fn checked(path: &Path) -> anyhow::Result<CheckedDevices> {
    let c = check_file(path)?;
    c.require_valid()?;
    Ok(c)
}

/// The first device of `role`.
pub fn entry(c: &CheckedDevices, role: Role) -> anyhow::Result<&DeviceEntry> {
    c.file
        .devices
        .iter()
        .find(|d| d.role == role)
        .with_context(|| format!("{}: no {role:?} device", c.path.display()))
}

/// Connect the first tracker of the device file and start tracking its tools (named after
/// their `.rom` files, in the file's order).
pub async fn open_tracker(c: &CheckedDevices) -> anyhow::Result<(Arc<dyn MarkerTracker>, String)> {
    let t = entry(c, Role::Tracker)?;
    let roms: Vec<(String, Vec<u8>)> = tool_roms(t, &c.base)?
        .into_iter()
        .map(|r| (r.name, r.bytes))
        .collect();
    let tracker: Arc<dyn MarkerTracker> = match t.protocol {
        Protocol::NdiTcp => Arc::new(
            NdiTracker::connect_tcp(&t.target(), NdiConfig::default(), &roms, ReplyMode::Binary)
                .await
                .with_context(|| format!("NDI tracker {:?} at {}", t.name, t.target()))?,
        ),
        Protocol::NdiSerial => Arc::new(
            NdiTracker::open_serial(&t.target(), NdiConfig::default(), &roms, ReplyMode::Binary)
                .await
                .with_context(|| format!("NDI tracker {:?} on {}", t.name, t.target()))?,
        ),
        other => bail!(
            "device {:?}: protocol {other:?}: capture streams an NDI tracker (ndi-tcp, ndi-serial)",
            t.name
        ),
    };
    Ok((tracker, t.name.clone()))
}
