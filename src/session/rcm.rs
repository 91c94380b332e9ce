//! The RCM endoscope session (seed 002): the hand-eye of an endoscope camera fixed in the
//! robot base, from the images of an instrument shaft the robot pivots about a trocar.
//!
//! Stages (in this order; `session.json` records each, `--resume` continues):
//! 1. plan: RCM pivots about the trocar (`[rcm]` of `plans/seed002-rcm.toml`, `--poses`) and a
//!    separate held-out set (another seed, `--heldout-points`) (`plan/train.json`,
//!    `plan/validation.json`);
//! 2. acquire-train / 3. acquire-validation: an endoscope image at every pose (`run-train/`,
//!    `run-validation/`: the controller's flange and the image);
//! 4. calibrate: each run's dataset with the cell's stated endoscope intrinsics and shaft
//!    radius as an RCM dataset (`run-<set>/endoscope.jsonl`, what `robocal calibrate rcm
//!    --data` reads), the shaft's silhouette lines detected in every image (views the detector
//!    refuses are listed and left out), seed 002's two-step then the ML refinement with a
//!    bootstrap over poses (`calibrate/calibration.json`, `calibrate/rcm_report.json`);
//! 5. diagnose: no effect model for this cell (recorded as such);
//! 6. validate: the held-out views' silhouettes predicted by the seed's hand-eye ("before")
//!    and by the ML hand-eye ("after"); the held-out views calibrated on their own, as an
//!    independent check of the stated interval; `deploy/calibration.json`;
//! 7. verify: not applicable (nothing is commanded with the camera); 8. report.
//!
//! Never reads the simulator's truth: every figure is a pixel distance between detected and
//! predicted silhouettes, or a difference between two calibrations.
use std::path::{Path, PathBuf};

use anyhow::{bail, Context as _};
use nalgebra::{DVector, Isometry3};
use serde::{Deserialize, Serialize};

use super::laser::{fit_timing, plan_set};
use super::{acquire_set, load_ds, stage_done, write_atomic, Cell, Log, SessionFile, Stage};
use crate::dataset::endoscope::{EndoscopeCamera, InstrumentBlock};
use crate::dataset::CalibrationFile;
use crate::plan::PlanSpec;
use crate::solve::lm::LsqProblem as _;
use crate::solve::rcm::{self, ml, RcmData, RcmObs};

/// The default plan spec of an RCM session.
pub const SPEC: &str = include_str!("../../plans/seed002-rcm.toml");
/// The default acceptance spec of an RCM session.
pub const ACCEPT: &str = include_str!("../../accept/rcm.toml");
/// Bootstrap resamples over poses for the deployed hand-eye's interval.
pub const BOOTSTRAP: usize = 100;

/// What the cell file states about an RCM cell: the endoscope's intrinsics (its own prior
/// calibration) and the instrument's shaft radius.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EndoscopeCell {
    /// The endoscope's device name.
    pub name: String,
    /// Intrinsics and distortion (`kind: "endoscope"`).
    pub camera: EndoscopeCamera,
    /// Shaft radius (mm).
    pub shaft_radius_mm: f64,
}

/// A hand-eye (camera in the robot base) with its 1-σ.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HandEyeSummary {
    pub xyz_mm: [f64; 3],
    /// `[w, x, y, z]`.
    pub quat: [f64; 4],
    pub std_mm: [f64; 3],
    pub std_deg: [f64; 3],
}

/// `session.json` `rcm`: what the RCM session found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RcmSummary {
    /// Views with detected lines used (training, held-out).
    pub views_train: usize,
    pub views_heldout: usize,
    /// Views the line detector refused (either set), with the reason.
    pub refused: Vec<String>,
    /// The detector's end-point 1-σ over the training views (px): median, worst (none when
    /// the lines came with the dataset instead of from images).
    pub detector_sigma_px: Option<[f64; 2]>,
    /// RMS end-point distance of the training fit (px).
    pub train_rms_px: f64,
    /// Held-out RMS end-point distance (px): seed 002's two-step hand-eye, the ML hand-eye.
    pub heldout_rms_px_seed: f64,
    pub heldout_rms_px_ml: f64,
    /// The deployed hand-eye (ML, bootstrap 1-σ).
    pub hand_eye: HandEyeSummary,
    /// The held-out views' own hand-eye: its distance from the deployed one (mm, deg).
    pub heldout_hand_eye_diff: Option<[f64; 2]>,
    /// Seed two-step → ML (mm, deg).
    pub seed_to_ml: [f64; 2],
    /// The RCM in the base and the robot axes' RMS distance from it (mm).
    pub rcm_base_mm: [f64; 3],
    pub rcm_axes_rms_mm: f64,
}

