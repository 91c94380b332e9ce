//! A camera calibration as files and text: the calibration file's `camera` block from a
//! result and back, `robocal predict` on it (the pixel of every board corner at every pose),
//! `camera_report.json` and the console table. Shared by `robocal calibrate camera`,
//! `robocal predict` and the session's camera stages.
#![allow(clippy::type_complexity)]
use std::path::Path;

use anyhow::Context as _;
use nalgebra::Isometry3;
use serde_json::json;

use super::data::Loaded;
use super::geom::{Intrinsics, N_INTR};
use super::{CameraResult, DistModel, Mount};
use crate::dataset::{
    CalibrationFile, CameraCalBlock, HandEyeBlock, IntrinsicsBlock, PoseWithStd, TargetHeader,
};
use crate::solve::camera;

/// `[w, x, y, z]` with `w ≥ 0`.
pub fn quat(p: &Isometry3<f64>) -> [f64; 4] {
    let q = p.rotation;
    let q = if q.w < 0.0 {
        -q.into_inner()
    } else {
        q.into_inner()
    };
    [q.w, q.i, q.j, q.k]
}

/// Translation (mm).
pub fn xyz(p: &Isometry3<f64>) -> [f64; 3] {
    let t = p.translation.vector;
    [t.x, t.y, t.z]
}

/// The distortion model's name in files.
pub fn dist_name(m: DistModel) -> String {
    serde_json::to_value(m)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_default()
}

/// The calibration file of a result.
pub fn calibration_file(train: &Loaded, res: &CameraResult) -> CalibrationFile {
    let k = &res.ml.intrinsics;
    let u = &res.uncertainty;
    let mount = train.data.mount;
    let target_pose = PoseWithStd {
        xyz_mm: xyz(&res.ml.target),
        quat: quat(&res.ml.target),
        std_mm: Some(u.target_mm),
        std_deg: Some(u.target_deg),
    };
    let block = CameraCalBlock {
        intrinsics: IntrinsicsBlock {
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
            dist: k.dist,
            width: train.data.width,
            height: train.data.height,
            model: Some(dist_name(res.distortion)),
            std: Some(u.intrinsics),
        },
        hand_eye: HandEyeBlock {
            mount: match mount {
                Mount::Flange => "flange".into(),
                Mount::Base => "base".into(),
            },
            xyz_mm: xyz(&res.ml.x),
            quat: quat(&res.ml.x),
            std_mm: Some(u.x_mm),
            std_deg: Some(u.x_deg),
            bootstrap: u
                .bootstrap
                .map(|(n, mm, deg)| json!({"refits": n, "std_mm": mm, "std_deg": deg})),
        },
        target_in_base: (mount == Mount::Flange).then(|| target_pose.clone()),
        target_in_flange: (mount == Mount::Base).then_some(target_pose),
        target: train.target.clone(),
        target_scale: (res.board_scale != 1.0).then_some(res.board_scale),
        target_bend_mm: (res.board_bend_mm != [0.0; 2]).then_some(res.board_bend_mm),
        flange_map: None,
    };
    let mut cal = CalibrationFile::new(train.dataset.header.robot.clone(), vec![]);
    cal.set_camera(&block);
    cal.metrics
        .insert("train_rms_px".into(), json!(res.ml.train_rms_px));
    if let Some(h) = res.ml.heldout_rms_px {
        cal.metrics.insert("heldout_rms_px".into(), json!(h));
    }
    cal.metrics
        .insert("views_used".into(), json!(res.used_views.len()));
    cal
}

