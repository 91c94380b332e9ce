//! Seed 001's second step as a library call (`robocal calibrate tool`): the tool (marker) on
//! the flange and the robot base in the tracker with the identified arm held fixed
//! (`solve::tool::tool_with_arm`: `AX = XB` closed form, then least squares), with bootstrap
//! standard deviations. Writes `calibration.json`: the arm with the new base and tool (each
//! with its std).
use std::path::{Path, PathBuf};

use anyhow::Context as _;

use crate::dataset::{CalibrationFile, CalibrationKind};
use crate::model::{KinematicModel, Unit};
use crate::solve::obs::{observations, Split};
use crate::solve::tool_boot::{tool_with_arm_boot, ToolBoot};

/// What the tool calibration found (and wrote).
#[derive(Debug, Clone)]
pub struct ToolCalibration {
    /// Pose records with a marker orientation (the ones fitted).
    pub with_quat: usize,
    /// The fit and its bootstrap.
    pub boot: ToolBoot,
    /// The arm with the new base and tool; `std` set (file units) on the bootstrapped ones.
    pub file: CalibrationFile,
    /// Where it was written (with `out`).
    pub written: Option<PathBuf>,
}

/// The tool and base with the identified arm `arm_path` held fixed, from the pose records of
/// `data`, with `bootstrap` replicates; `calibration.json` in `out` when given.
pub fn tool_with_arm(
    arm_path: &Path,
    data: &Path,
    bootstrap: usize,
    out: Option<&Path>,
) -> anyhow::Result<ToolCalibration> {
    let cal = CalibrationFile::load(arm_path)
        .with_context(|| format!("reading {}", arm_path.display()))?;
    anyhow::ensure!(
        cal.kind() == CalibrationKind::Kinematic,
        "{}: not a kinematic calibration (the identified arm is needed)",
        arm_path.display()
    );
    let mut arm = KinematicModel::from_robot_block(&cal.robot)
        .with_context(|| format!("{}: robot block", arm_path.display()))?;
    arm.apply_cal_params(&cal.params)
        .with_context(|| format!("{}: params", arm_path.display()))?;
    let ds = crate::plausible::load_checked(data)
        .with_context(|| format!("reading {}", data.display()))?;
    anyhow::ensure!(
        ds.header.robot.model == cal.robot.model,
        "{}: robot `{}` but the arm calibration {} is for `{}`",
        data.display(),
        ds.header.robot.model,
        arm_path.display(),
        cal.robot.model
    );
    let (obs, skipped) = observations(&ds, arm.dof(), Split::All);
    let with_quat = obs.iter().filter(|o| o.quat.is_some()).count();
    anyhow::ensure!(
        with_quat >= 3,
        "{}: {with_quat} pose records with a marker orientation (`quat`); tool identification \
         needs at least 3 (a 6-DoF marker body, not a single reflector){}",
        data.display(),
        if skipped.is_empty() {
            String::new()
        } else {
            format!("; {} records skipped", skipped.len())
        }
    );
    let b = tool_with_arm_boot(&arm, &obs, bootstrap, 30).context("tool identification")?;
    let mut file = crate::solve::calfile::kinematic_file(&cal.robot, &b.model);
    for p in file.params.iter_mut() {
        if let Some((_, s)) = b.std.iter().find(|(n, _)| *n == p.name) {
            let u = b
                .model
                .params()
                .iter()
                .find(|q| q.name == p.name)
                .map(|q| q.unit);
            p.std = Some(if u == Some(Unit::Rad) {
                s.to_degrees()
            } else {
                *s
            });
        }
    }
    file.effects = cal.effects.clone();
    file.metrics
        .insert("tool_rms_mm".into(), serde_json::json!(b.fit.rms_mm));
    file.metrics
        .insert("tool_rms_deg".into(), serde_json::json!(b.fit.rms_rot_deg));
    let mut written = None;
    if let Some(dir) = out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let path = dir.join("calibration.json");
        file.save(&path)
            .with_context(|| format!("writing {}", path.display()))?;
        CalibrationFile::load(&path).context("reading the written calibration back")?;
        written = Some(path);
    }
    Ok(ToolCalibration {
        with_quat,
        boot: b,
        file,
        written,
    })
}
