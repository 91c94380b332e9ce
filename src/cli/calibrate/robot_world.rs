//! `robocal calibrate robot-world --data D.jsonl --out robot_world.json`: tracker ↔ robot base
//! (`AX = YB`) from pose records (flange pose or nominal FK of `q`, marker pose): Shah, Li
//! and seed 003's Tsai route in closed form, then the joint LM refinement (weighted by
//! `--tracker-model`). With `--check PREV.json` it is the quick on-site registration check:
//! ~20 poses, no kinematic identification, pass/fail against `--tol-mm`.
//! The work is in [`crate::calibrate::robot_world`]; this file parses and prints.
use std::path::PathBuf;

use anyhow::bail;

use crate::calibrate::robot_world::{self as rw, FitOptions};
pub use crate::calibrate::robot_world::{MAX_RESIDUAL_DEG, MAX_RESIDUAL_MM};

/// Arguments of `robocal calibrate robot-world`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset with pose records (flange pose or `q`, marker `p` + `quat`).
    #[arg(long, value_name = "D.jsonl")]
    pub data: PathBuf,
    /// Stereo tracker noise model (JSON) for the weights.
    #[arg(long, value_name = "M.json")]
    pub tracker_model: Option<PathBuf>,
    /// Position noise per axis added to the model (mm): robot repeatability.
    #[arg(long, default_value_t = 0.05)]
    pub sigma_pos_mm: f64,
    /// Marker orientation noise per axis (deg).
    #[arg(long, default_value_t = 0.05)]
    pub sigma_rot_deg: f64,
    /// Closed form that starts the refinement: shah, li or tsai.
    #[arg(long, default_value = "shah")]
    pub start: String,
    /// Previous `robot_world.json` to check against (on-site registration check).
    #[arg(long, value_name = "PREV.json")]
    pub check: Option<PathBuf>,
    /// Check tolerance: largest shift of the working volume (mm).
    #[arg(long, default_value_t = 0.5)]
    pub tol_mm: f64,
    /// Output file.
    #[arg(long, value_name = "robot_world.json")]
    pub out: PathBuf,
}

/// Run it.
pub fn exec(a: Args) -> anyhow::Result<()> {
    let poses = rw::load(&a.data)?;
    for (id, why) in poses.skipped.iter().take(10) {
        eprintln!("skipped pose {id}: {why}");
    }
    let fit = rw::fit(
        &poses,
        &FitOptions {
            tracker_model: a.tracker_model,
            sigma_pos_mm: a.sigma_pos_mm,
            sigma_rot_deg: a.sigma_rot_deg,
            start: a.start,
        },
    )?;
    let r = &fit.refined;
    println!(
        "robot-world: {} poses, residual RMS {:.3} mm / {:.4} deg, reduced chi2 {:.2}",
        poses.obs.len(),
        r.rms_pos_mm,
        r.rms_rot_deg,
        r.chi2_reduced
    );
    for (name, (_, y)) in &fit.closed {
        println!(
            "  closed form {name:<5}: Y differs from refined by {:.3} mm, {:.4} deg",
            (y.translation.vector - r.y.translation.vector).norm(),
            y.rotation.angle_to(&r.y.rotation).to_degrees()
        );
    }
    let check = a.check.as_deref().map(|prev| (prev, a.tol_mm));
    let checked = rw::finish(&poses, &fit, check, &a.out)?;
    if let (Some(c), Some(prev)) = (&checked, &a.check) {
        println!(
            "check vs {}: rotation change {:.4} deg, largest shift {:.3} mm ({:.1} sigma) -> {}",
            prev.display(),
            c.rot_change_deg,
            c.max_shift_mm,
            c.shift_sigma,
            if c.pass { "PASS" } else { "FAIL" }
        );
    }
    println!("wrote {}", a.out.display());
    if checked.is_some_and(|c| !c.pass) {
        bail!(
            "registration check failed: the tracker moved relative to the robot by more than {} mm",
            a.tol_mm
        );
    }
    Ok(())
}
