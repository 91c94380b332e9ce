//! `robocal calibrate robot-world --data D.jsonl --out robot_world.json`: tracker ↔ robot base
//! (`AX = YB`) from pose records (flange pose or nominal FK of `q`, marker pose): Shah, Li
//! and seed 003's Tsai route in closed form, then the joint LM refinement (weighted by
//! `--tracker-model`). With `--check PREV.json` it is the quick on-site registration check:
//! ~20 poses, no kinematic identification, pass/fail against `--tol-mm`.
use std::path::PathBuf;

use anyhow::bail;

use crate::register::robot_world::{self as rw, RobotWorldFile};

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

/// Largest residual rotation RMS (deg) of a robot-world fit that is written.
pub const MAX_RESIDUAL_DEG: f64 = 5.0;
/// Largest residual position RMS (mm) of a robot-world fit that is written.
pub const MAX_RESIDUAL_MM: f64 = 10.0;

/// Run it.
pub fn exec(a: Args) -> anyhow::Result<()> {
    let ds = crate::dataset::Dataset::load(&a.data)?;
    let (obs, skipped) = rw::observations_from_dataset(&ds)?;
    for (id, why) in skipped.iter().take(10) {
        eprintln!("skipped pose {id}: {why}");
    }
    if obs.len() < 3 {
        bail!(
            "{}: {} usable poses (need ≥ 3 with marker orientation; ~20 for a check): {}",
            a.data.display(),
            obs.len(),
            rw::skip_summary(&skipped)
        );
    }
    let model = a
        .tracker_model
        .as_deref()
        .map(crate::register::run::load_model)
        .transpose()?;
    let shah = rw::shah(&obs)?;
    let li = rw::li(&obs)?;
    let tsai = rw::tsai_route(&obs)?;
    let start = match a.start.as_str() {
        "shah" => shah,
        "li" => li,
        "tsai" => tsai,
        s => bail!("--start `{s}`: use shah, li or tsai"),
    };
    let o = rw::RefineOptions {
        tracker_model: model,
        sigma_pos_mm: a.sigma_pos_mm,
        sigma_rot_deg: a.sigma_rot_deg,
    };
    let r = rw::refine(&obs, start, &o)?;
    println!(
        "robot-world: {} poses, residual RMS {:.3} mm / {:.4} deg, reduced chi2 {:.2}",
        obs.len(),
        r.rms_pos_mm,
        r.rms_rot_deg,
        r.chi2_reduced
    );
    for (name, (_, y)) in [("shah", shah), ("li", li), ("tsai", tsai)] {
        println!(
            "  closed form {name:<5}: Y differs from refined by {:.3} mm, {:.4} deg",
            (y.translation.vector - r.y.translation.vector).norm(),
            y.rotation.angle_to(&r.y.rotation).to_degrees()
        );
    }
    // A marker rigid on the flange leaves a fraction of a degree and of a millimetre: a fit
    // that leaves degrees or centimetres explains nothing, whatever its covariance says
    // (a wrong unit or pose convention fits badly, not loosely). Refused before anything is
    // written, with the likely cause.
    if !(r.rms_rot_deg.is_finite() && r.rms_rot_deg <= MAX_RESIDUAL_DEG) {
        bail!(
            "{}: the fit leaves {:.2}° RMS between the marker orientations and the flange's \
             (a rigid marker leaves < {MAX_RESIDUAL_DEG}°): likely quaternions in [x, y, z, w] \
             order (robocal reads [w, x, y, z]), orientations of another body, or a marker that \
             moved on the flange; nothing written",
            a.data.display(),
            r.rms_rot_deg
        );
    }
    if !(r.rms_pos_mm.is_finite() && r.rms_pos_mm <= MAX_RESIDUAL_MM) {
        bail!(
            "{}: the fit leaves {:.2} mm RMS (a rigid marker leaves < {MAX_RESIDUAL_MM} mm): \
             likely positions in metres or mixed units, or a marker that moved on the flange; \
             nothing written",
            a.data.display(),
            r.rms_pos_mm
        );
    }
    let mut fail = false;
    if let Some(prev) = &a.check {
        let p = RobotWorldFile::load(prev)?;
        let (py, _) = p.y()?;
        let c = rw::check(&r, &py, &obs, a.tol_mm);
        println!(
            "check vs {}: rotation change {:.4} deg, largest shift {:.3} mm ({:.1} sigma) -> {}",
            prev.display(),
            c.rot_change_deg,
            c.max_shift_mm,
            c.shift_sigma,
            if c.pass { "PASS" } else { "FAIL" }
        );
        fail = !c.pass;
    }
    let f = RobotWorldFile::new(
        &r,
        obs.len(),
        &[("shah", shah), ("li", li), ("tsai", tsai)],
        model,
    );
    f.save(&a.out)?;
    println!("wrote {}", a.out.display());
    if fail {
        bail!(
            "registration check failed: the tracker moved relative to the robot by more than {} mm",
            a.tol_mm
        );
    }
    Ok(())
}