/// The cell's endoscope block, or why a session cannot run without it.
fn endoscope(s: &SessionFile) -> anyhow::Result<&EndoscopeCell> {
    s.cell.endoscope.as_ref().context(
        "the cell file states no endoscope (a fixed camera with its intrinsics) and no RCM \
         instrument (`[scene.instrument]` with `radius_mm`): an RCM session needs both",
    )
}

/// The session's train and held-out plan specs, fitted to the cell.
fn session_specs(dir: &Path, s: &SessionFile) -> anyhow::Result<(PlanSpec, PlanSpec)> {
    let p = dir.join(&s.setup.spec_file);
    let mut spec = PlanSpec::from_file(&p).with_context(|| format!("reading {}", p.display()))?;
    let Some(r) = spec.rcm.as_mut() else {
        bail!(
            "{}: an RCM session needs an [rcm] plan spec (see plans/seed002-rcm.toml)",
            p.display()
        );
    };
    r.points = s.setup.poses;
    fit_timing(&mut spec, s);
    let mut val = spec.clone();
    val.name = format!("{}-validation", spec.name);
    val.seed = spec.seed.wrapping_add(1);
    val.group = "validation".into();
    if let Some(r) = val.rcm.as_mut() {
        r.points = s.setup.heldout_points;
    }
    Ok((spec, val))
}

/// The run dataset of `role` with the cell's endoscope and instrument blocks, written beside
/// it (`run-<role>/endoscope.jsonl`, images named relative to it as in the run), and read as
/// RCM data (lines detected in the images).
fn rcm_data(dir: &Path, s: &SessionFile, role: &str) -> anyhow::Result<(PathBuf, RcmData)> {
    let e = endoscope(s)?;
    let (p, mut ds) = load_ds(dir, s, role)?;
    ds.header.extra.insert(
        "camera".into(),
        serde_json::to_value(&e.camera).context("endoscope block")?,
    );
    ds.header.extra.insert(
        "instrument".into(),
        serde_json::to_value(InstrumentBlock {
            shaft_radius_mm: e.shaft_radius_mm,
        })?,
    );
    let out = p.with_file_name("endoscope.jsonl");
    ds.save(&out)
        .with_context(|| format!("writing {}", out.display()))?;
    let back = crate::dataset::Dataset::load(&out)?;
    let mut data = RcmData::from_dataset(&back, &out)
        .with_context(|| format!("reading the {role} views ({})", out.display()))?;
    screen_lines(&mut data, role);
    Ok((out, data))
}

/// A line fitted this much worse than the set's typical line (RMS of its edge points) is not
/// one straight silhouette: part of it is another edge (a tissue blob hiding the shaft, the
/// jaw beyond the tip).
pub const LINE_RMS_FACTOR: f64 = 3.0;
/// ... and at least this bad (px): a set of very clean lines does not refuse a clean one.
pub const LINE_RMS_FLOOR_PX: f64 = 0.3;

