//! Simulated DENSO RC8 b-CAP server (TCP 5007) over the world.
//!
//! Implements the functions of `docs/protocols.md`'s checklist (§2.6 / §6): Service_Start/Stop,
//! Controller_Connect/Disconnect/GetRobot/GetVariable/GetRobotNames/Execute, Robot_GetVariable,
//! Robot_Execute (TakeArm, GiveArm, Motor, ExtSpeed, CurJnt, HighCurJntEx, CurPos), Robot_Move
//! (synchronous; `J(...)` joint targets as BSTR or `[R8 array, "J", "@E"]`; `S_EXECUTING`
//! keepalives every `WDT=` ms; `E_BUSY_PROC` for requests arriving meanwhile), Robot_Halt,
//! Robot_Release, Variable_GetValue/PutValue/Release, with HRESULT errors for bad handles,
//! unknown names, motor off, arm not taken, out-of-range targets and protective stops.
//!
//! Faults (queue `<device>`), taken before every final reply: `DropLink` closes, `Delay` /
//! `Silence` hold the reply (wall clock), `Garbage` sends the bytes instead, `BadCrc` corrupts
//! the EOT byte (TCP b-CAP has no CRC), `Truncated` sends half the reply then closes,
//! `ErrorReply { code }` answers with that HRESULT.

pub mod server;

use crate::serve::{Bind, Endpoint, ServeError};
use crate::world::{DeviceRef, WorldHandle};
use tokio::net::TcpListener;

/// Start the b-CAP server of arm `device` (endpoint `bcap`).
pub async fn start(
    world: WorldHandle,
    device: &str,
    bind: &Bind,
) -> Result<Vec<Endpoint>, ServeError> {
    let arm = match world.device(device) {
        Some(DeviceRef::Arm(i)) => i,
        _ => return Err(ServeError::NoSuchDevice(device.to_string())),
    };
    let io = |source| ServeError::Io {
        device: device.to_string(),
        source,
    };
    let l = TcpListener::bind(bind.addr(robocal_drivers::bcap::client::PORT))
        .await
        .map_err(io)?;
    let addr = l.local_addr().map_err(io)?;
    let ctrl = server::BcapController::new(world, arm, device);
    let task = tokio::spawn(server::serve(l, ctrl));
    Ok(vec![Endpoint {
        device: device.to_string(),
        protocol: "bcap".into(),
        addr: Some(addr),
        path: None,
        task: Some(task),
    }])
}
