//! Intrinsics from board views alone (no robot): the camera model a calibration tool computes
//! from a folder of chessboard images, as OpenCV's `calibrateCamera` does. Zhang's closed form
//! from one homography per view, then one Levenberg–Marquardt fit of the intrinsics and every
//! view's board pose on every corner ([`super::problem::Layout::Views`]) with a given
//! distortion model. The RMS is OpenCV's: the root mean square of the 2-D corner error (px).
//!
//! This is the public-reference check: OpenCV's own test pins the intrinsics of
//! its `samples/data/left01..14.jpg` (`tests/opencv_left.rs`).
use nalgebra::Isometry3;

use super::geom::Intrinsics;
use super::problem::{BoardModel, Layout, Obs, Reproj};
use super::{
    obs_of, rms, single_view, view_h, zhang, zhang_start, CameraData, CameraError, DistModel,
};
use crate::solve::lm::{minimize, LmOptions, Termination};

/// What [`calibrate_intrinsics`] returns.
#[derive(Debug, Clone)]
pub struct IntrinsicsFit {
    pub k: Intrinsics,
    pub model: DistModel,
    /// RMS of the 2-D corner reprojection error (px), OpenCV's convention.
    pub rms_px: f64,
    /// Board in the camera, one per view of the input.
    pub poses: Vec<Isometry3<f64>>,
    pub corners: usize,
}

/// Fit the intrinsics with distortion `model` to every view of `data` (the flange poses are not
/// used). At least 3 views with 6 corners each.
pub fn calibrate_intrinsics(
    data: &CameraData,
    model: DistModel,
) -> Result<IntrinsicsFit, CameraError> {
    let n = data.views.len();
    let per_view: Vec<Vec<Obs>> = data
        .views
        .iter()
        .map(|v| single_view(&obs_of(std::slice::from_ref(v), &data.board)))
        .collect();
    let usable = per_view.iter().filter(|o| o.len() >= 6).count();
    if usable < 3 || usable < n {
        return Err(CameraError::TooFewViews {
            got: usable,
            need: n.max(3),
        });
    }
    let (k0m, k0) = zhang_start(data, &per_view)?;
    let init: Vec<Isometry3<f64>> = per_view
        .iter()
        .map(|o| {
            view_h(o)
                .and_then(|h| zhang::pose_from_h(&k0m, &h))
                .unwrap_or_else(Isometry3::identity)
        })
        .collect();
    let obs = obs_of(&data.views, &data.board);
    let p = Reproj {
        obs: &obs,
        flange: &[],
        layout: Layout::Views(n),
        intr_free: model.mask(),
        intr_fixed: k0,
        board: BoardModel::default(),
        arm: None,
        flange_map: None,
    };
    let opts = LmOptions {
        max_iter: 200,
        ..LmOptions::default()
    };
    let rep = minimize(&p, p.pack(&k0, &init, 1.0, [0.0; 2]), &opts);
    if rep.termination == Termination::NonFinite {
        return Err(CameraError::Intrinsics(
            "the intrinsics fit diverged (non-finite reprojection)".into(),
        ));
    }
    Ok(IntrinsicsFit {
        k: p.intrinsics(&rep.x),
        model,
        rms_px: rms(&rep.residuals),
        poses: (0..n).map(|b| p.pose(&rep.x, b)).collect(),
        corners: obs.len(),
    })
}