/// The intrinsics and hand-eye of a camera calibration file.
pub fn from_calibration(
    cal: &CalibrationFile,
) -> anyhow::Result<(
    Intrinsics,
    Isometry3<f64>,
    Isometry3<f64>,
    Mount,
    TargetHeader,
)> {
    let b = cal
        .camera()
        .map_err(|e| anyhow::anyhow!("calibration: {e}"))?
        .ok_or_else(|| anyhow::anyhow!("calibration has no \"camera\" block"))?;
    let i = &b.intrinsics;
    let k = Intrinsics {
        fx: i.fx,
        fy: i.fy,
        cx: i.cx,
        cy: i.cy,
        dist: i.dist,
    };
    let pose = |xyz: [f64; 3], q: [f64; 4], what: &str| {
        crate::solve::laser::file_pose(&xyz, &q).ok_or_else(|| {
            anyhow::anyhow!("calibration: camera.{what}: not a finite pose with a unit quaternion")
        })
    };
    let x = pose(b.hand_eye.xyz_mm, b.hand_eye.quat, "hand_eye")?;
    let (mount, t) = match b.hand_eye.mount.as_str() {
        "flange" => (Mount::Flange, b.target_in_base.as_ref()),
        "base" => (Mount::Base, b.target_in_flange.as_ref()),
        m => anyhow::bail!("calibration: camera.hand_eye.mount {m:?} (expected flange or base)"),
    };
    let t = t.ok_or_else(|| anyhow::anyhow!("calibration: camera block has no target pose"))?;
    let target = pose(t.xyz_mm, t.quat, "target")?;
    let mut tgt = b.target.clone();
    if let Some(s) = b.target_scale {
        tgt.square_mm *= s;
    }
    Ok((k, x, target, mount, tgt))
}

/// The arm model a camera calibration carries (`params`: the arm's kinematics identified
/// through the camera by the camera diagnosis' `arm_kinematics`), on the calibration's robot;
/// `None` when the file has no parameters.
pub fn arm_model(cal: &CalibrationFile) -> anyhow::Result<Option<crate::model::KinematicModel>> {
    if cal.params.is_empty() {
        return Ok(None);
    }
    let mut m = crate::model::KinematicModel::from_robot_block(&cal.robot)
        .map_err(|e| anyhow::anyhow!("calibration: robot: {e}"))?;
    m.apply_cal_params(&cal.params)
        .map_err(|e| anyhow::anyhow!("calibration: params: {e}"))?;
    Ok(Some(m))
}

/// The views' flange poses read through the calibration's flange map (`camera.flange_map`, what
/// the camera diagnosis' `flange_map` found), eye-in-hand, after [`apply_arm`]: the poses its
/// hand-eye holds for. Without a map, or eye-to-hand, nothing changes.
pub fn apply_flange_map(cal: &CalibrationFile, data: &mut camera::CameraData) {
    if data.mount != Mount::Flange {
        return;
    }
    if let Some(m) = cal.camera().ok().flatten().and_then(|b| b.flange_map) {
        for v in &mut data.views {
            v.flange = read_through_map(&m, &v.flange);
        }
    }
}

/// Flange `f` read through the file's map `m`.
pub fn read_through_map(
    m: &crate::dataset::camera::FlangeMapBlock,
    f: &Isometry3<f64>,
) -> Isometry3<f64> {
    super::problem::shift_flange(
        f,
        &nalgebra::Matrix3::from_fn(|r, c| m.matrix[r][c]),
        &nalgebra::Vector3::from(m.centre_mm),
    )
}

/// Flange poses of the views through the calibration's arm model (from each record's `q`),
/// when the calibration carries one: the poses its hand-eye was identified with. Views whose
/// record has no `q` keep theirs. Returns whether the arm model was used.
pub fn apply_arm(
    cal: &CalibrationFile,
    data: &mut camera::CameraData,
    ds: &crate::dataset::Dataset,
) -> anyhow::Result<bool> {
    let Some(m) = arm_model(cal)? else {
        return Ok(false);
    };
    anyhow::ensure!(
        crate::plausible::dataset::same_robot(&cal.robot, &ds.header.robot),
        "robot.model: the calibration is for robot model {:?}, the dataset for {:?}: a file from \
         another robot or cell",
        cal.robot.model,
        ds.header.robot.model
    );
    for v in &mut data.views {
        if let Some(q) = ds.poses().find(|r| r.id == v.id).and_then(|r| r.q.as_ref()) {
            let q: Vec<f64> = q.iter().map(|d| d.to_radians()).collect();
            v.flange = m.flange_pose(&q);
        }
    }
    Ok(true)
}

