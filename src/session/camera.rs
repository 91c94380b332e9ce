//! The camera half of a session (seed 004): the shell of viewpoints fitted to the cell's board,
//! the camera calibration stage (intrinsics, every closed-form hand-eye and the
//! maximum-likelihood refinement with uncertainties), the camera diagnosis' results and the
//! validation on the held-out images (reprojection before / after the diagnosis).
//!
//! The plan, acquisition, diagnosis, verdict, report and `--resume` are the kinematic
//! session's ([`super::run`]); only what is camera-specific lives here. Units: mm, degrees,
//! pixels (`_px`).
use std::path::Path;

use anyhow::Context as _;
use serde::{Deserialize, Serialize};

use super::{write_atomic, CellDescription, SessionFile, SessionSetup};
use crate::dataset::{CalibrationFile, CameraCalBlock};
use crate::plan::PlanSpec;
use crate::solve::camera::{self as cam, data};

/// The camera of the cell and its board, as the cell file states them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraCell {
    /// Device name.
    pub name: String,
    /// Image size (px).
    pub width: u32,
    pub height: u32,
    /// `flange` (eye-in-hand) or `base` (eye-to-hand).
    pub mount: String,
    /// The board (inner corners), when the cell file declares one.
    #[serde(default)]
    pub board: Option<BoardCell>,
}

/// A calibration board of the cell.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoardCell {
    /// `chessboard` or `charuco`.
    pub kind: String,
    /// Inner corners.
    pub cols: u32,
    pub rows: u32,
    pub square_mm: f64,
    /// The board's centre in the robot base (mm): the shell of viewpoints is centred on it.
    pub center_mm: [f64; 3],
}

/// One method's row of the side-by-side table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MethodRow {
    pub method: String,
    pub train_rms_px: f64,
    pub heldout_rms_px: Option<f64>,
    /// Hand-eye translation (mm).
    pub hand_eye_xyz_mm: [f64; 3],
}

/// The camera calibration of a session (`session.json` `camera`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSummary {
    /// Training views with a usable board, held-out views, views without a board.
    pub views_train: usize,
    pub views_heldout: usize,
    pub views_without_board: usize,
    /// Views the calibration rejected by residual (`id: reason`) and corners rejected.
    pub rejected_views: Vec<String>,
    pub rejected_corners: usize,
    /// Distortion model chosen by validation error.
    pub distortion: String,
    /// Every hand-eye method side by side (closed forms, then `ml`).
    pub methods: Vec<MethodRow>,
    /// The calibration stage's result (`calibrate/calibration.json`'s camera block).
    pub calibrated: CameraCalBlock,
    pub train_rms_px: f64,
    /// Held-out reprojection RMS with the calibration and after the diagnosis (px).
    pub heldout_rms_px_calibrated: Option<f64>,
    pub heldout_rms_px_diagnosed: Option<f64>,
    /// Training reprojection RMS after the diagnosis (px).
    #[serde(default)]
    pub train_rms_px_diagnosed: Option<f64>,
    /// The diagnosed (deployed) camera block: the calibration with the effects found.
    #[serde(default)]
    pub diagnosed: Option<CameraCalBlock>,
    /// Detection + calibration time of the calibrate stage (s).
    pub calibration_s: f64,
    /// Hand-eye check on independent data: the held-out views calibrated on their own
    /// (intrinsics + hand-eye, no effects), its difference from the deployed hand-eye (mm,
    /// deg). `None` when the held-out views alone cannot be calibrated.
    #[serde(default)]
    pub hand_eye_heldout_diff_mm: Option<f64>,
    #[serde(default)]
    pub hand_eye_heldout_diff_deg: Option<f64>,
    /// Plots of the held-out views (relative paths: reprojection per view, residual map).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub plots: Vec<String>,
}

/// Shell strata `[n_r, n_θ, n_α]` for about `n` viewpoints with `n_r` radii and 2 polar
/// bands (at least 3 azimuths).
pub fn shell_strata(n: usize, n_r: usize) -> [usize; 3] {
    let per = (n_r * 2).max(1);
    [n_r, 2, n.div_ceil(per).max(3)]
}