/// Refuses the views of `data` with a line whose fit RMS exceeds both [`LINE_RMS_FLOOR_PX`]
/// and [`LINE_RMS_FACTOR`] × the median over the set's lines. Uses only the images (the
/// detector's own quality figures), never a calibration: the same rule on training and
/// held-out views.
pub fn screen_lines(data: &mut RcmData, role: &str) {
    let all: Vec<f64> = data
        .detected
        .iter()
        .flat_map(|(_, d)| d.lines.iter().map(|l| l.rms_px))
        .collect();
    if all.len() < 6 {
        return;
    }
    let gate = (LINE_RMS_FACTOR * crate::solve::stats::quantile(&all, 0.5)).max(LINE_RMS_FLOOR_PX);
    let bad: Vec<(u64, f64)> = data
        .detected
        .iter()
        .filter_map(|(id, d)| {
            let worst = d.lines.iter().map(|l| l.rms_px).fold(0.0f64, f64::max);
            (worst > gate).then_some((*id, worst))
        })
        .collect();
    for (id, worst) in &bad {
        data.refused.push(format!(
            "{role} pose {id}: a silhouette's edge points lie {worst:.3} px RMS from its line \
             (more than {gate:.3} px, {LINE_RMS_FACTOR}× the set's median): part of it is \
             another edge (occluding tissue or the jaw)"
        ));
    }
    data.obs.retain(|o| !bad.iter().any(|(id, _)| *id == o.id));
    data.detected
        .retain(|(id, _)| !bad.iter().any(|(b, _)| b == id));
}

/// RMS end-point distance (px) of `obs` from the silhouettes predicted with camera pose `pose`.
pub fn rms_px(data: &RcmData, obs: &[RcmObs], pose: &Isometry3<f64>) -> f64 {
    if obs.is_empty() {
        return f64::NAN;
    }
    let p = ml::MlProblem::new(
        data.k,
        data.radius,
        obs.iter().map(RcmObs::axis).collect(),
        obs.iter().map(|o| o.segs).collect(),
        pose,
    );
    let r = p.residuals(&DVector::zeros(6));
    (r.norm_squared() / r.len() as f64).sqrt()
}

/// Runs (or continues) an RCM session.
pub fn run(
    dir: &Path,
    mut s: SessionFile,
    cell: &mut dyn Cell,
    log: Log,
) -> anyhow::Result<SessionFile> {
    if !s.done(Stage::Plan) {
        endoscope(&s)?;
        log("plan: RCM pivots about the trocar (training) and a separate held-out set");
        let (train, val) = session_specs(dir, &s)?;
        s.poses_planned = 0;
        s.predicted_duration_s = 0.0;
        s.plan_rejects.clear();
        plan_set(dir, &mut s, &train, "train", &mut *log)?;
        plan_set(dir, &mut s, &val, "validation", &mut *log)?;
        stage_done(dir, &mut s, Stage::Plan)?;
    }
    if s.setup.plan_only {
        return Ok(s);
    }
    for (stage, set) in [
        (Stage::AcquireTrain, "train"),
        (Stage::AcquireValidation, "validation"),
    ] {
        if !s.done(stage) {
            acquire_set(dir, &mut s, cell, set, &mut *log)?;
            stage_done(dir, &mut s, stage)?;
        }
    }
    if !s.done(Stage::Calibrate) {
        log("calibrate: shaft lines detected in the training images → seed 002 two-step → ML");
        calibrate_stage(dir, &mut s, &mut *log)?;
        stage_done(dir, &mut s, Stage::Calibrate)?;
    }
    if !s.done(Stage::Diagnose) {
        // The RCM model (pinhole + cylinder + rigid hand-eye) has no effect library yet.
        s.warnings.push(
            "diagnose: no effect model for the RCM cell (the residuals are reported, not \
             traced to a cause)"
                .into(),
        );
        stage_done(dir, &mut s, Stage::Diagnose)?;
    }
    if !s.done(Stage::Validate) {
        log("validate: held-out views, silhouettes predicted by the seed's and the ML hand-eye");
        validate_stage(dir, &mut s, &mut *log)?;
        stage_done(dir, &mut s, Stage::Validate)?;
    }
    // Nothing is commanded with the camera: the held-out views are the verification.
    super::close_without_verify(dir, &mut s)?;
    Ok(s)
}

