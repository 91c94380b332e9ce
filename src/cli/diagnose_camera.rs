//! `robocal diagnose` on a camera dataset (its header has a `camera` block): the camera
//! diagnosis of [`crate::diagnose::camera`]. Writes `DIR/diagnosis.json` and
//! `DIR/calibration.json` (the final camera calibration with the effects found).
use std::path::Path;

use anyhow::Context as _;

use crate::dataset::Dataset;
use crate::solve::camera::data::{load, Overrides};

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
    let d = crate::diagnose::camera::diagnose(
        &train.data,
        held.as_ref().map(|h| &h.data),
        &train.dataset,
        held.as_ref().map(|h| &h.dataset),
    )?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let file = d.to_file();
    crate::fsio::write(
        out.join("diagnosis.json"),
        serde_json::to_string_pretty(&file)? + "\n",
    )
    .with_context(|| format!("writing {}", out.join("diagnosis.json").display()))?;
    let mut s = String::new();
    let fmt = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.4}"));
    s += &format!(
        "camera diagnosis: held-out {} px -> {} px (train {:.4} -> {:.4} px)\n",
        fmt(file.heldout_rms_px_before),
        fmt(file.heldout_rms_px_after),
        file.train_rms_px_before,
        file.train_rms_px_after
    );
    for e in &d.effects {
        s += &format!(
            "  effect {}: {} (F {:.1}; held-out {} -> {} px; hand-eye moved {:.4} mm {:.5} deg)\n",
            e.kind,
            e.summary,
            e.evidence.f_stat,
            fmt(e.heldout_rms_before_px),
            fmt(e.heldout_rms_after_px),
            e.hand_eye_change_mm,
            e.hand_eye_change_deg
        );
    }
    for r in &d.rejected {
        s += &format!("  not significant: {} (F {:.1})\n", r.kind, r.f_stat);
    }
    if d.effects.is_empty() {
        s += "  no effect found: the camera model explains the residual\n";
    }
    Ok(s)
}
