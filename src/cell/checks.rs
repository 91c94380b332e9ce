//! The input checks of `robocal run` that need the cell description (bad input refused before anything moves): the plan
//! is re-checked against its own constraints and the cell's robot, and the speed and
//! acceleration caps must be finite, positive and within the cell's own limits. Runs before
//! anything is created or opened (a fresh run) and again on `--resume` (the run directory's
//! `run.json` and plan copy are files a user can edit).
use std::path::Path;

use anyhow::Context as _;

use crate::plan::recheck::{recheck, CellRobot};
use crate::plan::PlanFile;
use crate::plausible::limits::{motion_cap, CellLimit};
use robocal_mocks::scenario::Scenario;

/// The cell's arm: model and motion limits (deg/s, deg/s²) with their source.
struct CellArm {
    robot: CellRobot,
    vel: Option<CellLimit>,
    acc: Option<CellLimit>,
}

fn cell_arm(mode: &str, config: &Path, arm: Option<&str>) -> anyhow::Result<CellArm> {
    if mode == "sim" {
        let s = Scenario::load(config).with_context(|| format!("reading {}", config.display()))?;
        let a = match arm {
            Some(n) => s.arms.iter().find(|a| a.name == n),
            None => s.arms.first(),
        };
        let Some(a) = a else {
            anyhow::bail!(
                "{}: the scenario has no [[arm]]{}",
                config.display(),
                arm.map_or_else(String::new, |n| format!(" named {n:?}"))
            );
        };
        let src = |k: &str| format!("{}: arm \"{}\" motion.{k}", config.display(), a.name);
        return Ok(CellArm {
            robot: CellRobot {
                source: format!("{}: arm \"{}\"", config.display(), a.name),
                model: Some(a.model.clone()),
                safety: a.safety.as_ref().map(|s| crate::plan::recheck::CellSafety {
                    table_z_mm: s.table_z_mm,
                    table_clearance_mm: s.table_clearance_mm.unwrap_or(0.0),
                    envelope: s.envelope.clone(),
                }),
            },
            vel: Some(CellLimit {
                value: a.motion.max_vel_deg_s,
                source: src("max_vel_deg_s"),
            }),
            acc: Some(CellLimit {
                value: a.motion.max_acc_deg_s2,
                source: src("max_acc_deg_s2"),
            }),
        });
    }
    let f = crate::acquire::devices::DevicesFile::read(config)?;
    let arm = f
        .devices
        .iter()
        .find(|d| d.role == crate::acquire::devices::Role::Arm);
    // A device file's `model` is free text: compared only when it names a built-in preset.
    let model = arm
        .and_then(|d| d.model.clone())
        .filter(|m| crate::dataset::preset_dof(m.trim()).is_some());
    let name = arm.map(|d| d.name.as_str()).unwrap_or("?");
    let limit = |v: Option<f64>, k: &str| {
        v.map(|value| CellLimit {
            value,
            source: format!("{}: device \"{name}\" {k}", config.display()),
        })
    };
    Ok(CellArm {
        robot: CellRobot {
            source: format!("{}: device \"{name}\"", config.display()),
            model,
            safety: None,
        },
        vel: limit(arm.and_then(|d| d.max_speed_deg_s), "max_speed_deg_s"),
        acc: limit(arm.and_then(|d| d.max_accel_deg_s2), "max_accel_deg_s2"),
    })
}

/// Checks a run's plan, caps and frame count against the cell described by `config`
/// (`mode` `sim`: a scenario; `live`: a device file).
pub fn check_run_inputs(
    plan: &PlanFile,
    plan_path: &Path,
    mode: &str,
    config: &Path,
    speed_deg_s: f64,
    accel_deg_s2: f64,
    frames: usize,
) -> anyhow::Result<()> {
    let cell = cell_arm(mode, config, None)?;
    caps(&cell, speed_deg_s, accel_deg_s2, frames)?;
    recheck(plan, Some(&cell.robot))
        .with_context(|| format!("checking {}", plan_path.display()))?;
    Ok(())
}

fn caps(cell: &CellArm, speed_deg_s: f64, accel_deg_s2: f64, frames: usize) -> anyhow::Result<()> {
    motion_cap("--speed-deg-s", speed_deg_s, "deg/s", cell.vel.as_ref())
        .map_err(anyhow::Error::msg)?;
    motion_cap("--accel-deg-s2", accel_deg_s2, "deg/s²", cell.acc.as_ref())
        .map_err(anyhow::Error::msg)?;
    anyhow::ensure!(
        (1..=10_000).contains(&frames),
        "--frames {frames}: average 1 to 10000 tracker frames per pose"
    );
    Ok(())
}

/// A session's speed and acceleration caps and frame count, checked against the cell
/// (`arm` of a scenario, or the device file's arm) before the session is created — the same
/// checks `robocal run` applies, so a session never stores a value its run would refuse.
pub fn check_motion_options(
    mode: &str,
    config: &Path,
    arm: Option<&str>,
    speed_deg_s: f64,
    accel_deg_s2: f64,
    frames: usize,
) -> anyhow::Result<()> {
    caps(
        &cell_arm(mode, config, arm)?,
        speed_deg_s,
        accel_deg_s2,
        frames,
    )
}
