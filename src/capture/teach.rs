//! Teaching poses by hand on a device file's arm (`robocal capture poses`): a UR is put in
//! freedrive through its script interface (and taken out of it afterwards, whatever happened),
//! a DENSO is read while it is jogged from the teach pendant. The caller asks for the consent
//! to release a UR (`--live`) before calling [`teach_poses`].
use anyhow::Context as _;
use robocal_drivers::{Clock, JointReadout};

use super::poses::{capture_poses, PoseOptions, TaughtPose};
use super::Keys;
use crate::acquire::devices::{DeviceEntry, Protocol};

/// The freedrive program of a UR: freedrive until the program is replaced or stopped.
pub fn freedrive_program(seconds: f64) -> String {
    format!(
        "def robocal_freedrive():\n  freedrive_mode()\n  sleep({:.1})\n  end_freedrive_mode()\nend\n",
        seconds
    )
}

/// Connects to `arm` (b-CAP or RTDE), puts a UR in freedrive for up to `opt.max_seconds` and
/// records the poses held still (`capture_poses`); a UR's freedrive ends when this returns.
pub async fn teach_poses(
    arm: &DeviceEntry,
    clock: &dyn Clock,
    opt: &PoseOptions,
    keys: &Keys,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<Vec<TaughtPose>> {
    let mut script: Option<robocal_drivers::ur::script::ScriptClient> = None;
    let reader: Box<dyn JointReadout> = match arm.protocol {
        Protocol::Bcap => {
            let mut cfg = robocal_drivers::bcap::DensoConfig::new(arm.target());
            cfg.name = arm.name.clone();
            Box::new(
                robocal_drivers::bcap::DensoArm::connect(cfg)
                    .await
                    .with_context(|| format!("b-CAP arm {:?} at {}", arm.name, arm.target()))?,
            )
        }
        Protocol::Rtde => {
            let mut cfg = robocal_drivers::ur::UrConfig::new(arm.target());
            cfg.name = arm.name.clone();
            if let Some(p) = arm.ports {
                cfg.rtde_port = p.rtde.unwrap_or(cfg.rtde_port);
                cfg.dashboard_port = p.dashboard.unwrap_or(cfg.dashboard_port);
                cfg.script_port = p.script.unwrap_or(cfg.script_port);
            }
            let script_addr = format!("{}:{}", cfg.host, cfg.script_port);
            let ur = robocal_drivers::ur::UrArm::connect(cfg)
                .await
                .with_context(|| format!("UR arm {:?} at {}", arm.name, arm.target()))?;
            let s = robocal_drivers::ur::script::ScriptClient::connect(
                &script_addr,
                std::time::Duration::from_secs(5),
            )
            .await
            .with_context(|| format!("UR script interface at {script_addr}"))?;
            s.send(&freedrive_program(opt.max_seconds)).await?;
            script = Some(s);
            Box::new(ur)
        }
        other => anyhow::bail!("device {:?}: protocol {other:?} is not an arm", arm.name),
    };
    let r = capture_poses(&*reader, clock, opt, keys, progress).await;
    if let Some(s) = &script {
        // Replace the freedrive program: the arm holds again.
        s.send("end_freedrive_mode()\n").await.ok();
    }
    r
}