/// `robocal predict` on a camera calibration: CSV `id,corner,u_px,v_px` for every board corner
/// at every pose of `data` (flange from the record, else FK of `q`; through the calibration's
/// arm model from `q` when it carries one).
pub fn predict_rows(cal_path: &Path, data: &Path) -> anyhow::Result<Vec<(u64, usize, [f64; 2])>> {
    let cal = CalibrationFile::load(cal_path)?;
    crate::plausible::calibration::check_values(&cal, cal_path)?;
    let (k, x, target, mount, tgt) = from_calibration(&cal)?;
    // The board's bend the camera diagnosis found (`target_flatness`): applied, as the
    // diagnosis' own held-out figure does.
    let bend = cal
        .camera()
        .ok()
        .flatten()
        .and_then(|b| b.target_bend_mm)
        .unwrap_or([0.0; 2]);
    let ds = crate::dataset::Dataset::load(data)?;
    let model = crate::model::KinematicModel::from_robot_block(&ds.header.robot).ok();
    let mut views = vec![];
    for r in ds.poses() {
        let f = crate::solve::laser::record_flange(r, model.as_ref())
            .with_context(|| format!("{}", data.display()))?;
        views.push(camera::View {
            id: r.id,
            flange: f,
            corners: vec![],
        });
    }
    let mut cd = camera::CameraData {
        width: cal
            .camera()
            .ok()
            .flatten()
            .map_or(0, |c| c.intrinsics.width),
        height: 0,
        board: camera::detect::BoardSpec {
            cols: tgt.cols as usize,
            rows: tgt.rows as usize,
            square_mm: tgt.square_mm,
        },
        mount,
        views,
    };
    apply_arm(&cal, &mut cd, &ds).with_context(|| format!("{}", cal_path.display()))?;
    apply_flange_map(&cal, &mut cd);
    Ok(camera::predict(&cd, &k, &x, &target, bend))
}

/// `camera_report.json`: every method side by side, distortion scores, rejections, timing.
pub fn report_json(
    train: &Loaded,
    held: Option<&Loaded>,
    res: &CameraResult,
    t_detect: f64,
    t_total: f64,
) -> serde_json::Value {
    let est = |e: &camera::Estimate| {
        json!({"method": e.method, "hand_eye": {"xyz_mm": xyz(&e.x), "quat": quat(&e.x)},
               "target": {"xyz_mm": xyz(&e.target), "quat": quat(&e.target)},
               "intrinsics": {"fx": e.intrinsics.fx, "fy": e.intrinsics.fy, "cx": e.intrinsics.cx,
                              "cy": e.intrinsics.cy, "dist": e.intrinsics.dist},
               "train_rms_px": e.train_rms_px, "heldout_rms_px": e.heldout_rms_px})
    };
    let mut methods: Vec<serde_json::Value> = res.closed_form.iter().map(est).collect();
    if let Some(i) = &res.incremental {
        let mut v = est(&i.estimate);
        v["curve"] = json!(i.curve);
        v["rejected_views"] = json!(i.rejected);
        v["subset"] = json!({"size": i.subset.0, "count": i.subset.1});
        methods.push(v);
    }
    methods.push(est(&res.ml));
    json!({
        "format": crate::schema::CAMERA_REPORT_FORMAT,
        "views": train.data.views.len(),
        "views_without_board": unusable_json(train),
        "detection_notes": train.notes.iter().map(|(id, n)| json!({"id": id, "note": n})).collect::<Vec<_>>(),
        "target_kind": train.target.kind,
        // Views where only part of the board was seen (ChArUco: cut by the image border or
        // occluded; every corner still carries its board id).
        "partial_views": train.data.views.iter().filter(|v| v.corners.iter().any(|c| c.is_none())).count(),
        "heldout_views": held.map(|h| h.data.views.len()),
        "distortion": dist_name(res.distortion),
        "distortion_scores_px": res.model_scores.iter().map(|(m, s)| json!({"model": dist_name(*m), "validation_rms_px": s})).collect::<Vec<_>>(),
        "intrinsics_only_rms_px": res.intrinsics_rms_px,
        "rejected_views": res.rejected_views,
        "rejected_corners": res.rejected_corners,
        "methods": methods,
        "intrinsics_std": res.uncertainty.intrinsics,
        "hand_eye_std": hand_eye_std_json(&res.uncertainty),
        "timing_s": {"detection": t_detect, "total": t_total},
    })
}

