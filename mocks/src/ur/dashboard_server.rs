//! Dashboard server (29999): banner, one reply line per command (`docs/protocols.md` §1.8).
//!
//! Faults (queue `<device>/dashboard`), taken before every reply: `DropLink` closes;
//! `Delay`/`Silence` hold the reply (wall clock); `Garbage` sends the bytes instead;
//! `Truncated` sends half the reply without its newline and closes; `ErrorReply` answers
//! `could not understand: '<cmd>'`; `BadCrc` flips the reply's case (still a line).

use super::controller::{Controller, VERSION};
use crate::world::Fault;
use futures_util::StreamExt as _;
use robocal_drivers::ur::dashboard::LineCodec;
use robocal_drivers::ur::rtde::frame::{runtime_state, RobotMode, SafetyMode};
use std::sync::Arc;
use std::time::Duration;
use tokio::io::AsyncWriteExt;
use tokio::net::{TcpListener, TcpStream};
use tokio_util::codec::FramedRead;

/// The banner sent on connect.
pub const BANNER: &str = "Connected: Universal Robots Dashboard Server";

/// Accept dashboard clients forever.
pub async fn serve(listener: TcpListener, ctrl: Arc<Controller>) {
    loop {
        match listener.accept().await {
            Ok((sock, _)) => {
                let _ = sock.set_nodelay(true);
                tokio::spawn(connection(sock, ctrl.clone()));
            }
            Err(_) => tokio::time::sleep(Duration::from_millis(50)).await,
        }
    }
}

async fn connection(sock: TcpStream, ctrl: Arc<Controller>) {
    let (r, mut w) = sock.into_split();
    if w.write_all(format!("{BANNER}\n").as_bytes()).await.is_err() {
        return;
    }
    let mut lines = FramedRead::new(r, LineCodec);
    let queue = format!("{}/dashboard", ctrl.device);
    while let Some(Ok(cmd)) = lines.next().await {
        let (mut reply, close) = answer(&ctrl, &cmd);
        match ctrl.world.take_fault(&queue) {
            Some(Fault::DropLink) => return,
            Some(Fault::Delay { secs } | Fault::Silence { secs }) => {
                tokio::time::sleep(Duration::from_secs_f64(secs.clamp(0.0, 600.0))).await
            }
            Some(Fault::Garbage { bytes }) => {
                if w.write_all(&bytes).await.is_err() {
                    return;
                }
                continue;
            }
            Some(Fault::Truncated) => {
                let half = &reply.as_bytes()[..reply.len() / 2];
                let _ = w.write_all(half).await;
                return;
            }
            Some(Fault::ErrorReply { .. }) => reply = format!("could not understand: '{cmd}'"),
            Some(Fault::BadCrc) => reply = reply.to_lowercase(),
            _ => {}
        }
        if w.write_all(format!("{reply}\n").as_bytes()).await.is_err() || close {
            return;
        }
    }
}

/// The reply to one command, and whether to close afterwards.
pub fn answer(ctrl: &Arc<Controller>, cmd: &str) -> (String, bool) {
    let c = cmd.trim();
    let lower = c.to_ascii_lowercase();
    let r = match lower.as_str() {
        "power on" => {
            ctrl.with(|s| {
                if s.robot_mode != RobotMode::Running {
                    s.robot_mode = RobotMode::Idle
                }
            });
            "Powering on".to_string()
        }
        "power off" => {
            ctrl.stop_program();
            ctrl.with(|s| s.robot_mode = RobotMode::PowerOff);
            "Powering off".to_string()
        }
        "brake release" => {
            ctrl.with(|s| s.robot_mode = RobotMode::Running);
            "Brake releasing".to_string()
        }
        "play" => {
            if ctrl.with(|s| s.loaded.is_some()) {
                ctrl.run_program("def loaded_program():\nend\n".into());
                "Starting program".to_string()
            } else {
                "Failed to execute: play".to_string()
            }
        }
        "stop" => {
            ctrl.stop_program();
            "Stopped".to_string()
        }
        "pause" => {
            if ctrl.with(|s| s.runtime == runtime_state::PLAYING) {
                "Pausing program".to_string()
            } else {
                "Failed to execute: pause".to_string()
            }
        }
        "unlock protective stop" => unlock(ctrl),
        "close safety popup" => "closing safety popup".to_string(),
        "robotmode" => format!("Robotmode: {}", ctrl.with(|s| s.robot_mode).name()),
        "safetystatus" => format!("Safetystatus: {}", ctrl.safety_mode().name()),
        "safetymode" => format!("Safetymode: {}", ctrl.safety_mode().name()),
        "programstate" => {
            let (rt, name) = ctrl.with(|s| (s.runtime, s.loaded.clone().unwrap_or_default()));
            let st = match rt {
                runtime_state::PLAYING => "PLAYING",
                runtime_state::PAUSED => "PAUSED",
                _ => "STOPPED",
            };
            format!("{st} {name}")
        }
        "running" => format!(
            "Program running: {}",
            ctrl.with(|s| s.runtime == runtime_state::PLAYING)
        ),
        "get loaded program" => match ctrl.with(|s| s.loaded.clone()) {
            Some(p) => format!("Loaded program: {p}"),
            None => "No program loaded".to_string(),
        },
        "polyscopeversion" => format!("URSoftware {VERSION} (simulated)"),
        "version" => VERSION.to_string(),
        "is in remote control" => "true".to_string(),
        "get serial number" => ctrl.serial_digits(),
        "get robot model" => ctrl
            .world
            .arm_identity(ctrl.arm)
            .map(|(m, _)| m.trim_end_matches('e').to_uppercase())
            .unwrap_or_else(|| "UR5".into()),
        "isprogramsaved" => "true robocal".to_string(),
        "restart safety" => "Restarting safety".to_string(),
        "quit" => return ("Disconnected".to_string(), true),
        _ => {
            if let Some(p) = lower.strip_prefix("load ") {
                let p = c[c.len() - p.len()..].trim().to_string();
                if p.ends_with(".urp") {
                    ctrl.with(|s| s.loaded = Some(p.clone()));
                    format!("Loading program: {p}")
                } else {
                    format!("File not found: {p}")
                }
            } else {
                format!("could not understand: '{c}'")
            }
        }
    };
    (r, false)
}

fn unlock(ctrl: &Arc<Controller>) -> String {
    if ctrl.safety_mode() != SafetyMode::ProtectiveStop {
        // Nothing to unlock: real controllers answer the same text.
        return "Protective stop releasing".to_string();
    }
    let since = ctrl.with(|s| s.pstop_since).unwrap_or(0.0);
    let waited = ctrl.world.now() - since;
    if waited < 5.0 {
        if ctrl.world.is_virtual() {
            // Virtual time: the operator's 5 s wait passes instantly.
            ctrl.world.advance(5.0 - waited);
        } else {
            return "Cannot unlock protective stop until 5s after occurrence. Always inspect cause of protective stop before unlocking".to_string();
        }
    }
    match ctrl.world.arm_recover(ctrl.arm) {
        Ok(()) => {
            ctrl.with(|s| s.pstop_since = None);
            "Protective stop releasing".to_string()
        }
        Err(e) => format!("Failed to execute: unlock protective stop ({e})"),
    }
}