fn calibrate_stage(dir: &Path, s: &mut SessionFile, log: Log) -> anyhow::Result<()> {
    let (path, data) = rcm_data(dir, s, "train")?;
    for r in &data.refused {
        log(&format!("  refused: {r}"));
    }
    let res = rcm::calibrate(
        &data,
        &rcm::RcmOptions {
            bootstrap: BOOTSTRAP,
            seed: 2,
        },
    )
    .with_context(|| format!("RCM hand-eye calibration of {}", path.display()))?;
    let ds = crate::dataset::Dataset::load(&path)?;
    let (mut cal, report) = rcm::report::calibration_file(&ds.header.robot, &data, &res);
    cal.extra.insert("datasets".into(), s.dataset_hashes());
    let out = dir.join("calibrate");
    std::fs::create_dir_all(&out)?;
    cal.save(out.join("calibration.json"))
        .context("writing calibrate/calibration.json")?;
    CalibrationFile::load(out.join("calibration.json"))?;
    write_atomic(
        &out.join("rcm_report.json"),
        serde_json::to_string_pretty(&report)?.as_bytes(),
    )?;
    for line in rcm::report::text(&res).lines() {
        log(&format!("  {line}"));
    }
    Ok(())
}

/// The deployed hand-eye's interval: the bootstrap's when there is one.
fn pose_std(res: &rcm::RcmCalibration) -> rcm::PoseStd {
    res.bootstrap.unwrap_or(res.std)
}

fn validate_stage(dir: &Path, s: &mut SessionFile, log: Log) -> anyhow::Result<()> {
    // The training calibration (deterministic: recomputed from the same views).
    let (_, train) = rcm_data(dir, s, "train")?;
    let res = rcm::calibrate(
        &train,
        &rcm::RcmOptions {
            bootstrap: BOOTSTRAP,
            seed: 2,
        },
    )
    .context("RCM hand-eye calibration of the training views")?;
    let (vpath, val) = rcm_data(dir, s, "validation")?;
    if val.obs.is_empty() {
        bail!(
            "no held-out view with the shaft's lines detected ({}): {}",
            vpath.display(),
            val.refused.join("; ")
        );
    }
    let before = rms_px(&val, &val.obs, &res.seed.hand_eye);
    let after = rms_px(&val, &val.obs, &res.ml.pose);
    let std = pose_std(&res);
    // The held-out views on their own: an independent hand-eye (covariance interval).
    let own = rcm::calibrate(
        &val,
        &rcm::RcmOptions {
            bootstrap: 0,
            seed: 2,
        },
    );
    let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let (diff, ratio) = match &own {
        Ok(o) => {
            let (dt, dr) = rcm::pose_error(&o.ml.pose, &res.ml.pose);
            let bt = 1.96 * norm(std.xyz_mm).hypot(norm(o.std.xyz_mm));
            let br = 1.96 * norm(std.rot_deg).hypot(norm(o.std.rot_deg));
            (Some([dt, dr]), Some((dt / bt).max(dr / br)))
        }
        Err(e) => {
            s.warnings.push(format!(
                "the held-out views alone do not calibrate ({e}): the interval is not checked \
                 on independent data"
            ));
            (None, None)
        }
    };
    let ci_mm = 1.96 * std.xyz_mm.iter().fold(0.0f64, |a, b| a.max(*b));
    let ci_deg = 1.96 * std.rot_deg.iter().fold(0.0f64, |a, b| a.max(*b));
    let refused = train.refused.len() + val.refused.len();
    let views = train.obs.len() + val.obs.len() + refused;
    log(&format!(
        "  held-out silhouettes: {before:.3} px (seed two-step) → {after:.3} px (ML), {} views; \
         hand-eye 95 % ± {ci_mm:.3} mm / {ci_deg:.4}°{}",
        val.obs.len(),
        diff.map_or(String::new(), |d| format!(
            "; held-out views alone: {:.3} mm / {:.4}° away",
            d[0], d[1]
        ))
    ));
    let m = &mut s.measured;
    m.heldout_poses = val.obs.len();
    m.rcm_heldout_px_before = Some(before);
    m.rcm_heldout_px_after = Some(after);
    m.hand_eye_ci95_mm = Some(ci_mm);
    m.hand_eye_ci95_deg = Some(ci_deg);
    m.hand_eye_heldout_ratio = ratio;
    m.rcm_refused_fraction = (views > 0).then(|| refused as f64 / views as f64);
    // Deploy the calibration.
    let src = dir.join("calibrate").join("calibration.json");
    let bytes = crate::fsio::read(&src).with_context(|| format!("{}", src.display()))?;
    write_atomic(&dir.join("deploy").join("calibration.json"), &bytes)?;
    s.deploy = vec!["deploy/calibration.json".into()];
    let q: Vec<f64> = train.detected.iter().map(|(_, d)| d.sigma_px()).collect();
    let t = res.ml.pose.translation.vector;
    let r = res.ml.pose.rotation;
    s.rcm = Some(RcmSummary {
        views_train: train.obs.len(),
        views_heldout: val.obs.len(),
        refused: train.refused.iter().chain(&val.refused).cloned().collect(),
        detector_sigma_px: (!q.is_empty()).then(|| {
            [
                crate::solve::stats::quantile(&q, 0.5),
                q.iter().fold(0.0f64, |a, b| a.max(*b)),
            ]
        }),
        train_rms_px: res.ml.rms_px,
        heldout_rms_px_seed: before,
        heldout_rms_px_ml: after,
        hand_eye: HandEyeSummary {
            xyz_mm: [t.x, t.y, t.z],
            quat: [r.w, r.i, r.j, r.k],
            std_mm: std.xyz_mm,
            std_deg: std.rot_deg,
        },
        heldout_hand_eye_diff: diff,
        seed_to_ml: {
            let (a, b) = rcm::pose_error(&res.seed.hand_eye, &res.ml.pose);
            [a, b]
        },
        rcm_base_mm: res.rcm_base.0.into(),
        rcm_axes_rms_mm: res.rcm_base.1,
    });
    Ok(())
}