/// Fit a camera plan spec to the cell: the shell is centred on the cell's board and holds
/// about `setup.poses` viewpoints. Returns notes for the log.
pub fn fit_shell(spec: &mut PlanSpec, cell: &CellDescription, setup: &SessionSetup) -> Vec<String> {
    let mut notes = vec![];
    let Some(sh) = spec.shell.as_mut() else {
        return notes;
    };
    if let Some(b) = cell.camera.as_ref().and_then(|c| c.board.as_ref()) {
        sh.center_mm = b.center_mm;
        notes.push(format!(
            "viewpoints on a shell about the cell's board centre ({:.1}, {:.1}, {:.1}) mm",
            b.center_mm[0], b.center_mm[1], b.center_mm[2]
        ));
    } else {
        notes.push(
            "the cell file does not say where the board is: shell centre from the plan spec".into(),
        );
    }
    sh.strata = shell_strata(setup.poses, 2);
    notes
}

fn hashes_into(v: &mut serde_json::Value, s: &SessionFile) {
    if let Some(o) = v.as_object_mut() {
        o.insert("datasets".into(), s.dataset_hashes());
    }
}

fn camera_block(path: &Path) -> anyhow::Result<CameraCalBlock> {
    let cal = CalibrationFile::load(path).with_context(|| format!("{}", path.display()))?;
    cal.camera()
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?
        .with_context(|| format!("{}: no camera block", path.display()))
}

/// Largest 95 % half-interval of a block's hand-eye translation (mm) and rotation (deg).
fn hand_eye_ci95(b: &CameraCalBlock) -> (Option<f64>, Option<f64>) {
    let max = |v: Option<[f64; 3]>| {
        v.map(|a| 1.96 * a.iter().cloned().fold(0.0, f64::max))
            .filter(|x| x.is_finite())
    };
    (max(b.hand_eye.std_mm), max(b.hand_eye.std_deg))
}

/// The calibration stage: detect the board in the training and validation images, calibrate
/// (intrinsics, five closed-form hand-eyes, the maximum-likelihood refinement, covariance),
/// write `calibrate/calibration.json` and `calibrate/camera_report.json`; the result stays in
/// `work` for the diagnosis.
pub fn calibrate_stage(
    dir: &Path,
    s: &mut SessionFile,
    work: &mut super::Work,
    log: super::Log,
) -> anyhow::Result<()> {
    let t0 = std::time::Instant::now();
    let tp = work.dataset(dir, s, "train")?.0.clone();
    camera_set(work, dir, s, "train")?;
    camera_set(work, dir, s, "validation")?;
    let (train, held) = (&work.camera.sets["train"], &work.camera.sets["validation"]);
    let t_detect = t0.elapsed().as_secs_f64();
    let res = cam::calibrate(&train.data, Some(&held.data), &cam::Options::default())
        .with_context(|| format!("calibrating the camera of {}", tp.display()))?;
    let t_total = t0.elapsed().as_secs_f64();
    let cdir = dir.join("calibrate");
    let mut cal = crate::solve::camera::calfile::calibration_file(train, &res);
    cal.extra.insert("datasets".into(), s.dataset_hashes());
    std::fs::create_dir_all(&cdir)?;
    cal.save(cdir.join("calibration.json"))
        .context("writing calibrate/calibration.json")?;
    let mut rep =
        crate::solve::camera::calfile::report_json(train, Some(held), &res, t_detect, t_total);
    hashes_into(&mut rep, s);
    write_atomic(
        &cdir.join("camera_report.json"),
        (serde_json::to_string_pretty(&rep)? + "\n").as_bytes(),
    )?;
    for l in crate::solve::camera::calfile::table(train, Some(held), &res).lines() {
        log(&format!("  {l}"));
    }
    let block = camera_block(&cdir.join("calibration.json"))?;
    let mut methods: Vec<&cam::Estimate> = res.closed_form.iter().collect();
    methods.push(&res.ml);
    let (mm, deg) = hand_eye_ci95(&block);
    s.measured.hand_eye_ci95_mm = mm;
    s.measured.hand_eye_ci95_deg = deg;
    s.camera = Some(CameraSummary {
        views_train: res.used_views.len(),
        views_heldout: held.data.views.len(),
        views_without_board: train.no_board.len() + held.no_board.len(),
        rejected_views: res
            .rejected_views
            .iter()
            .map(|(id, why)| format!("{id}: {why}"))
            .collect(),
        rejected_corners: res.rejected_corners,
        distortion: block.intrinsics.model.clone().unwrap_or_default(),
        methods: methods
            .iter()
            .map(|e| {
                let t = e.x.translation.vector;
                MethodRow {
                    method: e.method.clone(),
                    train_rms_px: e.train_rms_px,
                    heldout_rms_px: e.heldout_rms_px,
                    hand_eye_xyz_mm: [t.x, t.y, t.z],
                }
            })
            .collect(),
        calibrated: block,
        train_rms_px: res.ml.train_rms_px,
        heldout_rms_px_calibrated: res.ml.heldout_rms_px,
        heldout_rms_px_diagnosed: None,
        train_rms_px_diagnosed: None,
        diagnosed: None,
        calibration_s: t_total,
        hand_eye_heldout_diff_mm: None,
        hand_eye_heldout_diff_deg: None,
        plots: vec![],
    });
    for (id, why) in train.no_board.iter().chain(&held.no_board) {
        s.warnings
            .push(format!("view {id}: no usable board ({why})"));
    }
    use crate::solve::camera::calfile::{estimator_note, lens_model_note};
    if let Some(n) = lens_model_note(&res) {
        s.warnings.push(format!("camera: {n}"));
    }
    // The diagnosis that follows may calibrate the arm (`arm_kinematics`), which decides it.
    if let Some(n) = estimator_note(&res) {
        s.warnings.push(format!(
            "camera (calibration stage, before the diagnosis): {n}"
        ));
    }
    work.camera.calibrated = Some(res);
    Ok(())
}

