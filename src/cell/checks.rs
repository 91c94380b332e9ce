//! The input checks of `robocal run` that need the cell description (bad input refused before anything moves): the plan
//! is re-checked against its own constraints and the cell's robot, and the speed and
//! acceleration caps must be finite, positive and within the cell's own limits. Runs before
//! anything is created or opened (a fresh run) and again on `--resume` (the run directory's
//! `run.json` and plan copy are files a user can edit).
use std::path::Path;

use anyhow::Context as _;

use crate::plan::recheck::recheck;
use crate::plan::PlanFile;
use crate::plausible::limits::motion_cap;

use super::source::{source, OpenOptions, StatedArm as CellArm};

/// The arm of the cell described by `config` (`mode` `sim`: a scenario; `live`: a device file).
fn cell_arm(mode: &str, config: &Path, arm: Option<&str>) -> anyhow::Result<CellArm> {
    Ok(source(mode, config, OpenOptions::default())?
        .stated(arm)?
        .arm)
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
