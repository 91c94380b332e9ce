//! The calibration file and report of an RCM hand-eye calibration.
use nalgebra::Isometry3;
use serde::Serialize;

use super::{PoseStd, RcmCalibration, RcmData};
use crate::dataset::endoscope::{CameraCal, HandEye, RcmPoint};
use crate::dataset::{CalParam, CalibrationFile, RobotBlock};

/// `rcm_report.json`.
#[derive(Debug, Clone, Serialize)]
pub struct RcmReport {
    /// Always `robocal-rcm-report/1`.
    pub format: String,
    /// Poses used.
    pub n_poses: usize,
    /// RMS point-to-silhouette distance of the final fit (px).
    pub rms_px: f64,
    /// Solver termination of the final fit.
    pub termination: String,
    /// The seed's two-step hand-eye (camera in base) and how far the ML moved from it.
    pub seed_hand_eye: HandEye,
    /// Seed → ML change (mm, deg).
    pub seed_to_ml_mm_deg: [f64; 2],
    /// RMS half-length of the camera-frame common perpendiculars before / after the seed's
    /// RCM refinement (mm).
    pub seed_meet_rms_mm: [f64; 2],
    /// Uncertainty from the LM covariance.
    pub std_covariance: PoseStd,
    /// Uncertainty from the bootstrap over poses.
    pub std_bootstrap: Option<PoseStd>,
    /// Per pose: id, file line, RMS of its four end-point distances (px).
    pub poses: Vec<(u64, usize, f64)>,
    /// The RCM point.
    pub rcm: RcmPoint,
    /// Poses whose lines were detected in their image: id and each line's quality.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub detected: Vec<(u64, [super::lines::FittedLine; 2])>,
    /// Views the line detector refused, with the reason.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub refused: Vec<String>,
}

/// `camera.hand_eye` of a pose (camera in base).
pub fn hand_eye(pose: &Isometry3<f64>, std: Option<&PoseStd>) -> HandEye {
    let t = pose.translation.vector;
    let q = pose.rotation;
    HandEye {
        mount: "base".into(),
        xyz_mm: [t.x, t.y, t.z],
        quat: [q.w, q.i, q.j, q.k],
        xyz_std_mm: std.map(|s| s.xyz_mm),
        rot_std_deg: std.map(|s| s.rot_deg),
        extra: Default::default(),
    }
}

/// The calibration file (kind `rcm`, params `cam_x/y/z` mm and `cam_rx/ry/rz` deg as a
/// rotation vector, the `camera` block) and the report.
pub fn calibration_file(
    robot: &RobotBlock,
    data: &RcmData,
    res: &RcmCalibration,
) -> (CalibrationFile, RcmReport) {
    let std = res.bootstrap.unwrap_or(res.std);
    let t = res.ml.pose.translation.vector;
    let w = res.ml.pose.rotation.scaled_axis();
    let mut params = Vec::new();
    for (k, n) in ["cam_x", "cam_y", "cam_z"].iter().enumerate() {
        params.push(CalParam {
            name: n.to_string(),
            value: t[k],
            std: Some(std.xyz_mm[k]),
            unit: "mm".into(),
            free: true,
            extra: Default::default(),
        });
    }
    for (k, n) in ["cam_rx", "cam_ry", "cam_rz"].iter().enumerate() {
        params.push(CalParam {
            name: n.to_string(),
            value: w[k].to_degrees(),
            std: Some(std.rot_deg[k]),
            unit: "deg".into(),
            free: true,
            extra: Default::default(),
        });
    }
    let mut cal = CalibrationFile::new(robot.clone(), params);
    cal.set_kind("rcm");
    let rcm = RcmPoint {
        base_mm: res.rcm_base.0.into(),
        camera_mm: res.rcm_cam.into(),
        axes_rms_mm: res.rcm_base.1,
    };
    let cam = CameraCal {
        intrinsics: Some(data.camera.clone()),
        hand_eye: hand_eye(&res.ml.pose, Some(&std)),
        rcm: Some(rcm.clone()),
        extra: Default::default(),
    };
    cal.extra.insert(
        "camera".into(),
        serde_json::to_value(&cam).expect("camera block serialises"),
    );
    cal.extra.insert(
        "method".into(),
        "seed 002 two-step (Plücker axes, RCM refinement, hand-eye) then ML on the silhouette end points".into(),
    );
    let m = &mut cal.metrics;
    m.insert("train_rms_px".into(), res.ml.rms_px.into());
    m.insert("n_poses".into(), res.n_poses.into());
    m.insert("rcm_axes_rms_mm".into(), res.rcm_base.1.into());
    let poses = data
        .obs
        .iter()
        .enumerate()
        .map(|(i, o)| {
            let r = &res.ml.residuals[4 * i..4 * i + 4];
            (
                o.id,
                o.line,
                (r.iter().map(|x| x * x).sum::<f64>() / 4.0).sqrt(),
            )
        })
        .collect();
    let (dt, dr) = super::pose_error(&res.seed.hand_eye, &res.ml.pose);
    let report = RcmReport {
        format: crate::schema::RCM_REPORT_FORMAT.into(),
        n_poses: res.n_poses,
        rms_px: res.ml.rms_px,
        termination: res.ml.termination.describe().into(),
        seed_hand_eye: hand_eye(&res.seed.hand_eye, None),
        seed_to_ml_mm_deg: [dt, dr],
        seed_meet_rms_mm: [res.seed.meet_rms_mm.0, res.seed.meet_rms_mm.1],
        std_covariance: res.std,
        std_bootstrap: res.bootstrap,
        poses,
        rcm,
        detected: data
            .detected
            .iter()
            .map(|(id, d)| (*id, d.lines.clone()))
            .collect(),
        refused: data.refused.clone(),
    };
    (cal, report)
}

/// Console summary.
pub fn text(res: &RcmCalibration) -> String {
    let t = res.ml.pose.translation.vector;
    let q = res.ml.pose.rotation;
    let s = res.bootstrap.unwrap_or(res.std);
    let (dt, dr) = super::pose_error(&res.seed.hand_eye, &res.ml.pose);
    format!(
        "RCM hand-eye from {} poses: camera in base xyz = ({:.3}, {:.3}, {:.3}) mm ± ({:.3}, {:.3}, {:.3}), quat [w,x,y,z] = [{:.6}, {:.6}, {:.6}, {:.6}], rot ± ({:.4}, {:.4}, {:.4}) deg ({})\n  silhouette RMS {:.3} px; {}\n  seed two-step → ML moved {:.3} mm / {:.4} deg; seed axes meet RMS {:.3} → {:.3} mm\n  RCM: base ({:.3}, {:.3}, {:.3}) mm (axes RMS {:.4} mm), camera ({:.3}, {:.3}, {:.3}) mm\n",
        res.n_poses,
        t.x, t.y, t.z,
        s.xyz_mm[0], s.xyz_mm[1], s.xyz_mm[2],
        q.w, q.i, q.j, q.k,
        s.rot_deg[0], s.rot_deg[1], s.rot_deg[2],
        if res.bootstrap.is_some() { "1σ bootstrap" } else { "1σ covariance" },
        res.ml.rms_px,
        res.ml.termination.describe(),
        dt, dr,
        res.seed.meet_rms_mm.0, res.seed.meet_rms_mm.1,
        res.rcm_base.0.x, res.rcm_base.0.y, res.rcm_base.0.z, res.rcm_base.1,
        res.rcm_cam.x, res.rcm_cam.y, res.rcm_cam.z,
    )
}