/// The camera datasets of a session with their boards detected, and the calibration of the
/// training views: read, detected and computed once per invocation, handed from stage to stage.
#[derive(Default)]
pub(crate) struct CameraWork {
    pub(crate) sets: std::collections::BTreeMap<String, data::Loaded>,
    /// The calibrate stage's result (absent when that stage ran in an earlier invocation).
    pub(crate) calibrated: Option<cam::CameraResult>,
}

/// The session's `role` camera dataset with its boards detected (read and detected once).
pub(crate) fn camera_set<'a>(
    work: &'a mut super::Work,
    dir: &Path,
    s: &SessionFile,
    role: &str,
) -> anyhow::Result<&'a data::Loaded> {
    if !work.camera.sets.contains_key(role) {
        let (p, loaded) = work.dataset(dir, s, role)?;
        let (p, ds) = (p.clone(), loaded.dataset.clone());
        let l = data::load_dataset(ds, &p, &data::Overrides::default(), false)
            .with_context(|| format!("{}", p.display()))?;
        work.camera.sets.insert(role.to_string(), l);
    }
    Ok(&work.camera.sets[role])
}

/// After the camera diagnosis: the diagnosed camera block (deployed), held-out pixels, the
/// deployed hand-eye's intervals.
pub fn after_diagnosis(
    dir: &Path,
    s: &mut SessionFile,
    diag: &crate::schema::DiagnosisFile,
) -> anyhow::Result<()> {
    let block = camera_block(&dir.join("diagnose").join("calibration.json"))?;
    let (mm, deg) = hand_eye_ci95(&block);
    s.measured.hand_eye_ci95_mm = mm;
    s.measured.hand_eye_ci95_deg = deg;
    let c = s
        .camera
        .as_mut()
        .context("the calibrate stage left no camera summary in session.json")?;
    c.heldout_rms_px_diagnosed = diag.heldout_rms.final_px;
    c.train_rms_px_diagnosed = diag.train_rms.final_px;
    if c.heldout_rms_px_calibrated.is_none() {
        c.heldout_rms_px_calibrated = diag.heldout_rms.base_model_px;
    }
    c.diagnosed = Some(block);
    Ok(())
}

