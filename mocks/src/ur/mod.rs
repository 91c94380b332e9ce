//! Simulated Universal Robots controller: RTDE (30004), dashboard (29999) and the script
//! interfaces (30001–30003), all over one [`controller::Controller`] backed by the world.
//!
//! Proven against the public `ur-rtde` Python package (`RTDEReceiveInterface`,
//! `RTDEControlInterface.moveJ`) in `mocks/tests/ur_peer.rs`.
//!
//! Fault queues (inject with `world.control().inject(queue, fault)`): `<device>` for RTDE,
//! `<device>/dashboard`, `<device>/script`. Protective stops come from
//! `world.control().protective_stop(arm)`. Delays and silences are wall-clock (they exist to
//! exercise client deadlines, which are wall-clock).

pub mod controller;
pub mod dashboard_server;
pub mod rtde_server;
pub mod script_server;

use crate::serve::{Bind, Endpoint, ServeError};
use crate::world::{DeviceRef, WorldHandle};
pub use controller::Controller;
use std::sync::Arc;
use tokio::net::TcpListener;

/// Start the UR servers of arm `device`: endpoints `rtde`, `dashboard`, `script` (30003),
/// `script-primary` (30001), `script-secondary` (30002), each with its bound address.
pub async fn start(
    world: WorldHandle,
    device: &str,
    bind: &Bind,
) -> Result<Vec<Endpoint>, ServeError> {
    let arm = match world.device(device) {
        Some(DeviceRef::Arm(i)) => i,
        _ => return Err(ServeError::NoSuchDevice(device.to_string())),
    };
    let ctrl = Controller::new(world, arm, device);
    start_controller(ctrl, bind).await
}

/// Start the servers over an existing controller (tests keep the `Arc` to inspect it).
pub async fn start_controller(
    ctrl: Arc<Controller>,
    bind: &Bind,
) -> Result<Vec<Endpoint>, ServeError> {
    let device = ctrl.device.clone();
    let io = |source| ServeError::Io {
        device: device.clone(),
        source,
    };
    let mut out = Vec::new();
    let specs: [(&str, u16); 5] = [
        ("rtde", 30004),
        ("dashboard", 29999),
        ("script", 30003),
        ("script-primary", 30001),
        ("script-secondary", 30002),
    ];
    let mut listeners = Vec::new();
    for (name, port) in specs {
        let l = TcpListener::bind(bind.addr(port)).await.map_err(io)?;
        let addr = l.local_addr().map_err(io)?;
        listeners.push((name, l, addr));
    }
    for (name, l, addr) in listeners {
        let c = ctrl.clone();
        let task = match name {
            "rtde" => tokio::spawn(rtde_server::serve(l, c)),
            "dashboard" => tokio::spawn(dashboard_server::serve(l, c)),
            _ => tokio::spawn(script_server::serve(l, c)),
        };
        out.push(Endpoint {
            device: device.clone(),
            protocol: name.to_string(),
            addr: Some(addr),
            path: None,
            task: Some(task),
        });
    }
    Ok(out)
}