/// X's stated 1σ and, when known, its parts (they add in quadrature): the estimate's own fit,
/// the board-only intrinsics, the choice among plausible distortion models (with the share of
/// resamples of the views in which the calibration's rule chooses each), the choice among the
/// candidate estimators (likewise).
fn hand_eye_std_json(u: &camera::Uncertainty) -> serde_json::Value {
    let mut v = json!({"xyz_mm": u.x_mm, "rot_deg_about_own_axes": u.x_deg});
    if let Some(p) = &u.x_parts {
        v["parts"] = json!({
            "fit": {"xyz_mm": p.fit_mm, "rot_deg": p.fit_deg},
            "intrinsics": {"xyz_mm": p.intrinsics_mm, "rot_deg": p.intrinsics_deg},
            "distortion_model": {"xyz_mm": p.distortion_model_mm, "rot_deg": p.distortion_model_deg,
                                 "plausible_models": p.plausible_models.iter().map(|m| dist_name(*m)).collect::<Vec<_>>(),
                                 "chosen_in_resamples": p.model_shares.iter().map(|(m, w)| json!({"model": dist_name(*m), "share": w})).collect::<Vec<_>>()},
            "estimator": {"xyz_mm": p.estimator_mm, "rot_deg": p.estimator_deg,
                          "chosen_in_resamples": p.estimator_shares.iter().map(|(m, w)| json!({"method": m, "share": w})).collect::<Vec<_>>()},
        });
    }
    if let Some((n, mm, deg)) = u.bootstrap {
        v["bootstrap"] = json!({"resamples": n, "xyz_mm": mm, "rot_deg": deg});
    }
    v
}

/// When the choice among plausible distortion models dominates X's rotation 1σ: which
/// models, how much, and what would decide it (one sentence; the console and the session's
/// warnings).
pub fn lens_model_note(res: &CameraResult) -> Option<String> {
    let p = res.uncertainty.x_parts.as_ref()?;
    let (what, axis, deg) = p.dominant_rotation();
    if what != "distortion model" || p.plausible_models.is_empty() {
        return None;
    }
    let others: Vec<String> = p.plausible_models.iter().map(|m| dist_name(*m)).collect();
    let shares: Vec<String> = p
        .model_shares
        .iter()
        .map(|(m, w)| format!("{} {:.0} %", dist_name(*m), 100.0 * w))
        .collect();
    Some(format!(
        "these views do not decide the lens model: {} fit them as well as the chosen {} \
         (validation error within {:.0} %; chosen in resamples of the views: {}), and X's \
         rotation about the camera's {} axis depends on it (1σ {deg:.2} deg from that alone). \
         Views with the board near the image corners and edges, tilted, decide it.",
        others.join(", "),
        dist_name(res.distortion),
        (camera::DIST_MODEL_PLAUSIBLE - 1.0) * 100.0,
        shares.join(", "),
        ["x", "y", "z"][axis],
    ))
}