/// What the CLI prints of an RCM session.
pub fn lines(r: &RcmSummary, m: &super::Measured) -> Vec<String> {
    let f = |v: Option<f64>| v.map_or("—".into(), |x| format!("{x:.3}"));
    let h = &r.hand_eye;
    vec![
        format!(
            "rcm: held-out silhouette RMS {} px (seed 002 two-step) → {} px (ML), {} held-out + {} \
             training views, {} refused by the line detector; training RMS {:.3} px",
            f(m.rcm_heldout_px_before),
            f(m.rcm_heldout_px_after),
            r.views_heldout,
            r.views_train,
            r.refused.len(),
            r.train_rms_px
        ),
        format!(
            "endoscope in base: xyz [{:.3}, {:.3}, {:.3}] ± [{:.3}, {:.3}, {:.3}] mm, rot ± [{:.4}, \
             {:.4}, {:.4}]° (1σ, bootstrap); held-out views alone: {}",
            h.xyz_mm[0],
            h.xyz_mm[1],
            h.xyz_mm[2],
            h.std_mm[0],
            h.std_mm[1],
            h.std_mm[2],
            h.std_deg[0],
            h.std_deg[1],
            h.std_deg[2],
            r.heldout_hand_eye_diff
                .map_or("not calibrated".into(), |d| format!(
                    "{:.3} mm / {:.4}° away",
                    d[0], d[1]
                ))
        ),
    ]
}

