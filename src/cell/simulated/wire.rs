//! The wire-level dry-run cell: the scenario's simulators served on loopback TCP / ptys
//! ([`SimCell::serve`]) with the REAL protocol clients of `robocal_drivers`
//! connected to them, so a rehearsal exercises everything but the hardware.
//!
//! | scenario protocol | server                  | client                                    |
//! |-------------------|-------------------------|-------------------------------------------|
//! | arm `bcap`        | b-CAP on TCP            | [`DensoArm`]                              |
//! | arm `ur`          | RTDE + dashboard + script | [`UrArm`]                               |
//! | tracker `ndi-tcp` | NDI Combined API on TCP | [`NdiTracker`] over [`NdiClient`] (TCP)   |
//! | tracker `ndi-serial` | NDI on a pty         | [`NdiTracker`] over [`NdiClient`] (serial)|
//! | laser `dl-rs1a`   | DL-RS1A on a pty        | [`Il600`] over [`KeyenceClient`]          |
//! | camera `camera`   | MJPEG over HTTP         | OpenCV `VideoCaptureSource` (feature `opencv`) |
//!
//! Devices with no wire protocol in this build (`optotrak`: NDI's proprietary library) fall
//! back to the in-process simulated device; they are listed in
//! [`Served::unavailable`] and logged (`tracing::warn!`). The camera needs the OpenCV client:
//! without feature `opencv` it is the in-process simulated camera (same renderer, no wire).
//!
//! Units: as everywhere in the library, mm and radians.
use std::sync::Arc;
use std::time::Duration;

use anyhow::{bail, Context as _};
use robocal_drivers::bcap::{DensoArm, DensoConfig};
use robocal_drivers::keyence::{Il600, Il600Config, KeyenceClient, KeyenceConfig};
use robocal_drivers::ndi::{NdiConfig, NdiTracker, ReplyMode};
use robocal_drivers::ur::{Backoff, UrArm, UrConfig};
use robocal_drivers::{Arm, ImageSource, MarkerTracker, RangeSensor};
use robocal_mocks::stated::{Bind, Endpoint, Protocol, Served, SimCell, SimDeviceSet};

use crate::cell::CellInfo;

/// Size of the synthetic tool definition loaded into a simulated NDI tracker. The simulator
/// treats a `.rom` as opaque (its `k`-th tool is reported on the `k`-th handle loaded); a
/// real cell loads the marker's `.rom` file instead.
const SIM_ROM_LEN: usize = 752;

/// Reconnect policy for loopback links: quick, bounded.
fn loopback_backoff() -> Backoff {
    Backoff {
        attempts: 4,
        initial: Duration::from_millis(20),
        max: Duration::from_millis(200),
    }
}

fn endpoint<'a>(served: &'a Served, device: &str, protocol: &str) -> Option<&'a Endpoint> {
    served
        .endpoints
        .iter()
        .find(|e| e.device == device && e.protocol == protocol)
}

fn tcp_addr(served: &Served, device: &str, protocol: &str) -> anyhow::Result<std::net::SocketAddr> {
    endpoint(served, device, protocol)
        .and_then(|e| e.addr)
        .with_context(|| format!("no {protocol} TCP endpoint was served for {device}"))
}

fn pty_path(served: &Served, device: &str, protocol: &str) -> anyhow::Result<String> {
    endpoint(served, device, protocol)
        .and_then(|e| e.path.clone())
        .with_context(|| format!("no {protocol} pty was served for {device}"))
}

fn fallback(served: &Served, device: &str, protocol: Protocol) {
    let why = served
        .unavailable
        .iter()
        .find(|(d, _, _)| d == device)
        .map_or_else(|| "no wire protocol".to_string(), |(_, _, e)| e.clone());
    tracing::warn!(
        "wire cell: {device} ({}) has no wire simulator ({why}); using the in-process simulated device",
        protocol.as_str()
    );
}

/// A synthetic tool definition for the simulated tracker (deterministic bytes).
fn sim_rom(tool: &str) -> Vec<u8> {
    let tag = tool
        .bytes()
        .fold(0u8, |a, b| a.wrapping_mul(31).wrapping_add(b));
    (0..SIM_ROM_LEN).map(|i| (i as u8) ^ tag).collect()
}

async fn connect_arm(
    world: &SimCell,
    served: &Served,
    name: &str,
    protocol: Protocol,
) -> anyhow::Result<Arc<dyn Arm>> {
    Ok(match protocol {
        Protocol::Bcap => {
            let addr = tcp_addr(served, name, "bcap")?;
            let mut cfg = DensoConfig::new(addr.to_string());
            cfg.name = name.to_string();
            cfg.dof = world.arm_dof();
            cfg.backoff = loopback_backoff();
            let arm = DensoArm::connect(cfg)
                .await
                .with_context(|| format!("b-CAP client to {name} at {addr}"))?;
            Arc::new(arm)
        }
        Protocol::Ur => {
            let rtde = tcp_addr(served, name, "rtde")?;
            let mut cfg = UrConfig::new(rtde.ip().to_string());
            cfg.name = name.to_string();
            cfg.rtde_port = rtde.port();
            cfg.dashboard_port = tcp_addr(served, name, "dashboard")?.port();
            cfg.script_port = tcp_addr(served, name, "script")?.port();
            cfg.backoff = loopback_backoff();
            let arm = UrArm::connect(cfg)
                .await
                .with_context(|| format!("UR client (RTDE + dashboard + script) to {name}"))?;
            Arc::new(arm)
        }
        other => {
            fallback(served, name, other);
            world.arm_in_process(name)
        }
    })
}