/// When the choice of estimator is the largest part of X's 1σ on some axis and X there is
/// uncertain by more than 1 mm or 0.1° from it alone: which estimators the views write, how
/// often, and what would decide it (one sentence; the console and the session's warnings). On
/// a real KUKA set (RWHE-Calib `kuka_2`, 21 training views) resamples of the views write the
/// joint ML in 52 %, the ML with the board-only intrinsics in 30 % and the per-view corrections
/// in 18 %, and X's x is uncertain by 2.25 mm from that alone.
pub fn estimator_note(res: &CameraResult) -> Option<String> {
    let p = res.uncertainty.x_parts.as_ref()?;
    if p.estimator_shares.len() < 2 {
        return None;
    }
    // The axis where the estimator part is largest and larger than every other part:
    // translation first (beyond 1 mm), then rotation (beyond 0.1°).
    let pick = |est: [f64; 3], others: [[f64; 3]; 3], floor: f64| {
        (0..3)
            .filter(|&a| est[a] > floor && others.iter().all(|o| est[a] > o[a]))
            .max_by(|&a, &b| est[a].total_cmp(&est[b]))
            .map(|a| (a, est[a]))
    };
    let worst = pick(
        p.estimator_mm,
        [p.fit_mm, p.intrinsics_mm, p.distortion_model_mm],
        1.0,
    )
    .map(|(a, v)| (a, v, "mm"))
    .or_else(|| {
        pick(
            p.estimator_deg,
            [p.fit_deg, p.intrinsics_deg, p.distortion_model_deg],
            0.1,
        )
        .map(|(a, v)| (a, v, "deg"))
    });
    let (axis, v, unit) = worst?;
    let what = if unit == "mm" {
        format!(
            "X's translation along the camera's {} axis",
            ["x", "y", "z"][axis]
        )
    } else {
        format!(
            "X's rotation about the camera's {} axis",
            ["x", "y", "z"][axis]
        )
    };
    Some(format!(
        "these views do not decide the estimator: resamples of the views write {}, and \
         {what} depends on it (1σ {v:.2} {unit} from that alone). The \
         flange poses' own error is what the estimators treat differently: more views, spread \
         over the workspace with large rotations between them, or a calibrated arm, decide it.",
        estimator_shares_text(&p.estimator_shares),
    ))
}

