//! `robocal diagnose` on a camera dataset (its header has a `camera` block): the camera
//! diagnosis of [`crate::diagnose::camera`]. Writes `DIR/diagnosis.json`
//! (`robocal-diagnosis/2`, [`crate::schema::DiagnosisFile`], RMS in `_px` fields) and
//! `DIR/calibration.json` (the final camera calibration with the effects found: board scale
//! and bend in the camera block, the arm's identified kinematics in `params`, the flange map in
//! `camera.flange_map`).
use std::path::Path;

use anyhow::Context as _;

use crate::dataset::Dataset;
use crate::solve::camera::data::{load, Loaded, Overrides};
use crate::solve::camera::CameraResult;

/// Whether `data` is a camera dataset (header `camera` block).
pub fn is_camera_dataset(data: &Path) -> bool {
    Dataset::load(data).is_ok_and(|d| d.header.camera().ok().flatten().is_some())
}

/// Run the camera diagnosis; returns the console summary.
pub fn run(data: &Path, heldout: Option<&Path>, out: &Path) -> anyhow::Result<String> {
    let ov = Overrides::default();
    let train = load(data, &ov, false).with_context(|| format!("reading {}", data.display()))?;
    let held = heldout
        .map(|h| load(h, &ov, false).with_context(|| format!("reading {}", h.display())))
        .transpose()?;
    run_loaded(&train, held.as_ref(), None, out)
}

/// [`run`] on camera datasets already read (and their boards detected), from `base`, the
/// calibration of the same views when it is already made (`None`: calibrated here).
pub fn run_loaded(
    train: &Loaded,
    held: Option<&Loaded>,
    base: Option<CameraResult>,
    out: &Path,
) -> anyhow::Result<String> {
    let d = crate::diagnose::camera::diagnose_from(
        base,
        &train.data,
        held.as_ref().map(|h| &h.data),
        &train.dataset,
        held.as_ref().map(|h| &h.dataset),
    )?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let file = d.to_file();
    crate::schema::write(&out.join("diagnosis.json"), &file)?;
    // The final calibration: the maximum-likelihood fit with every accepted effect.
    let mut res = d.calibration.clone();
    res.ml = d.last().clone();
    res.board_scale = d.scale;
    res.board_bend_mm = d.bend_mm;
    res.uncertainty = d.uncertainty.clone();
    let mut cal = crate::solve::camera::calfile::calibration_file(train, &res);
    if let Some(arm) = &d.arm {
        arm.write_into(&mut cal);
    }
    if let Some(m) = &d.flange_map {
        let mut b = cal
            .camera()
            .map_err(|e| anyhow::anyhow!("calibration: {e}"))?
            .context("calibration: no camera block")?;
        b.flange_map = Some(m.block());
        cal.set_camera(&b);
    }
    crate::dataset::write_calibration(out.join("calibration.json"), &cal)
        .with_context(|| format!("writing {}", out.join("calibration.json").display()))?;
    let mut s = String::new();
    let fmt = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.4}"));
    s += &format!(
        "camera diagnosis: held-out {} px -> {} px (train {} -> {} px)\n",
        fmt(file.heldout_rms.base_model_px),
        fmt(file.heldout_rms.final_px),
        fmt(file.train_rms.base_model_px),
        fmt(file.train_rms.final_px)
    );
    for e in &d.effects {
        s += &format!(
            "  effect {}: {} (F {:.1}; held-out {} -> {} px; hand-eye moved {:.4} mm {:.5} deg)\n",
            e.kind,
            e.summary,
            e.evidence.f.unwrap_or(f64::NAN),
            fmt(e.heldout_rms_before_px),
            fmt(e.heldout_rms_after_px),
            e.hand_eye_change_mm,
            e.hand_eye_change_deg
        );
    }
    for r in &d.rejected {
        s += &format!("  not significant: {} (F {:.1})\n", r.kind, r.f_stat);
    }
    for f in d.findings() {
        s += &format!("  {f}\n");
    }
    if d.effects.is_empty() && !d.robot_dominates() {
        s += "  no effect found: the camera model explains the residual\n";
    }
    Ok(s)
}