/// The validation stage: the held-out images' reprojection RMS with the calibration and
/// with the diagnosed model (the diagnosis scored them; this stage checks the file and
/// records the numbers the verdict uses) and the calibration to deploy.
pub fn validate_stage(
    dir: &Path,
    s: &mut SessionFile,
    work: &mut super::Work,
) -> anyhow::Result<()> {
    let dpath = dir.join("diagnose").join("diagnosis.json");
    let diag: crate::schema::DiagnosisFile = crate::schema::read(&dpath)?;
    anyhow::ensure!(
        diag.sensor == crate::schema::DiagnosisSensor::Camera,
        "{}: not a camera diagnosis",
        dpath.display()
    );
    let c = s
        .camera
        .as_ref()
        .context("the calibrate stage left no camera summary in session.json")?;
    let m = &mut s.measured;
    m.heldout_poses = diag.n_heldout;
    m.heldout_reprojection_px_before = c
        .heldout_rms_px_calibrated
        .or(diag.heldout_rms.base_model_px);
    m.heldout_reprojection_px_after = diag.heldout_rms.final_px;
    if m.heldout_reprojection_px_after.is_none() {
        anyhow::bail!(
            "{}: no held-out reprojection error (the validation images had no usable board)",
            dpath.display()
        );
    }
    // The hand-eye on independent data: the held-out views calibrated on their own.
    let vp = work.dataset(dir, s, "validation")?.0.clone();
    let held = camera_set(work, dir, s, "validation")?;
    let plots = super::camera_plots::write(
        dir,
        &vp,
        &held.data.views,
        held.data.width,
        held.data.height,
    )
    .context("plotting the held-out views")?;
    // Calibrated alone, but with what the deployed calibration says about the arm and the
    // board (its identified arm kinematics or flange map, and board scale): the hand-eyes then
    // differ only by noise when that model is complete.
    let mut held_data = held.data.clone();
    let dcal_path = dir.join("diagnose").join("calibration.json");
    let dcal =
        CalibrationFile::load(&dcal_path).with_context(|| format!("{}", dcal_path.display()))?;
    crate::solve::camera::calfile::apply_arm(&dcal, &mut held_data, &held.dataset)
        .with_context(|| format!("{}", dcal_path.display()))?;
    if let Some(sc) = dcal.camera().ok().flatten().and_then(|b| b.target_scale) {
        held_data.board.square_mm *= sc;
    }
    // And its flange map (`flange_map`), as `robocal predict` reads the flanges.
    crate::solve::camera::calfile::apply_flange_map(&dcal, &mut held_data);
    let deployed = c
        .diagnosed
        .as_ref()
        .unwrap_or(&c.calibrated)
        .hand_eye
        .clone();
    let diff = cam::calibrate(&held_data, None, &cam::Options::default())
        .map_err(|e| e.to_string())
        .and_then(|r| {
            let x = crate::solve::laser::file_pose(&deployed.xyz_mm, &deployed.quat)
                .ok_or_else(|| "the deployed hand-eye is not a pose".to_string())?;
            let (mm, deg) = cam::geom::pose_error(&x, &r.ml.x);
            Ok((mm, deg, r.uncertainty.x_mm, r.uncertainty.x_deg))
        });
    let c = s.camera.as_mut().expect("checked above");
    c.plots = plots;
    match diff {
        Ok((mm, deg, held_mm, held_deg)) => {
            c.hand_eye_heldout_diff_mm = Some(mm);
            c.hand_eye_heldout_diff_deg = Some(deg);
            // Combined 95 % bound of a difference of two independent 3-vectors:
            // 1.96 √(Σ σ_deployed² + Σ σ_held²) (conservative for the norm of 3 components).
            let bound = |a: Option<[f64; 3]>, b: [f64; 3]| {
                a.map(|a| 1.96 * a.iter().chain(&b).map(|v| v * v).sum::<f64>().sqrt())
                    .filter(|x| x.is_finite() && *x > 0.0)
            };
            let ratio = match (
                bound(deployed.std_mm, held_mm),
                bound(deployed.std_deg, held_deg),
            ) {
                (Some(bm), Some(bd)) => Some((mm / bm).max(deg / bd)),
                _ => None,
            };
            s.measured.hand_eye_heldout_ratio = ratio;
            if let Some(r) = ratio.filter(|r| *r > 1.0) {
                s.warnings.push(format!(
                    "the hand-eye from the held-out views alone differs from the deployed one by \
                     {mm:.3} mm / {deg:.3}°, {r:.1}× the combined 95 % bound: the stated hand-eye \
                     interval is optimistic — the hand-eye absorbs an error the model lacks (an arm \
                     or board error the camera diagnosis did not identify)"
                ));
            }
        }
        Err(e) => s.warnings.push(format!(
            "the held-out views alone could not be calibrated ({e}): no independent hand-eye check"
        )),
    }
    // What to deploy: the diagnosed camera calibration (read back before it is offered).
    let ddir = dir.join("deploy");
    std::fs::create_dir_all(&ddir)?;
    let src = dir.join("diagnose").join("calibration.json");
    let bytes = crate::fsio::read(&src).with_context(|| format!("{}", src.display()))?;
    write_atomic(&ddir.join("calibration.json"), &bytes)?;
    let cal = CalibrationFile::load(ddir.join("calibration.json"))
        .context("reading deploy/calibration.json back")?;
    crate::solve::camera::calfile::from_calibration(&cal)
        .context("deploy/calibration.json: the camera block")?;
    s.deploy = vec!["deploy/calibration.json".into()];
    Ok(())
}

/// Shell spec check for a camera session (a clear error rather than an empty plan).
pub fn check_spec(spec: &PlanSpec, path: &str) -> anyhow::Result<()> {
    anyhow::ensure!(
        spec.shell.is_some(),
        "{path}: a camera session needs a camera-viewpoint plan spec with a [shell] table \
         (e.g. plans/seed004-ur5e-camera.toml)"
    );
    Ok(())
}