/// `"park-martin 82 %, daniilidis 9 %, tsai-lenz < 1 %"`.
fn estimator_shares_text(shares: &[(String, f64)]) -> String {
    shares
        .iter()
        .map(|(m, w)| {
            if *w < 0.01 {
                format!("{m} < 1 %")
            } else {
                format!("{m} {:.0} %", 100.0 * w)
            }
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// The lines under the console table that say what X's 1σ is made of and, when the lens model
/// or the estimator dominates it, what would decide it (empty without parts).
pub fn sigma_parts_lines(res: &CameraResult) -> String {
    let Some(p) = &res.uncertainty.x_parts else {
        return String::new();
    };
    let f3 = |v: [f64; 3], d: usize| format!("{:.d$} {:.d$} {:.d$}", v[0], v[1], v[2]);
    // The joint ML frees the intrinsics: their uncertainty is in its fit's.
    let lens = if res.ml.method == "ml" {
        " (intrinsics free)".to_string()
    } else {
        format!(
            "; intrinsics {} mm, {} deg; distortion model {} mm, {} deg",
            f3(p.intrinsics_mm, 3),
            f3(p.intrinsics_deg, 4),
            f3(p.distortion_model_mm, 3),
            f3(p.distortion_model_deg, 4),
        )
    };
    let mut s = format!(
        "  of which: fit {} mm, {} deg{lens}; estimator {} mm, {} deg\n",
        f3(p.fit_mm, 3),
        f3(p.fit_deg, 4),
        f3(p.estimator_mm, 3),
        f3(p.estimator_deg, 4),
    );
    if p.estimator_shares.len() > 1 {
        s += &format!(
            "  resamples of the views write: {} (X of each on every view; the spread is the \
             estimator part)\n",
            estimator_shares_text(&p.estimator_shares)
        );
    }
    for n in [lens_model_note(res), estimator_note(res)]
        .into_iter()
        .flatten()
    {
        s += &format!("  note: {n}\n");
    }
    s
}

/// Every image / record of `l` that gave no view: `[{"id", "reason"}]`.
pub fn unusable_json(l: &Loaded) -> serde_json::Value {
    l.no_board
        .iter()
        .map(|(id, why)| json!({"id": id, "reason": why}))
        .collect()
}

/// `camera_report.json` when the calibration failed: why, and every image that gave no view.
pub fn failure_report_json(
    train: &Loaded,
    held: Option<&Loaded>,
    error: &str,
) -> serde_json::Value {
    json!({
        "format": crate::schema::CAMERA_REPORT_FORMAT,
        "failed": error,
        "views": train.data.views.len(),
        "views_without_board": unusable_json(train),
        "target_kind": train.target.kind,
        "heldout_views": held.map(|h| h.data.views.len()),
        "heldout_views_without_board": held.map(unusable_json),
    })
}

/// The console table.
pub fn table(train: &Loaded, held: Option<&Loaded>, res: &CameraResult) -> String {
    let mut s = String::new();
    let k = &res.ml.intrinsics;
    s += &format!(
        "camera: {} views with a board ({} without, {} rejected by residual, {} corners rejected); held-out views: {}\n",
        res.used_views.len(),
        train.no_board.len(),
        res.rejected_views.len(),
        res.rejected_corners,
        held.map_or("none".to_string(), |h| h.data.views.len().to_string())
    );
    s += &format!(
        "distortion model {} (validation px: {})\n",
        dist_name(res.distortion),
        res.model_scores
            .iter()
            .map(|(m, v)| format!("{} {v:.4}", dist_name(*m)))
            .collect::<Vec<_>>()
            .join(", ")
    );
    s += &format!(
        "intrinsics fx {:.3} fy {:.3} cx {:.3} cy {:.3} dist [{:.5}, {:.5}, {:.6}, {:.6}, {:.5}]\n",
        k.fx, k.fy, k.cx, k.cy, k.dist[0], k.dist[1], k.dist[2], k.dist[3], k.dist[4]
    );
    let _ = N_INTR;
    s += &format!(
        "{:<24} {:>10} {:>12} {:>12}\n",
        "method", "train px", "held-out px", "X xyz mm"
    );
    let mut rows: Vec<&camera::Estimate> = res.closed_form.iter().collect();
    if let Some(i) = &res.incremental {
        rows.push(&i.estimate);
    }
    rows.push(&res.ml);
    for e in rows {
        let t = e.x.translation.vector;
        s += &format!(
            "{:<24} {:>10.4} {:>12} {:>8.3} {:>8.3} {:>8.3}\n",
            e.method,
            e.train_rms_px,
            e.heldout_rms_px.map_or("-".into(), |h| format!("{h:.4}")),
            t.x,
            t.y,
            t.z
        );
    }
    let u = &res.uncertainty;
    s += &format!(
        "hand-eye 1σ ({}): {:.4} {:.4} {:.4} mm, {:.5} {:.5} {:.5} deg",
        res.ml.method, u.x_mm[0], u.x_mm[1], u.x_mm[2], u.x_deg[0], u.x_deg[1], u.x_deg[2]
    );
    if let Some((n, mm, deg)) = u.bootstrap {
        s += &format!(
            "; bootstrap ({n}): {:.4} {:.4} {:.4} mm, {:.5} {:.5} {:.5} deg",
            mm[0], mm[1], mm[2], deg[0], deg[1], deg[2]
        );
    }
    s += "\n";
    s += &sigma_parts_lines(res);
    s
}
