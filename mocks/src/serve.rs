//! Run every simulated device of a scenario as a protocol server.
//!
//! # Contract for protocol-simulator authors (`crate::{ur, bcap, ndi, keyence, camera}`)
//!
//! Each protocol module exposes exactly one entry point with this signature:
//!
//! ```ignore
//! pub async fn start(
//!     world: crate::world::WorldHandle,
//!     device: &str,
//!     bind: &crate::serve::Bind,
//! ) -> Result<Vec<crate::serve::Endpoint>, crate::serve::ServeError>;
//! ```
//!
//! - `device` is the scenario's device name; resolve it with `world.device(device)`
//!   (→ `DeviceRef::Arm(i)` / `Tracker(i)` / `Laser(i)` / `Camera(i)`).
//! - TCP servers bind `bind.addr(STANDARD_PORT)` (port 0 unless `--standard-ports`), spawn their
//!   accept loop with `tokio::spawn`, and return one [`Endpoint`] per listening socket with the
//!   ACTUAL bound address (`listener.local_addr()`) — readiness is signalled by returning, never
//!   by sleeping. UR returns several endpoints (`rtde`, `dashboard`, `script-primary`, …).
//! - Serial protocols (`ndi-serial`, `dl-rs1a`) open a pty and return an endpoint with `path`.
//! - Before each reply, poll `world.take_fault(device)` and apply the [`crate::world::Fault`].
//! - Time: use `world.clock()` (virtual or real) for stream pacing and delays.
//!
//! The registry [`start_device`] has one match arm per protocol; arms whose module has not
//! landed yet return [`ServeError::NotAvailable`].

use crate::scenario::Protocol;
use crate::world::WorldHandle;
use std::net::{IpAddr, Ipv4Addr, SocketAddr};

/// Where servers bind.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Bind {
    /// Host address (e.g. 127.0.0.1, or 127.0.0.N to give each simulated controller its own IP).
    pub host: IpAddr,
    /// Bind the vendors' fixed ports (RTDE 30004, dashboard 29999, script 30001–30003,
    /// b-CAP 5007, NDI 8765, camera 8080) instead of port 0.
    pub standard_ports: bool,
}

impl Default for Bind {
    fn default() -> Self {
        Self {
            host: IpAddr::V4(Ipv4Addr::LOCALHOST),
            standard_ports: false,
        }
    }
}

impl Bind {
    /// The address to bind for a service whose vendor port is `standard_port`.
    pub fn addr(&self, standard_port: u16) -> SocketAddr {
        SocketAddr::new(
            self.host,
            if self.standard_ports {
                standard_port
            } else {
                0
            },
        )
    }
}

/// One running server endpoint.
#[derive(Debug)]
pub struct Endpoint {
    /// Scenario device name.
    pub device: String,
    /// Protocol / service name (`rtde`, `dashboard`, `bcap`, `ndi-tcp`, `dl-rs1a`, …).
    pub protocol: String,
    /// Bound TCP address, for network servers.
    pub addr: Option<SocketAddr>,
    /// Serial device path (pty), for serial servers.
    pub path: Option<String>,
    /// The server task (aborted when the endpoint is dropped by [`Endpoint::abort`]).
    pub task: Option<tokio::task::JoinHandle<()>>,
}

impl Endpoint {
    /// The JSON line printed by `robocal sim serve`.
    pub fn to_json(&self) -> serde_json::Value {
        let mut m = serde_json::Map::new();
        m.insert("device".into(), self.device.clone().into());
        m.insert("protocol".into(), self.protocol.clone().into());
        if let Some(a) = self.addr {
            m.insert("addr".into(), a.to_string().into());
        }
        if let Some(p) = &self.path {
            m.insert("path".into(), p.clone().into());
        }
        serde_json::Value::Object(m)
    }
    /// Stop the server task.
    pub fn abort(&self) {
        if let Some(t) = &self.task {
            t.abort();
        }
    }
}

/// Why a server could not start.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ServeError {
    /// The protocol simulator has not landed yet.
    #[error("protocol {protocol} not available yet (device {device})")]
    NotAvailable {
        /// Protocol name.
        protocol: String,
        /// Device name.
        device: String,
    },
    /// The scenario has no such device, or it is of the wrong kind for the protocol.
    #[error("no suitable device {0:?} in the scenario")]
    NoSuchDevice(String),
    /// Binding or opening a pty failed.
    #[error("cannot start server for {device}: {source}")]
    Io {
        /// Device name.
        device: String,
        /// Cause.
        source: std::io::Error,
    },
    /// Anything else.
    #[error("{0}")]
    Other(String),
}

/// Start the server(s) for one device.
pub async fn start_device(
    world: &WorldHandle,
    device: &str,
    protocol: Protocol,
    bind: &Bind,
) -> Result<Vec<Endpoint>, ServeError> {
    if world.device(device).is_none() {
        return Err(ServeError::NoSuchDevice(device.to_string()));
    }
    match protocol {
        Protocol::Ur => crate::ur::start(world.clone(), device, bind).await,
        Protocol::NdiTcp => crate::ndi::start(world.clone(), device, bind).await,
        Protocol::NdiSerial => crate::ndi::start_serial(world.clone(), device, bind).await,
        Protocol::DlRs1a => crate::keyence::start(world.clone(), device, bind).await,
        Protocol::Bcap => crate::bcap::start(world.clone(), device, bind).await,
        Protocol::Camera => crate::camera::start(world.clone(), device, bind).await,
        Protocol::Optotrak => Err(ServeError::NotAvailable {
            protocol: protocol.as_str().to_string(),
            device: device.to_string(),
        }),
    }
}

/// What [`serve_all`] started.
#[derive(Debug, Default)]
pub struct Served {
    /// Running endpoints.
    pub endpoints: Vec<Endpoint>,
    /// Devices whose protocol simulator is not available (device, protocol, message).
    pub unavailable: Vec<(String, String, String)>,
}

impl Served {
    /// The JSON lines `robocal sim serve` prints before `{"ready": true}`: one per endpoint,
    /// then one `{"device", "protocol", "error"}` per unavailable device.
    pub fn json_lines(&self) -> Vec<serde_json::Value> {
        let mut v: Vec<serde_json::Value> = self.endpoints.iter().map(Endpoint::to_json).collect();
        v.extend(
            self.unavailable
                .iter()
                .map(|(d, p, e)| serde_json::json!({"device": d, "protocol": p, "error": e})),
        );
        v
    }
    /// Stop every server.
    pub fn abort(&self) {
        for ep in &self.endpoints {
            ep.abort();
        }
    }
}

/// Start every device of the world's scenario. Devices whose protocol is not available are
/// listed in [`Served::unavailable`]; any other failure stops everything and is returned.
pub async fn serve_all(world: &WorldHandle, bind: &Bind) -> Result<Served, ServeError> {
    let mut out = Served::default();
    for (name, protocol) in world.scenario().devices() {
        match start_device(world, &name, protocol, bind).await {
            Ok(eps) => out.endpoints.extend(eps),
            Err(e @ ServeError::NotAvailable { .. }) => {
                out.unavailable
                    .push((name, protocol.as_str().to_string(), e.to_string()));
            }
            Err(e) => {
                out.abort();
                return Err(e);
            }
        }
    }
    Ok(out)
}