/// The RCM section of the session report.
pub fn html(r: &RcmSummary, m: &super::Measured) -> String {
    let esc = |t: &str| {
        t.replace('&', "&amp;")
            .replace('<', "&lt;")
            .replace('>', "&gt;")
    };
    let f = |v: Option<f64>| v.map_or("—".into(), |x| format!("{x:.3}"));
    let h = &r.hand_eye;
    let mut out = format!(
        "<h2>Endoscope hand-eye under an RCM (seed 002)</h2><p id=\"rcm\">{} training and {} \
         held-out endoscope views; the shaft's two silhouette lines detected in each image \
         (end-point 1-σ median, worst: {} px); {} views refused by the detector. \
         The RCM is at ({:.2}, {:.2}, {:.2}) mm in the base (instrument axes {:.3} mm RMS from \
         it).</p>",
        r.views_train,
        r.views_heldout,
        r.detector_sigma_px
            .map_or("—".into(), |d| format!("{:.3}, {:.3}", d[0], d[1])),
        r.refused.len(),
        r.rcm_base_mm[0],
        r.rcm_base_mm[1],
        r.rcm_base_mm[2],
        r.rcm_axes_rms_mm
    );
    out.push_str(
        "<table id=\"rcm-heldout\"><tr><th>hand-eye</th><th>held-out silhouette RMS (px)</th></tr>",
    );
    out.push_str(&format!(
        "<tr><td>seed 002 two-step (Plücker axes, RCM refinement)</td><td>{}</td></tr>\
         <tr><td>maximum likelihood on the end points (deployed)</td><td>{}</td></tr></table>",
        f(m.rcm_heldout_px_before),
        f(m.rcm_heldout_px_after)
    ));
    out.push_str("<table id=\"rcm-hand-eye\"><tr><th></th><th>x</th><th>y</th><th>z</th></tr>");
    for (what, v, digits) in [
        ("endoscope in base (mm)", h.xyz_mm, 3),
        ("1σ (mm, bootstrap)", h.std_mm, 3),
        ("1σ rotation (deg)", h.std_deg, 4),
    ] {
        out.push_str(&format!("<tr><td>{what}</td>"));
        for x in v {
            out.push_str(&format!("<td>{x:.digits$}</td>"));
        }
        out.push_str("</tr>");
    }
    out.push_str("</table>");
    out.push_str(&format!(
        "<p id=\"rcm-check\">Seed two-step → ML moved {:.3} mm / {:.4}°. {}</p>",
        r.seed_to_ml[0],
        r.seed_to_ml[1],
        r.heldout_hand_eye_diff.map_or(
            "The held-out views alone did not calibrate.".into(),
            |d| format!(
                "The held-out views calibrated on their own put the endoscope {:.3} mm and \
                 {:.4}° from the deployed hand-eye.",
                d[0], d[1]
            )
        )
    ));
    if !r.refused.is_empty() {
        out.push_str("<ul id=\"rcm-refused\">");
        for x in &r.refused {
            out.push_str(&format!("<li>{}</li>", esc(x)));
        }
        out.push_str("</ul>");
    }
    out.push('\n');
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::rcm::lines::{FittedLine, ShaftLines};

    fn line(rms_px: f64) -> FittedLine {
        FittedLine {
            seg: [0.0, 0.0, 100.0, 100.0],
            n_points: 100,
            rms_px,
            length_px: 141.0,
            run_px: 141.0,
            sigma_px: 2.0 * rms_px / 10.0,
            contrast: 20.0,
            polarity: 1.0,
            abc: [0.0; 3],
        }
    }

    fn data(rms: &[[f64; 2]]) -> RcmData {
        let cam = EndoscopeCamera {
            kind: "endoscope".into(),
            width: 640,
            height: 480,
            fx: 500.0,
            fy: 500.0,
            cx: 320.0,
            cy: 240.0,
            dist: [0.0; 5],
        };
        let obs = (0..rms.len() as u64)
            .map(|id| RcmObs {
                id,
                line: id as usize + 2,
                flange: Isometry3::identity(),
                segs: [[0.0, 0.0, 100.0, 100.0], [10.0, 0.0, 110.0, 100.0]],
            })
            .collect();
        let mut d = RcmData::new(cam, 4.0, obs);
        d.detected = rms
            .iter()
            .enumerate()
            .map(|(id, r)| {
                (
                    id as u64,
                    ShaftLines {
                        lines: [line(r[0]), line(r[1])],
                        candidates: 2,
                        edge_points: 200,
                    },
                )
            })
            .collect();
        d
    }

    /// A view whose line fits its points far worse than the set's lines is refused (named,
    /// with the reason); a set of equally good lines keeps every view.
    #[test]
    fn a_badly_fitted_line_refuses_its_view_and_only_it() {
        let mut d = data(&[[0.10, 0.12], [0.11, 0.13], [0.12, 0.54], [0.13, 0.10]]);
        screen_lines(&mut d, "validation");
        let ids: Vec<u64> = d.obs.iter().map(|o| o.id).collect();
        assert_eq!(ids, [0, 1, 3]);
        assert_eq!(d.detected.len(), 3);
        assert_eq!(d.refused.len(), 1);
        assert!(
            d.refused[0].contains("validation pose 2"),
            "{:?}",
            d.refused
        );
        let mut d = data(&[[0.25, 0.29], [0.11, 0.13], [0.12, 0.14], [0.13, 0.10]]);
        screen_lines(&mut d, "train");
        assert_eq!(d.obs.len(), 4, "{:?}", d.refused);
    }
}
