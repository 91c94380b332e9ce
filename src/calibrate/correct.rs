//! `robocal correct` as a library call: a kinematic calibration and desired tool poses in,
//! corrected joint targets out as a table or a robot program (the deploy path for controllers
//! that cannot load a new kinematic model). Reads files, never opens a device.
use std::path::Path;

use anyhow::Context as _;

use crate::dataset::{CalibrationFile, CalibrationKind};
use crate::solve::correct;

/// What `correct` writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Output {
    /// Table: corrected and nominal joints (deg), nominal error, compensated pose.
    Csv,
    /// UR program: `movej` to each corrected joint target (rad).
    Urscript,
    /// DENSO PacScript: `Move P, J(...)` (deg).
    Pacscript,
}

/// Options of `correct`.
#[derive(Debug, Clone)]
pub struct Options<'a> {
    /// Kinematic calibration (`robocal-calibration/1`).
    pub calibration: &'a Path,
    /// Desired tool poses in the robot base (`name,x_mm,y_mm,z_mm,qw,qx,qy,qz[,branch]`).
    pub targets: &'a Path,
    pub output: Output,
    /// URScript joint speed (rad/s) and acceleration (rad/s²); PacScript speed (%).
    pub speed: f64,
    pub accel: f64,
    /// Wait at each target (s).
    pub wait: f64,
}

/// Checks the options, corrects every target and returns the text to write; `log` gets the
/// warnings and the summary line as they arise.
pub fn run(o: &Options, log: &mut dyn FnMut(&str)) -> anyhow::Result<String> {
    let cal = CalibrationFile::load(o.calibration)
        .with_context(|| format!("reading {}", o.calibration.display()))?;
    anyhow::ensure!(
        cal.kind() == CalibrationKind::Kinematic,
        "{}: a {:?} calibration; `correct` needs a kinematic calibration (robocal calibrate \
         kinematics / session)",
        o.calibration.display(),
        cal.kind()
    );
    for (v, what) in [
        (o.speed, "--speed"),
        (o.accel, "--accel"),
        (o.wait, "--wait"),
    ] {
        anyhow::ensure!(
            v.is_finite() && v > 0.0,
            "{what} must be a positive number, got {v}"
        );
    }
    match o.output {
        Output::Urscript => correct::check_script_motion(true, o.speed, o.accel)?,
        Output::Pacscript => correct::check_script_motion(false, o.speed, o.accel)?,
        Output::Csv => {}
    }
    if !cal.effects.is_empty() {
        log(&format!(
            "warning: {}: {} effect(s) beyond the geometry are not inverted by `correct` \
             (geometric IK only)",
            o.calibration.display(),
            cal.effects.len()
        ));
    }
    let (calibrated, nominal) =
        correct::models_of(&cal).with_context(|| format!("{}", o.calibration.display()))?;
    let targets = correct::read_targets(o.targets)?;
    // The file's navigation-chain correction network (`calibrate navchain`), when it has one.
    let net = crate::navchain::correction::from_calibration(&cal)
        .with_context(|| format!("{}", o.calibration.display()))?;
    let rows = match &net {
        Some(b) => {
            let (rows, largest) = crate::navchain::correct_targets::correct_targets_with_net(
                &calibrated,
                &nominal,
                &targets,
                b,
            )?;
            log(&format!(
                "the calibration's correction network (navchain_net, 6-{}-6) is applied: \
                 positions corrected by up to {largest:.3} mm",
                b.hidden
            ));
            rows
        }
        None => correct::correct_targets(&calibrated, &nominal, &targets)?,
    };
    let errs: Vec<f64> = rows.iter().filter_map(|r| r.nominal_pos_err_mm).collect();
    log(&format!(
        "{} targets → {} corrected joint targets (every branch within the limits); the nominal \
         command would miss by RMS {:.3} mm, max {:.3} mm on the calibrated robot",
        targets.len(),
        rows.len(),
        crate::solve::stats::rms(&errs),
        errs.iter().cloned().fold(0.0, f64::max)
    ));
    let name = o
        .targets
        .file_stem()
        .map_or("corrected".into(), |s| s.to_string_lossy().into_owned());
    Ok(match o.output {
        Output::Csv => correct::to_csv(&rows)?,
        Output::Urscript => crate::plan::export::poses_to_urscript(
            &name,
            &correct::as_plan_poses(&rows),
            o.speed,
            o.accel,
            o.wait,
        ),
        Output::Pacscript => crate::plan::export::poses_to_pacscript(
            &name,
            &correct::as_plan_poses(&rows),
            o.speed,
            o.wait,
        ),
    })
}