async fn connect_tracker(
    world: &SimCell,
    served: &Served,
    name: &str,
    protocol: Protocol,
    tool: &str,
) -> anyhow::Result<Arc<dyn MarkerTracker>> {
    let tools = [(tool.to_string(), sim_rom(tool))];
    Ok(match protocol {
        Protocol::NdiTcp => {
            let addr = tcp_addr(served, name, "ndi-tcp")?;
            let t = NdiTracker::connect_tcp(
                &addr.to_string(),
                NdiConfig::default(),
                &tools,
                ReplyMode::Binary,
            )
            .await
            .with_context(|| format!("NDI tracker {name} at {addr} (connect and start-up)"))?;
            Arc::new(t.with_clock(world.clock()))
        }
        Protocol::NdiSerial => {
            let path = pty_path(served, name, "ndi-serial")?;
            let t = NdiTracker::open_serial(&path, NdiConfig::default(), &tools, ReplyMode::Binary)
                .await
                .with_context(|| format!("NDI tracker {name} on {path} (open and start-up)"))?;
            Arc::new(t.with_clock(world.clock()))
        }
        other => {
            fallback(served, name, other);
            world.tracker_in_process(name)
        }
    })
}

fn connect_laser(
    world: &SimCell,
    served: &Served,
    name: &str,
    protocol: Protocol,
) -> anyhow::Result<Arc<dyn RangeSensor>> {
    Ok(match protocol {
        Protocol::DlRs1a => {
            let path = pty_path(served, name, "dl-rs1a")?;
            let client = KeyenceClient::open_serial(&path, KeyenceConfig::default())
                .with_context(|| format!("KEYENCE DL-RS1A client to {name} on {path}"))?;
            Arc::new(Il600::new(client, Il600Config::default()))
        }
        other => {
            fallback(served, name, other);
            world.range_in_process(name)
        }
    })
}

/// The scenario's first camera (named `name`): with feature `opencv` and the wall clock,
/// OpenCV's `VideoCapture` reading the simulator's MJPEG stream (frames stamped by the world's
/// clock); otherwise, or when no stream is served, the in-process simulated camera. On a
/// virtual clock the stream cannot keep up with the world: it is paced on wall time while a
/// move of seconds passes in milliseconds, so a frame grabbed at a pose may have been rendered
/// during the move to it. There the in-process camera renders the world at the pose.
async fn connect_camera(
    world: &SimCell,
    served: &Served,
    name: &str,
) -> anyhow::Result<Arc<dyn ImageSource>> {
    #[cfg(feature = "opencv")]
    if let Some(addr) = endpoint(served, name, "mjpeg")
        .and_then(|e| e.addr)
        .filter(|_| !world.is_virtual())
    {
        use robocal_drivers::camera::opencv::{CaptureConfig, VideoCaptureSource};
        let config = CaptureConfig::new(format!("http://{addr}/video.mjpg"));
        let clock = world.clock();
        // Opening blocks until the first HTTP reply: off the runtime that serves it.
        let src =
            tokio::task::spawn_blocking(move || VideoCaptureSource::open_with_clock(config, clock))
                .await
                .context("camera open task")?
                .with_context(|| format!("connecting OpenCV to the camera stream of {name}"))?;
        tracing::debug!("wire cell: camera {name} over MJPEG at {addr} (OpenCV)");
        return Ok(Arc::new(src));
    }
    let _ = served;
    tracing::debug!("wire cell: camera {name} is the in-process simulated camera");
    Ok(world.camera_in_process(name))
}

/// Serve every device of the cell's scenario on loopback TCP (port 0) / ptys and connect
/// the real drivers to the first arm, tracker and laser, plus the first camera (the same
/// devices as [`super::sim_cell`]). The clock is the cell's.
///
/// The arm is NOT wrapped in the safety decorators (`robocal run` does that for every arm).
/// Keep the returned [`Served`] alive for the whole run: dropping it does not stop the
/// servers, [`Served::abort`] does. Devices in [`Served::unavailable`] were wired
/// in-process instead.
pub async fn wire_cell(
    world: &SimCell,
) -> anyhow::Result<(crate::acquire::Devices, CellInfo, Served)> {
    let scenario = world.stated();
    let Some(arm_cfg) = scenario.arms.first() else {
        bail!("scenario {:?} has no arm", scenario.name);
    };
    let served = world
        .serve(&Bind::default())
        .await
        .with_context(|| format!("serving the devices of {:?}", scenario.name))?;
    let built = async {
        let arm = connect_arm(world, &served, &arm_cfg.name, arm_cfg.protocol).await?;
        let tracker = match scenario.trackers.first() {
            Some(t) => Some(connect_tracker(world, &served, &t.name, t.protocol, &t.tool).await?),
            None => None,
        };
        let range = match scenario.lasers.first() {
            Some(l) => Some(connect_laser(world, &served, &l.name, l.protocol)?),
            None => None,
        };
        let camera = match scenario.cameras.first() {
            Some(c) => Some(connect_camera(world, &served, &c.name).await?),
            None => None,
        };
        anyhow::Ok(SimDeviceSet {
            arm,
            tracker,
            range,
            camera,
        })
    }
    .await;
    match built {
        Ok(set) => Ok((super::devices(world, set), super::info(world), served)),
        Err(e) => {
            served.abort();
            Err(e)
        }
    }
}
