//! The laser (range sensor) glue between files and [`crate::solve::laser`]: the held-out
//! targets of a second file, the diagnosis of a laser dataset into a directory (what
//! `robocal diagnose` runs on a laser dataset) and the reconstruction of a scan.
use anyhow::{bail, Context as _};
use nalgebra::Point3;
use std::path::Path;

use crate::dataset::{CalibrationFile, Dataset};
use crate::solve::laser;

/// Reconstruct a scan with `beam`: per-face points (by `target` label, `-` when unlabelled),
/// face angles and flatness; writes `DIR/scan_report.json` and the PLY when asked. Returns the
/// console lines.
pub fn scan_report(
    beam: &laser::Beam,
    scan: &Path,
    out_dir: &Path,
    ply_path: Option<&Path>,
) -> anyhow::Result<String> {
    let ds = Dataset::load(scan)?;
    let obs = laser::observations(&ds)
        .with_context(|| format!("reading laser poses of {}", scan.display()))?;
    let mut faces: std::collections::BTreeMap<String, Vec<Point3<f64>>> = Default::default();
    let mut all = Vec::new();
    for o in &obs {
        let p = beam.spot(&o.flange, o.d);
        faces
            .entry(o.target.clone().unwrap_or_else(|| "-".into()))
            .or_default()
            .push(p);
        all.push(p);
    }
    if all.is_empty() {
        bail!("{}: no pose record with a valid range", scan.display());
    }
    let angles = laser::face_angles(&faces);
    let mut flat = Vec::new();
    let mut s = format!(
        "scan {}: {} points, {} face(s)\n",
        scan.display(),
        all.len(),
        faces.len()
    );
    for (k, pts) in &faces {
        if let Some(pl) = laser::fit::pca_plane(pts) {
            let (rms, max, _) = laser::plane_stats(pts, &pl);
            s.push_str(&format!(
                "  face {k}: {} points, flatness RMS {rms:.4} mm, max {max:.4} mm\n",
                pts.len()
            ));
            flat.push(crate::schema::FaceFlatness {
                face: k.clone(),
                points: pts.len(),
                rms_mm: rms,
                max_mm: max,
            });
        }
    }
    for (a, b, deg) in &angles {
        s.push_str(&format!("  angle {a}/{b}: {deg:.3} deg\n"));
    }
    crate::schema::write(
        &out_dir.join("scan_report.json"),
        &crate::schema::ScanReportFile {
            format: crate::schema::SCAN_REPORT_FORMAT.into(),
            scan: scan.display().to_string(),
            points: all.len(),
            faces: flat,
            angles: angles
                .iter()
                .map(|(a, b, d)| crate::schema::FaceAngle {
                    a: a.clone(),
                    b: b.clone(),
                    angle_deg: *d,
                })
                .collect(),
        },
    )?;
    if let Some(p) = ply_path {
        crate::fsio::write(
            p,
            laser::ply(&all, &format!("robocal laser scan of {}", scan.display())),
        )
        .with_context(|| format!("writing {}", p.display()))?;
        s.push_str(&format!("  wrote {}\n", p.display()));
    }
    Ok(s)
}

/// The validation (target) poses of a `--heldout` file: read strictly, checked for
/// plausibility and for the robot of `ds`; an error when it has none (never silently
/// dropped).
pub fn load_heldout(
    h: &Path,
    ds: &Dataset,
    data: &Path,
    arm: Option<&laser::IdentifiedArm>,
) -> anyhow::Result<Vec<laser::LaserObs>> {
    let hd = Dataset::load(h)?;
    crate::plausible::check_same_robot(
        &ds.header.robot,
        data,
        &hd.header.robot,
        h,
        "held-out file",
    )?;
    crate::plausible::check_dataset(&hd, h)?;
    let v: Vec<laser::LaserObs> = laser::observations_through(&hd, arm)
        .with_context(|| format!("reading laser poses of {}", h.display()))?
        .into_iter()
        .filter(|o| o.target.is_some())
        .collect();
    anyhow::ensure!(
        !v.is_empty(),
        "{}: no usable held-out poses (laser poses with a `target` label and a range reading)",
        h.display()
    );
    Ok(v)
}

