//! The robot-world registration of `robocal calibrate robot-world` as a library call: tracker ↔
//! robot base (`AX = YB`) from pose records (flange pose or nominal FK of `q`, marker pose):
//! Shah, Li and seed 003's Tsai route in closed form, then the joint LM refinement (weighted by
//! a tracker noise model). With a previous `robot_world.json` it is the quick on-site
//! registration check. Three steps, so that the CLI prints each as it comes: [`load`] (the
//! usable poses and why others were skipped), [`fit`] (closed forms + refinement), [`finish`]
//! (the residual limits, the check, the file).
use std::path::{Path, PathBuf};

use anyhow::bail;
use nalgebra::Isometry3;

use crate::register::robot_world::{self as rw, CheckResult, RobotWorld, RobotWorldFile, RwObs};
use crate::register::StereoTrackerModel;

/// Largest residual rotation RMS (deg) of a robot-world fit that is written.
pub const MAX_RESIDUAL_DEG: f64 = 5.0;
/// Largest residual position RMS (mm) of a robot-world fit that is written.
pub const MAX_RESIDUAL_MM: f64 = 10.0;

/// How to fit.
#[derive(Debug, Clone)]
pub struct FitOptions {
    /// Stereo tracker noise model (JSON) for the weights.
    pub tracker_model: Option<PathBuf>,
    /// Position noise per axis added to the model (mm): robot repeatability.
    pub sigma_pos_mm: f64,
    /// Marker orientation noise per axis (deg).
    pub sigma_rot_deg: f64,
    /// Closed form that starts the refinement: shah, li or tsai.
    pub start: String,
}

/// The usable poses of a dataset and the skipped ones (id, why).
#[derive(Debug, Clone)]
pub struct Poses {
    /// The dataset read.
    pub data: PathBuf,
    /// Usable poses.
    pub obs: Vec<RwObs>,
    /// Skipped poses: id and reason.
    pub skipped: Vec<(u64, String)>,
}

/// A closed form's name and its solution (`X`, `Y`).
pub type ClosedForm = (&'static str, (Isometry3<f64>, Isometry3<f64>));

/// A fitted registration: the refined solution and its closed-form starts.
#[derive(Debug, Clone)]
pub struct Fit {
    /// The refinement.
    pub refined: RobotWorld,
    /// The closed forms (`X`, `Y`): shah, li, tsai.
    pub closed: [ClosedForm; 3],
    /// The noise model the weights came from.
    pub model: Option<StereoTrackerModel>,
}

/// The pose records of the dataset `data`.
pub fn load(data: &Path) -> anyhow::Result<Poses> {
    let ds = crate::dataset::Dataset::load(data)?;
    let (obs, skipped) = rw::observations_from_dataset(&ds)?;
    Ok(Poses {
        data: data.to_path_buf(),
        obs,
        skipped,
    })
}

/// The closed forms and the refinement started from `o.start`.
pub fn fit(p: &Poses, o: &FitOptions) -> anyhow::Result<Fit> {
    let obs = &p.obs;
    if obs.len() < 3 {
        bail!(
            "{}: {} usable poses (need ≥ 3 with marker orientation; ~20 for a check): {}",
            p.data.display(),
            obs.len(),
            rw::skip_summary(&p.skipped)
        );
    }
    let model = o
        .tracker_model
        .as_deref()
        .map(crate::register::run::load_model)
        .transpose()?;
    let shah = rw::shah(obs)?;
    let li = rw::li(obs)?;
    let tsai = rw::tsai_route(obs)?;
    let start = match o.start.as_str() {
        "shah" => shah,
        "li" => li,
        "tsai" => tsai,
        s => bail!("--start `{s}`: use shah, li or tsai"),
    };
    let ro = rw::RefineOptions {
        tracker_model: model,
        sigma_pos_mm: o.sigma_pos_mm,
        sigma_rot_deg: o.sigma_rot_deg,
    };
    let refined = rw::refine(obs, start, &ro)?;
    Ok(Fit {
        refined,
        closed: [("shah", shah), ("li", li), ("tsai", tsai)],
        model,
    })
}

/// Refuses a fit that explains nothing, checks it against `check` = (previous file,
/// tolerance mm) and writes `out`. Returns the check's result (the caller fails on a FAIL,
/// after the file is written).
pub fn finish(
    p: &Poses,
    f: &Fit,
    check: Option<(&Path, f64)>,
    out: &Path,
) -> anyhow::Result<Option<CheckResult>> {
    let r = &f.refined;
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
            p.data.display(),
            r.rms_rot_deg
        );
    }
    if !(r.rms_pos_mm.is_finite() && r.rms_pos_mm <= MAX_RESIDUAL_MM) {
        bail!(
            "{}: the fit leaves {:.2} mm RMS (a rigid marker leaves < {MAX_RESIDUAL_MM} mm): \
             likely positions in metres or mixed units, or a marker that moved on the flange; \
             nothing written",
            p.data.display(),
            r.rms_pos_mm
        );
    }
    let checked = match check {
        Some((prev, tol_mm)) => {
            let (py, _) = RobotWorldFile::load(prev)?.y()?;
            Some(rw::check(r, &py, &p.obs, tol_mm))
        }
        None => None,
    };
    RobotWorldFile::new(r, p.obs.len(), &f.closed, f.model).save(out)?;
    Ok(checked)
}