/// Whether `ds` is a laser (range sensor) dataset: pose records with ranges, calibration-plane
/// labels, and no tracked marker.
pub fn is_laser_dataset(ds: &Dataset) -> bool {
    let mut any_plane = false;
    for p in ds.poses() {
        if p.marker.is_some() {
            return false;
        }
        any_plane |= p.plane.is_some() && p.range.is_some();
    }
    any_plane
}

/// `robocal diagnose` on a laser dataset: fit the beam, then test the laser effects
/// (`laser_scale`, `laser_incidence`, `laser_nonlinearity`) and add the significant ones.
/// Writes `DIR/diagnosis.json` and `DIR/calibration.json` (with the effects); returns the
/// console summary.
pub fn diagnose_laser(data: &Path, heldout: Option<&Path>, out: &Path) -> anyhow::Result<String> {
    let ds = crate::plausible::load_checked(data)?;
    let obs = laser::observations(&ds)
        .with_context(|| format!("reading laser poses of {}", data.display()))?;
    let train: Vec<laser::LaserObs> = obs.iter().filter(|o| o.plane.is_some()).cloned().collect();
    let mut validation: Vec<laser::LaserObs> =
        obs.iter().filter(|o| o.target.is_some()).cloned().collect();
    if let Some(h) = heldout {
        validation.extend(load_heldout(h, &ds, data, None)?);
    }
    let cmp = laser::compare(&train, &validation, None, None).context("laser base fit")?;
    let beam = cmp.final_beam.context("no beam")?;
    let diag = laser::effects::diagnose(&train, &validation, &beam, &cmp.final_planes)
        .context("laser effect diagnosis")?;
    let final_beam = diag.beam.unwrap_or(beam);
    let mut cal = CalibrationFile::new(
        ds.header.robot.clone(),
        laser::beam_params(&final_beam, None),
    );
    cal.set_kind("laser");
    cal.effects = diag.cal_effects();
    cal.metrics
        .insert("plane_rms_mm_before".into(), diag.rms_before_mm.into());
    cal.metrics
        .insert("plane_rms_mm_after".into(), diag.rms_after_mm.into());
    if let (Some(b), Some(a)) = (diag.spread_before_mm, diag.spread_after_mm) {
        cal.metrics.insert("spread_mm_before".into(), b.into());
        cal.metrics.insert("spread_mm_after".into(), a.into());
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    cal.save(out.join("calibration.json"))?;
    crate::schema::write(
        &out.join("diagnosis.json"),
        &diag.to_file(train.len(), validation.len()),
    )?;
    let mut s = format!(
        "laser diagnosis of {}: point-to-plane RMS {:.4} mm",
        data.display(),
        diag.rms_before_mm
    );
    for f in &diag.findings {
        s.push_str(&format!(
            "\n  -> {} (F = {:.1}, p = {:.2e}, dBIC = {:.1}; {:.1} {} ± {:.1}) -> RMS {:.4} mm",
            f.kind,
            f.f_stat,
            f.p_value,
            f.delta_bic,
            f.sensor_value,
            f.sensor_unit,
            f.coef_std * if f.sensor_unit == "ppm" { 1e6 } else { 1.0 },
            f.rms_after_mm
        ));
    }
    if diag.findings.is_empty() {
        s.push_str("\n  no laser effect is significant");
    }
    if let (Some(b), Some(a)) = (diag.spread_before_mm, diag.spread_after_mm) {
        s.push_str(&format!("\n  5-direction spread {b:.4} -> {a:.4} mm"));
    }
    s.push_str(&format!(
        "\n  wrote {}",
        out.join("calibration.json").display()
    ));
    Ok(s)
}
