//! Camera calibration and hand-eye (seed 004): intrinsics, every closed-form hand-eye side by
//! side, the maximum-likelihood refinement on raw corner reprojection, seed 004's incremental
//! mode, uncertainty (covariance and bootstrap).
//!
//! Pipeline ([`calibrate`]):
//! 1. Zhang's closed form ([`zhang`]) from one homography per view.
//! 2. LM on reprojection over intrinsics + per-view board poses ([`problem::Layout::Views`]) on
//!    up to 20 views spread over the set, for each distortion model of [`DistModel`]; the
//!    model is chosen by the reprojection error of the *other* views (their board poses fitted
//!    with the intrinsics held).
//! 3. Every view's board pose with those intrinsics; views and corners whose residual is far
//!    beyond the robust spread of the rest are rejected automatically; the chosen model is then
//!    refitted on every kept view ([`boardonly`], a Schur-complement solver).
//! 4. Tsai–Lenz, Park–Martin, Horaud, Andreff, Daniilidis ([`handeye`]).
//! 5. One LM over intrinsics, `X` and the target pose on every raw corner with the robot poses
//!    as inputs ([`problem::Layout::HandEye`]), started from the best closed form.
//! 6. The written candidate chosen by cross-validation ([`select`]); X's 1σ from the model
//!    covariance or the view jackknife, plus what the board-only intrinsics' uncertainty and
//!    the choice among plausible distortion models (weighed by how often resamples of the
//!    views choose each) do to X; a view bootstrap that re-estimates the intrinsics and
//!    re-chooses the model; seed 004's incremental Tsai–Lenz.
//!
//! Eye-to-hand (camera fixed, board on the flange) runs the same code with the inverse flange
//! poses: then `X` is the camera in the base and the "target" pose is the board in the flange.
pub mod boardonly;
pub mod calfile;
pub mod charuco;
pub mod data;
pub mod detect;
pub mod geom;
pub mod handeye;
pub mod intrinsics;
pub mod posenoise;
pub mod problem;
pub mod realeval;
pub mod select;
pub mod subpix;
pub mod viewcorr;
mod viewcorr_jac;
pub mod zhang;

use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Vector3};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

use crate::solve::lm::{minimize, LmOptions};
use geom::{board_point, Intrinsics, N_INTR};
use handeye::Method;
use problem::{BoardModel, Layout, Obs, Reproj};

/// Where the camera is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mount {
    /// Eye-in-hand: camera on the flange, board fixed in the base.
    Flange,
    /// Eye-to-hand: camera fixed in the base, board on the flange.
    Base,
}

/// One view: the flange pose (base ← flange) and the board's inner corners in board order
/// (`j·cols + i`; `None` where not detected / rejected).
#[derive(Debug, Clone)]
pub struct View {
    pub id: u64,
    pub flange: Isometry3<f64>,
    pub corners: Vec<Option<[f64; 2]>>,
}

/// A camera dataset in internal form.
#[derive(Debug, Clone)]
pub struct CameraData {
    pub width: u32,
    pub height: u32,
    pub board: detect::BoardSpec,
    pub mount: Mount,
    pub views: Vec<View>,
}

/// Lens distortion models, simplest first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DistModel {
    None,
    K1,
    K1K2,
    K1K2P1P2,
    K1K2P1P2K3,
}

impl DistModel {
    pub const ALL: [DistModel; 5] = [
        DistModel::None,
        DistModel::K1,
        DistModel::K1K2,
        DistModel::K1K2P1P2,
        DistModel::K1K2P1P2K3,
    ];
    /// Free intrinsics `[fx, fy, cx, cy, k1, k2, p1, p2, k3]`.
    pub fn mask(self) -> [bool; N_INTR] {
        let d = match self {
            DistModel::None => [false; 5],
            DistModel::K1 => [true, false, false, false, false],
            DistModel::K1K2 => [true, true, false, false, false],
            DistModel::K1K2P1P2 => [true, true, true, true, false],
            DistModel::K1K2P1P2K3 => [true; 5],
        };
        [true, true, true, true, d[0], d[1], d[2], d[3], d[4]]
    }
}

/// Options of [`calibrate`].
#[derive(Debug, Clone)]
pub struct Options {
    /// Force a distortion model (default: chosen by held-out error).
    pub distortion: Option<DistModel>,
    /// Bootstrap refits (0 = none).
    pub bootstrap: usize,
    /// Seed 004's incremental mode.
    pub incremental: bool,
    /// Random seed (bootstrap, subsets).
    pub seed: u64,
    /// Free board scale / bend in the final fit (the camera diagnosis).
    pub board: BoardModel,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            distortion: None,
            bootstrap: 0,
            incremental: false,
            seed: 4,
            board: BoardModel::default(),
        }
    }
}

/// Errors of the camera calibration.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    #[error("too few views with a detected board: {got} (need at least {need})")]
    TooFewViews { got: usize, need: usize },
    #[error("the closed-form intrinsics failed: {0}")]
    Intrinsics(String),
    #[error("no closed-form hand-eye method produced a solution (the robot poses need rotations about at least two different axes)")]
    HandEye,
    /// The robot's motion and the images disagree: the joint fit had to bend the intrinsics
    /// far from what the board alone gives. Refused rather than written.
    #[error("the robot poses and the images disagree: {0}")]
    Inconsistent(String),
}

/// One hand-eye estimate.
#[derive(Debug, Clone)]
pub struct Estimate {
    pub method: String,
    /// Camera in flange (eye-in-hand) or in base (eye-to-hand).
    pub x: Isometry3<f64>,
    /// Target in base (eye-in-hand) or in flange (eye-to-hand).
    pub target: Isometry3<f64>,
    pub intrinsics: Intrinsics,
    /// RMS reprojection (px) on the training corners.
    pub train_rms_px: f64,
    /// RMS reprojection (px) on the held-out views, when given.
    pub heldout_rms_px: Option<f64>,
}

/// Seed 004's incremental mode.
#[derive(Debug, Clone)]
pub struct Incremental {
    /// `(views used, training RMS px after that update)` from 4 views on.
    pub curve: Vec<(usize, f64)>,
    /// View ids rejected by the 2σ rule.
    pub rejected: Vec<u64>,
    /// Subset size and count of the averaging.
    pub subset: (usize, usize),
    pub estimate: Estimate,
}

/// Standard deviations of the final estimate.
#[derive(Debug, Clone, Default)]
pub struct Uncertainty {
    /// Of `[fx, fy, cx, cy, k1, k2, p1, p2, k3]` (0 for fixed ones).
    pub intrinsics: [f64; N_INTR],
    /// Of X: translation mm (x, y, z of the parent frame), rotation deg (small rotations about
    /// X's own x, y, z axes: the camera's, eye-in-hand; the same frame as the jackknife's and
    /// the bootstrap's spread).
    pub x_mm: [f64; 3],
    pub x_deg: [f64; 3],
    pub target_mm: [f64; 3],
    pub target_deg: [f64; 3],
    /// Bootstrap: std of X translation (mm) and rotation (deg) magnitudes, when run.
    pub bootstrap: Option<(usize, [f64; 3], [f64; 3])>,
    /// What X's 1σ is made of: when the internal cross-validation ran (the estimator part),
    /// and the intrinsics' and lens model's parts when the written estimate holds the
    /// board-only intrinsics.
    pub x_parts: Option<SigmaParts>,
}

/// The parts of X's stated 1σ (translation mm, rotation deg, as [`Uncertainty::x_mm`] /
/// [`Uncertainty::x_deg`]); they add in quadrature.
#[derive(Debug, Clone, Default)]
pub struct SigmaParts {
    /// The estimate's own: the larger of its model covariance and its view jackknife, with
    /// the intrinsics held.
    pub fit_mm: [f64; 3],
    pub fit_deg: [f64; 3],
    /// What the board-only intrinsics' uncertainty does to X.
    pub intrinsics_mm: [f64; 3],
    pub intrinsics_deg: [f64; 3],
    /// X's spread over the distortion models as plausible as the chosen one.
    pub distortion_model_mm: [f64; 3],
    pub distortion_model_deg: [f64; 3],
    /// Those other models (validation error within [`DIST_MODEL_PLAUSIBLE`] of the best).
    pub plausible_models: Vec<DistModel>,
    /// How often each plausible model, the chosen one first, is the one the calibration's rule
    /// chooses when the views are resampled ([`model_shares`]): the weights of
    /// `distortion_model_*`.
    pub model_shares: Vec<(DistModel, f64)>,
    /// X's spread over the candidate estimators that resamples of the views choose instead of
    /// the written one ([`select::choice_shares`]).
    pub estimator_mm: [f64; 3],
    pub estimator_deg: [f64; 3],
    /// Every candidate that resamples of the views write, the written one first, with its
    /// share of the resamples: the weights of `estimator_*`.
    pub estimator_shares: Vec<(String, f64)>,
}

impl SigmaParts {
    /// The part that dominates the largest rotation 1σ: `"fit"`, `"intrinsics"`,
    /// `"distortion model"` or `"estimator"`, with that axis (0–2) and value (deg).
    pub fn dominant_rotation(&self) -> (&'static str, usize, f64) {
        let mut best = ("fit", 0, 0.0);
        for (name, v) in [
            ("fit", self.fit_deg),
            ("intrinsics", self.intrinsics_deg),
            ("distortion model", self.distortion_model_deg),
            ("estimator", self.estimator_deg),
        ] {
            for (a, x) in v.iter().enumerate() {
                if *x > best.2 {
                    best = (name, a, *x);
                }
            }
        }
        best
    }
}

/// What [`calibrate`] returns.
#[derive(Debug, Clone)]
pub struct CameraResult {
    pub distortion: DistModel,
    /// Per model: validation RMS px of the intrinsics-only fit.
    pub model_scores: Vec<(DistModel, f64)>,
    /// The intrinsics-only calibration (per-view board poses).
    pub intrinsics_only: Intrinsics,
    pub intrinsics_rms_px: f64,
    /// The five closed forms (intrinsics of step 2).
    pub closed_form: Vec<Estimate>,
    /// The maximum-likelihood refinement.
    pub ml: Estimate,
    pub incremental: Option<Incremental>,
    pub uncertainty: Uncertainty,
    /// Board scale and bend of the final fit (1, 0 unless freed).
    pub board_scale: f64,
    pub board_bend_mm: [f64; 2],
    /// Views used / rejected (ids with reason).
    pub used_views: Vec<u64>,
    pub rejected_views: Vec<(u64, String)>,
    pub rejected_corners: usize,
    /// Residuals of the final fit: `(view id, corner index, du, dv)`.
    pub residuals: Vec<(u64, usize, f64, f64)>,
    /// Internal cross-validation RMS (px) of every candidate ([`select`]); the lowest is
    /// written as `ml`. Empty when the board model was freed or with fewer than 8 views.
    pub cv_scores: Vec<(String, f64)>,
    /// The other ML variants on every training view (board-only intrinsics, robot pose noise).
    pub candidates: Vec<Estimate>,
    /// The robot's pose noise the data imply: rotation deg, translation mm (1σ per axis).
    pub pose_noise: Option<(f64, f64)>,
    /// The board scale (printed / declared square size) the robot's motion implies, in closed
    /// form from the board-only camera poses (NaN when it cannot be computed); evidence the
    /// diagnosis shows beside its fitted `target_scale`.
    pub implied_scale: f64,
}

fn obs_of(views: &[View], board: &detect::BoardSpec) -> Vec<Obs> {
    let mut out = vec![];
    for (v, view) in views.iter().enumerate() {
        for (k, c) in view.corners.iter().enumerate() {
            if let Some(uv) = c {
                let (i, j) = (k % board.cols, k / board.cols);
                out.push(Obs {
                    view: v,
                    pt: board_point(i, j, board.square_mm).coords,
                    uv: *uv,
                });
            }
        }
    }
    out
}

fn rms(r: &DVector<f64>) -> f64 {
    if r.is_empty() {
        return f64::NAN;
    }
    // per-corner RMS of the 2-D error = sqrt(Σ r² / n_corners)
    (r.norm_squared() / (r.len() / 2) as f64).sqrt()
}

/// The flange poses as the hand-eye code needs them (inverse for eye-to-hand).
pub fn motion_poses(views: &[View], mount: Mount) -> Vec<Isometry3<f64>> {
    views
        .iter()
        .map(|v| match mount {
            Mount::Flange => v.flange,
            Mount::Base => v.flange.inverse(),
        })
        .collect()
}

/// Reprojection RMS (px per corner) of views the intrinsics `k` were not fitted on: each view's
/// board pose fitted with `k` held, from the given start (`views`: corners, start pose).
fn validation_rms<'a>(
    k: &Intrinsics,
    views: impl Iterator<Item = (&'a [Obs], Isometry3<f64>)>,
) -> f64 {
    let (mut se, mut nc) = (0.0, 0usize);
    for (ob, init) in views {
        let (_, r, res) = pnp(k, ob, init);
        if r.is_finite() {
            se += res.norm_squared();
            nc += res.len() / 2;
        }
    }
    (se / nc.max(1) as f64).sqrt()
}

/// Board-in-camera pose of one view with the intrinsics held (returns pose and RMS px).
fn pnp(k: &Intrinsics, obs: &[Obs], init: Isometry3<f64>) -> (Isometry3<f64>, f64, DVector<f64>) {
    let p = Reproj {
        obs,
        flange: &[],
        layout: Layout::Views(1),
        intr_free: [false; N_INTR],
        intr_fixed: *k,
        board: BoardModel::default(),
        arm: None,
        flange_map: None,
    };
    let x0 = p.pack(k, &[init], 1.0, [0.0; 2]);
    let rep = minimize(&p, x0, &LmOptions::default());
    (p.pose(&rep.x, 0), rms(&rep.residuals), rep.residuals)
}

fn single_view(obs: &[Obs]) -> Vec<Obs> {
    obs.iter().map(|o| Obs { view: 0, ..*o }).collect()
}

fn view_h(obs: &[Obs]) -> Option<Matrix3<f64>> {
    let plane: Vec<[f64; 2]> = obs.iter().map(|o| [o.pt.x, o.pt.y]).collect();
    let img: Vec<[f64; 2]> = obs.iter().map(|o| o.uv).collect();
    zhang::homography(&plane, &img)
}

fn k_matrix(k: &Intrinsics) -> Matrix3<f64> {
    Matrix3::new(k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0)
}

/// Reprojection of held-out views under a hand-eye estimate (RMS px over all corners).
pub fn heldout_rms(
    data: &CameraData,
    k: &Intrinsics,
    x: &Isometry3<f64>,
    target: &Isometry3<f64>,
    scale: f64,
    bend: [f64; 2],
) -> f64 {
    let r = predict_residuals(data, k, x, target, scale, bend);
    if r.is_empty() {
        return f64::NAN;
    }
    (r.iter().map(|(_, _, a, b)| a * a + b * b).sum::<f64>() / r.len() as f64).sqrt()
}

/// Predicted pixel of every board corner at every view: `(view id, corner, u, v)`, with the
/// board bent by `bend` (mm, the sag model of [`problem`] about [`bend_centre`]; `[0, 0]` =
/// flat): the same board model the camera diagnosis fits, so `robocal predict` on a
/// diagnosis' calibration reproduces its figures.
pub fn predict(
    data: &CameraData,
    k: &Intrinsics,
    x: &Isometry3<f64>,
    target: &Isometry3<f64>,
    bend: [f64; 2],
) -> Vec<(u64, usize, [f64; 2])> {
    let g = motion_poses(&data.views, data.mount);
    let [x0, y0, rr] = bend_centre(&data.board);
    let mut out = vec![];
    for (v, view) in data.views.iter().enumerate() {
        let cam_from_board = (g[v] * x).inverse() * target;
        for k_i in 0..data.board.cols * data.board.rows {
            let mut p = board_point(
                k_i % data.board.cols,
                k_i / data.board.cols,
                data.board.square_mm,
            );
            p.z = bend[0] * ((p.x - x0) / rr).powi(2) + bend[1] * ((p.y - y0) / rr).powi(2);
            if let Some(uv) = geom::project(k, &(cam_from_board * p).coords) {
                out.push((view.id, k_i, uv));
            }
        }
    }
    out
}

/// Residuals `(view id, corner, du, dv)` of the detected corners of `data` under an estimate.
pub fn predict_residuals(
    data: &CameraData,
    k: &Intrinsics,
    x: &Isometry3<f64>,
    target: &Isometry3<f64>,
    scale: f64,
    bend: [f64; 2],
) -> Vec<(u64, usize, f64, f64)> {
    let obs = obs_of(&data.views, &data.board);
    let g = motion_poses(&data.views, data.mount);
    let p = Reproj {
        obs: &obs,
        flange: &g,
        layout: Layout::HandEye,
        intr_free: [false; N_INTR],
        intr_fixed: *k,
        board: BoardModel {
            scale: true,
            bend: true,
            centre: bend_centre(&data.board),
        },
        arm: None,
        flange_map: None,
    };
    let r = crate::solve::lm::LsqProblem::residuals(&p, &p.pack(k, &[*x, *target], scale, bend));
    let ids = corner_ids(&data.views);
    ids.iter()
        .enumerate()
        .map(|(i, (v, c))| (*v, *c, r[2 * i], r[2 * i + 1]))
        .collect()
}

fn corner_ids(views: &[View]) -> Vec<(u64, usize)> {
    views
        .iter()
        .flat_map(|v| {
            v.corners
                .iter()
                .enumerate()
                .filter(|(_, c)| c.is_some())
                .map(move |(k, _)| (v.id, k))
        })
        .collect()
}

/// Centre and radius of the bend model: the board's centre and its corner radius.
pub fn bend_centre(b: &detect::BoardSpec) -> [f64; 3] {
    let (w, h) = (
        (b.cols + 1) as f64 * b.square_mm,
        (b.rows + 1) as f64 * b.square_mm,
    );
    [w / 2.0, h / 2.0, (w * w + h * h).sqrt() / 2.0]
}

/// Robust σ (1.4826 · median absolute value).
fn robust_sigma(v: &[f64]) -> f64 {
    let mut a: Vec<f64> = v.iter().map(|x| x.abs()).collect();
    a.sort_by(f64::total_cmp);
    if a.is_empty() {
        return 0.0;
    }
    1.4826 * a[a.len() / 2]
}

/// Hand-eye ML fit: intrinsics (free per `mask`), X, target, optional board parameters.
/// The board scale the robot's motion implies, in closed form: `G_i X T_i = B` for every view
/// (`G_i` the motion pose, `T_i` the board in the camera from the board-only calibration, whose
/// translation scales with the square size while its rotation does not), with the hand-eye
/// rotation known from a closed form. Linear in `(t_X, s, t_B)`:
/// `R_Gi t_X + s·R_Gi R_X t_Ti − t_B = −t_Gi`. Robust to a square size off by any factor,
/// where an iterative refit stalls.
fn implied_board_scale(
    g: &[Isometry3<f64>],
    rx: &nalgebra::UnitQuaternion<f64>,
    t_list: &[Isometry3<f64>],
) -> f64 {
    let n = g.len().min(t_list.len());
    if n < 3 {
        return f64::NAN;
    }
    let mut a = nalgebra::DMatrix::zeros(3 * n, 7);
    let mut b = nalgebra::DVector::zeros(3 * n);
    for i in 0..n {
        let r = g[i].rotation.to_rotation_matrix();
        let v = r * (rx * t_list[i].translation.vector);
        for row in 0..3 {
            for col in 0..3 {
                a[(3 * i + row, col)] = r[(row, col)];
            }
            a[(3 * i + row, 3)] = v[row];
            a[(3 * i + row, 4 + row)] = -1.0;
            b[3 * i + row] = -g[i].translation.vector[row];
        }
    }
    a.svd(true, true)
        .solve(&b, 1e-12)
        .map_or(f64::NAN, |x| x[3])
}

/// Refuse a joint fit that had to bend the intrinsics to reconcile the robot's motion with the
/// images: the focal length more than 5 % from the board-only calibration `k_board`, or the
/// principal point outside the image. The commonest cause is a square size in the wrong unit
/// (`--square 3` for a 30 mm board): the board alone calibrates at any scale, but the robot's
/// translations fix the metric one. `implied_scale` refits with the board scale free to name
/// the square size the robot's motion implies.
fn check_joint_fit(
    data: &CameraData,
    (k_board, rms_board): (&Intrinsics, f64),
    (k_joint, rms_joint): (&Intrinsics, f64),
    implied_scale: impl FnOnce() -> f64,
) -> Result<(), CameraError> {
    let rel = (k_joint.fx / k_board.fx - 1.0)
        .abs()
        .max((k_joint.fy / k_board.fy - 1.0).abs());
    let (w, h) = (data.width as f64, data.height as f64);
    let pp_out = w > 0.0
        && h > 0.0
        && (!(0.0..=w).contains(&k_joint.cx) || !(0.0..=h).contains(&k_joint.cy));
    // The board alone explains the images; a joint fit that leaves far more than that (an arm
    // mm off leaves a fraction of a pixel) did not find a consistent hand-eye.
    let unexplained = !(rms_joint.is_finite() && rms_joint <= (20.0 * rms_board).max(5.0));
    if rel.is_finite() && rel <= 0.05 && !pp_out && !unexplained {
        return Ok(());
    }
    let what = format!(
        "with the declared square size {:.3} mm the joint fit leaves {:.2} px RMS (the board \
         alone {:.3} px) and needs fx {:.1} px and a principal point at ({:.1}, {:.1}) px in a \
         {}×{} image, where the board alone gives fx {:.1} px at ({:.1}, {:.1}) px",
        data.board.square_mm,
        rms_joint,
        rms_board,
        k_joint.fx,
        k_joint.cx,
        k_joint.cy,
        data.width,
        data.height,
        k_board.fx,
        k_board.cx,
        k_board.cy
    );
    let s = implied_scale();
    let cause = if s.is_finite() && s > 0.0 && (s - 1.0).abs() > 0.05 {
        format!(
            "the robot's motion says the squares are {:.2} mm, not {:.3}: check `--square` / the \
             header's `target.square_mm` (millimetres)",
            data.board.square_mm * s,
            data.board.square_mm
        )
    } else {
        "the square size is consistent with the robot's motion, so the robot poses do not belong \
         to these images (check the records' `flange` / `q`, the `mount`, that the camera did \
         not move on its mount, and that the robot model is this arm's)"
            .to_string()
    };
    Err(CameraError::Inconsistent(format!("{what}; {cause}")))
}

#[allow(clippy::too_many_arguments)]
fn ml_fit(
    obs: &[Obs],
    g: &[Isometry3<f64>],
    k: &Intrinsics,
    mask: [bool; N_INTR],
    x: &Isometry3<f64>,
    target: &Isometry3<f64>,
    board: BoardModel,
    scale: f64,
    bend: [f64; 2],
) -> (
    Intrinsics,
    Isometry3<f64>,
    Isometry3<f64>,
    f64,
    [f64; 2],
    crate::solve::lm::LmReport,
) {
    let p = Reproj {
        obs,
        flange: g,
        layout: Layout::HandEye,
        intr_free: mask,
        intr_fixed: *k,
        board,
        arm: None,
        flange_map: None,
    };
    let opts = LmOptions {
        max_iter: 200,
        ..LmOptions::default()
    };
    let rep = minimize(&p, p.pack(k, &[*x, *target], scale, bend), &opts);
    let (s, c) = p.board_params(&rep.x);
    (
        p.intrinsics(&rep.x),
        p.pose(&rep.x, 0),
        p.pose(&rep.x, 1),
        s,
        c,
        rep,
    )
}

/// The intrinsics (those free in `mask`) and the target fitted to `data` with the hand-eye
/// `x` held: `(intrinsics, target, RMS px)`. An X from the motions' consistency (a closed
/// form) with the camera and target that best predict the corners under it: how much of the
/// joint ML's predictive edge its X, rather than its camera, carries.
pub fn fit_with_x_held(
    data: &CameraData,
    k: &Intrinsics,
    mask: [bool; N_INTR],
    x: &Isometry3<f64>,
    b0: &Isometry3<f64>,
) -> (Intrinsics, Isometry3<f64>, f64) {
    let obs = obs_of(&data.views, &data.board);
    let g = motion_poses(&data.views, data.mount);
    let p = Reproj {
        obs: &obs,
        flange: &g,
        layout: Layout::HandEye,
        intr_free: mask,
        intr_fixed: *k,
        board: BoardModel::default(),
        arm: None,
        flange_map: None,
    };
    let o = p.pose_offset(0);
    let h = crate::solve::lm::Held::new(&p, p.pack(k, &[*x, *b0], 1.0, [0.0; 2]), o..o + 6);
    let opts = LmOptions {
        max_iter: 200,
        ..LmOptions::default()
    };
    let rep = minimize(&h, h.free_of(&h.at), &opts);
    let full = h.full(&rep.x);
    (p.intrinsics(&full), p.pose(&full, 1), rms(&rep.residuals))
}

/// X and target fitted to `data` with the intrinsics `k` held, from `x0`, `b0`:
/// `(X, target, RMS px)` (the held-out floor: what the views' own robot-pose error leaves).
pub fn fit_fixed_intrinsics(
    data: &CameraData,
    k: &Intrinsics,
    x0: &Isometry3<f64>,
    b0: &Isometry3<f64>,
) -> (Isometry3<f64>, Isometry3<f64>, f64) {
    let obs = obs_of(&data.views, &data.board);
    let g = motion_poses(&data.views, data.mount);
    let (_, x, t, _, _, rep) = ml_fit(
        &obs,
        &g,
        k,
        [false; N_INTR],
        x0,
        b0,
        BoardModel::default(),
        1.0,
        [0.0; 2],
    );
    (x, t, rms(&rep.residuals))
}

/// Target pose from X and the per-view board poses: mean of `G_i X T_i`.
fn target_from(g: &[Isometry3<f64>], x: &Isometry3<f64>, t: &[Isometry3<f64>]) -> Isometry3<f64> {
    let all: Vec<Isometry3<f64>> = g.iter().zip(t).map(|(g, t)| g * x * t).collect();
    geom::mean_pose(&all)
}

/// Zhang's closed form from one homography per view (`per_view`: each view's corners), with
/// a centred-principal-point fallback when the full form is implausible: the camera matrix
/// and the distortion-free intrinsics.
fn zhang_start(
    data: &CameraData,
    per_view: &[Vec<Obs>],
) -> Result<(Matrix3<f64>, Intrinsics), CameraError> {
    let hs: Vec<Matrix3<f64>> = per_view.iter().filter_map(|o| view_h(o)).collect();
    let (w, h) = (data.width as f64, data.height as f64);
    let (cx0, cy0) = (w / 2.0 - 0.5, h / 2.0 - 0.5);
    let plausible = |k: &Matrix3<f64>| {
        let f = (k[(0, 0)] * k[(1, 1)]).sqrt();
        f > 0.1 * w
            && f < 20.0 * w
            && (k[(0, 0)] / k[(1, 1)] - 1.0).abs() < 0.2
            && (k[(0, 2)] - cx0).abs() < 0.3 * w
            && (k[(1, 2)] - cy0).abs() < 0.3 * h
    };
    let k0m = zhang::zhang_k(&hs, cx0, cy0, w)
        .filter(plausible)
        .or_else(|| zhang::focal_centered(&hs, cx0, cy0))
        .ok_or_else(|| CameraError::Intrinsics("no focal length fits the homographies".into()))?;
    let k0 = Intrinsics {
        fx: k0m[(0, 0)],
        fy: k0m[(1, 1)],
        cx: k0m[(0, 2)],
        cy: k0m[(1, 2)],
        dist: [0.0; 5],
    };
    Ok((k0m, k0))
}

thread_local! {
    static CALIBRATIONS: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

/// The distortion model chosen is the simplest whose validation error is within this factor of
/// the best ([`calibrate`] step 2).
pub const DIST_MODEL_SIMPLER: f64 = 1.02;

/// A distortion model whose validation error is within this factor of the best is as
/// plausible as the chosen one: X's move under it enters X's stated 1σ ([`calibrate`]).
pub const DIST_MODEL_PLAUSIBLE: f64 = 1.05;

/// How many camera calibrations ([`calibrate`]) this thread has run: a test counts the fits
/// of a pipeline.
pub fn calibrations_on_this_thread() -> usize {
    CALIBRATIONS.with(|c| c.get())
}

/// Calibrate intrinsics and hand-eye (see the module docs).
pub fn calibrate(
    train: &CameraData,
    heldout: Option<&CameraData>,
    opts: &Options,
) -> Result<CameraResult, CameraError> {
    CALIBRATIONS.with(|c| c.set(c.get() + 1));
    let board = train.board;
    let mut rejected_views: Vec<(u64, String)> = vec![];
    let mut views: Vec<View> = vec![];
    for v in &train.views {
        let n = v.corners.iter().filter(|c| c.is_some()).count();
        if n >= 6 {
            views.push(v.clone());
        } else {
            rejected_views.push((v.id, format!("{n} corners")));
        }
    }
    if views.len() < 4 {
        return Err(CameraError::TooFewViews {
            got: views.len(),
            need: 4,
        });
    }
    // 1. Homographies and Zhang.
    let per_view: Vec<Vec<Obs>> = views
        .iter()
        .map(|v| single_view(&obs_of(std::slice::from_ref(v), &board)))
        .collect();
    let (k0m, k0) = zhang_start(train, &per_view)?;
    // 2. Intrinsics on up to 20 spread views, model by validation on the others.
    let n = views.len();
    let nsub = n.min(20);
    let sub: Vec<usize> = (0..nsub).map(|i| i * n / nsub).collect();
    let val: Vec<usize> = (0..n).filter(|i| !sub.contains(i)).collect();
    let val = if val.len() >= 3 {
        val
    } else {
        (0..n).collect()
    };
    let sub_obs: Vec<&[Obs]> = sub.iter().map(|&v| per_view[v].as_slice()).collect();
    let init_poses: Vec<Isometry3<f64>> = sub
        .iter()
        .map(|&v| {
            view_h(&per_view[v])
                .and_then(|h| zhang::pose_from_h(&k0m, &h))
                .unwrap_or_else(Isometry3::identity)
        })
        .collect();
    let models: Vec<DistModel> = match opts.distortion {
        Some(m) => vec![m],
        None => DistModel::ALL.to_vec(),
    };
    // One distortion model per core (collected in the models' order).
    let fits: Vec<(DistModel, Intrinsics, f64, f64, DMatrix<f64>)> = models
        .into_par_iter()
        .filter_map(|m| {
            let b = boardonly::fit(&sub_obs, &init_poses, &k0, m.mask(), &LmOptions::default())?;
            let k = b.k;
            // Validation: other views' poses fitted with k held.
            let vr = validation_rms(
                &k,
                val.iter().map(|&v| {
                    let init = view_h(&per_view[v])
                        .and_then(|h| zhang::pose_from_h(&k_matrix(&k), &h))
                        .unwrap_or_else(Isometry3::identity);
                    (per_view[v].as_slice(), init)
                }),
            );
            Some((m, k, b.rms, vr, b.cov))
        })
        .collect();
    let best_val = fits.iter().map(|f| f.3).fold(f64::INFINITY, f64::min);
    // Simplest model within 2 % of the best validation error.
    let chosen = fits
        .iter()
        .find(|f| f.3 <= best_val * DIST_MODEL_SIMPLER)
        .cloned()
        .ok_or_else(|| CameraError::Intrinsics("no distortion model converged".into()))?;
    let (model, mut k1, mut k1_rms, _, mut k1_cov_model) = chosen;
    let model_scores = fits.iter().map(|f| (f.0, f.3)).collect();
    // The models as plausible as the chosen one (it included), simplest first, with their
    // intrinsics from the selection: the stated 1σ and the bootstrap see the choice too.
    let mut plausible_models: Vec<(DistModel, Intrinsics)> = fits
        .iter()
        .filter(|f| f.3 <= best_val * DIST_MODEL_PLAUSIBLE)
        .map(|f| (f.0, f.1))
        .collect();
    // 3. Every view's board pose with k1; reject views / corners by residual.
    let mut t_views = vec![];
    let mut view_rms = vec![];
    for ob in &per_view {
        let init = view_h(ob)
            .and_then(|h| zhang::pose_from_h(&k_matrix(&k1), &h))
            .unwrap_or_else(Isometry3::identity);
        let (t, r, res) = pnp(&k1, ob, init);
        t_views.push((t, res));
        view_rms.push(r);
    }
    let med = {
        let mut s = view_rms.clone();
        s.sort_by(f64::total_cmp);
        s[s.len() / 2]
    };
    let all_res: Vec<f64> = t_views
        .iter()
        .flat_map(|(_, r)| r.iter().copied())
        .collect();
    let sig = robust_sigma(&all_res).max(1e-3);
    let mut keep_views = vec![];
    let mut rejected_corners = 0;
    for (i, v) in views.iter_mut().enumerate() {
        if !(view_rms[i].is_finite()) || view_rms[i] > (4.0 * med).max(med + 0.5) {
            rejected_views.push((
                v.id,
                format!(
                    "reprojection RMS {:.3} px vs median {:.3} px",
                    view_rms[i], med
                ),
            ));
            continue;
        }
        // Corner rejection (5 σ).
        let res = &t_views[i].1;
        let mut k = 0;
        for c in v.corners.iter_mut() {
            if c.is_some() {
                let e = (res[2 * k].powi(2) + res[2 * k + 1].powi(2)).sqrt();
                if e > 5.0 * sig * std::f64::consts::SQRT_2 {
                    *c = None;
                    rejected_corners += 1;
                }
                k += 1;
            }
        }
        keep_views.push(i);
    }
    let views: Vec<View> = keep_views.iter().map(|&i| views[i].clone()).collect();
    let mut t_list: Vec<Isometry3<f64>> = keep_views.iter().map(|&i| t_views[i].0).collect();
    if views.len() < 4 {
        return Err(CameraError::TooFewViews {
            got: views.len(),
            need: 4,
        });
    }
    // Every kept view's corners (after the corner rejection), one slice per view.
    let kept_obs: Vec<Vec<Obs>> = views
        .iter()
        .map(|v| single_view(&obs_of(std::slice::from_ref(v), &board)))
        .collect();
    let kept_obs: Vec<&[Obs]> = kept_obs.iter().map(Vec::as_slice).collect();
    // The chosen model's intrinsics refitted on every kept view (the model was chosen on up to
    // 20 of them): on a real UR3e set (66 training views of a 6×5 board) X then moves 1.97 mm
    // between random halves of the views on average, 2.62 mm with the intrinsics of 20.
    let k1_fit = boardonly::fit(&kept_obs, &t_list, &k1, model.mask(), &LmOptions::default());
    if let Some(f) = &k1_fit {
        k1 = f.k;
        k1_rms = f.rms;
        k1_cov_model = f.cov.clone();
        t_list = f.poses.clone();
    }
    let kept = CameraData {
        views: views.clone(),
        ..train.clone()
    };
    let obs = obs_of(&views, &board);
    let g = motion_poses(&views, train.mount);
    // 4. Closed forms.
    let pairs = handeye::motion_pairs(&g, &t_list, 2.0);
    let mut closed = vec![];
    for m in Method::ALL {
        if let Some(x) = handeye::solve(m, &pairs) {
            let target = target_from(&g, &x, &t_list);
            closed.push(estimate(m.name(), &kept, heldout, &k1, &x, &target));
        }
    }
    let best = closed
        .iter()
        .filter(|e| e.train_rms_px.is_finite())
        .min_by(|a, b| a.train_rms_px.total_cmp(&b.train_rms_px))
        .ok_or(CameraError::HandEye)?
        .clone();
    // 5. ML refinement (robust: one pass of 5σ corner rejection).
    let bc = BoardModel {
        centre: bend_centre(&board),
        ..opts.board
    };
    // From the best closed form, on every corner (`board` says which board parameters are free).
    let from_best = |board: BoardModel| {
        ml_fit(
            &obs,
            &g,
            &k1,
            model.mask(),
            &best.x,
            &best.target,
            board,
            1.0,
            [0.0; 2],
        )
    };
    let (mut kf, mut xf, mut tf, mut sf, mut cf, mut rep) = from_best(bc);
    let sig2 = robust_sigma(rep.residuals.as_slice()).max(1e-4);
    let bad: Vec<bool> = (0..obs.len())
        .map(|i| {
            rep.residuals[2 * i].hypot(rep.residuals[2 * i + 1])
                > 5.0 * sig2 * std::f64::consts::SQRT_2
        })
        .collect();
    let ids_all = corner_ids(&views);
    let mut ids = ids_all.clone();
    if bad.iter().any(|b| *b) {
        rejected_corners += bad.iter().filter(|b| **b).count();
        let obs_used: Vec<Obs> = obs
            .iter()
            .zip(&bad)
            .filter(|(_, b)| !**b)
            .map(|(o, _)| *o)
            .collect();
        ids = ids_all
            .iter()
            .zip(&bad)
            .filter(|(_, b)| !**b)
            .map(|(o, _)| *o)
            .collect();
        (kf, xf, tf, sf, cf, rep) = ml_fit(&obs_used, &g, &kf, model.mask(), &xf, &tf, bc, sf, cf);
    }
    check_joint_fit(train, (&k1, k1_rms), (&kf, rms(&rep.residuals)), || {
        implied_board_scale(&g, &best.x.rotation, &t_list)
    })?;
    // A square size a little off (31 mm for a 30 mm board) passes the 5 % check above but
    // shifts the focal length and the hand-eye translation by as much: warn from 1 % on.
    let implied_scale = implied_board_scale(&g, &best.x.rotation, &t_list);
    let s = implied_scale;
    if s.is_finite() && s > 0.0 && (s - 1.0).abs() > 0.01 {
        tracing::warn!(
            "the robot's motion says the board squares are {:.3} mm, not the declared {:.3} mm \
             ({:+.1} %): check `--square` / the header's `target.square_mm`; the focal length \
             and the hand-eye translation scale with it",
            train.board.square_mm * s,
            train.board.square_mm,
            (s - 1.0) * 100.0
        );
    }
    let ml_free = Estimate {
        method: "ml".into(),
        x: xf,
        target: tf,
        intrinsics: kf,
        train_rms_px: rms(&rep.residuals),
        heldout_rms_px: heldout.map(|h| heldout_rms(h, &kf, &xf, &tf, sf, cf)),
    };
    // 6. The written estimate, chosen by internal cross-validation on the training views
    // (with the default board model; a diagnosis freeing the board keeps the joint ML), and
    // its uncertainty: the larger of the model covariance and the view jackknife.
    let mut unc = covariance(&rep, &model.mask(), bc);
    let ctx = select::Ctx {
        data: &kept,
        t_list: &t_list,
        g: &g,
        k1,
        mask: model.mask(),
        sigma_px: k1_rms / std::f64::consts::SQRT_2,
        x0: best.x,
        b0: best.target,
    };
    let all: Vec<usize> = (0..views.len()).collect();
    let mut cv_scores = vec![];
    let mut candidates = vec![];
    let mut pose_noise = None;
    let mut chosen = select::Candidate::Ml;
    let mut all_fits: Vec<(select::Candidate, Option<select::Fit>)> = vec![];
    // Every candidate's CV errors per view (empty when the CV does not run).
    let mut per: Vec<(select::Candidate, Option<select::PerView>)> = vec![];
    let robot_dominates = best.train_rms_px > select::ROBOT_DOMINATES_RATIO * k1_rms;
    if !bc.scale && !bc.bend && views.len() >= 8 {
        // The candidates' cross-validations and fits are independent: one per core (the
        // order of the results, hence the choice, is the same as one after the other).
        per = select::Candidate::all()
            .into_par_iter()
            .map(|c| (c, ctx.cv_views(c, 5)))
            .collect();
        cv_scores = per
            .iter()
            .map(|(c, v)| (c.name(), select::cv_of(v.as_deref())))
            .collect();
        chosen = select::choose(&per, robot_dominates).unwrap_or(chosen);
        candidates.push(ml_free.clone());
        all_fits = [
            select::Candidate::MlBoardIntrinsics,
            select::Candidate::PoseNoise,
            select::Candidate::PoseNoiseFull,
            select::Candidate::ViewCorrections,
            select::Candidate::ViewCorrectionsScaled(-4),
            select::Candidate::ViewCorrectionsScaled(-3),
            select::Candidate::ViewCorrectionsScaled(-2),
        ]
        .into_par_iter()
        .map(|c| (c, ctx.fit(c, &all)))
        .collect();
        for (c, f) in &all_fits {
            if let Some(f) = f {
                pose_noise = pose_noise.or(f.pose_noise);
                candidates.push(Estimate {
                    method: c.name(),
                    ..estimate("", &kept, heldout, &f.k, &f.x, &f.target)
                });
            }
        }
    }
    // The chosen candidate's fit on every view, taken from the fits above when it is one.
    let chosen_fit = match chosen {
        select::Candidate::Ml => None,
        c => match all_fits.iter().find(|(a, _)| *a == c) {
            Some((_, f)) => f.clone(),
            None => ctx.fit(c, &all),
        },
    };
    // The joint ML's X on every view (an alternative to the written candidate below).
    let ml_free_x = ml_free.x;
    let (ml, residuals) = match &chosen_fit {
        None => {
            let residuals = ids
                .iter()
                .enumerate()
                .map(|(i, (v, c))| (*v, *c, rep.residuals[2 * i], rep.residuals[2 * i + 1]))
                .collect();
            (ml_free, residuals)
        }
        Some(f) => {
            (sf, cf) = (1.0, [0.0; 2]);
            unc.x_mm = f.sd_mm;
            unc.x_deg = f.sd_deg;
            (
                Estimate {
                    method: chosen.name(),
                    ..estimate("", &kept, heldout, &f.k, &f.x, &f.target)
                },
                predict_residuals(&kept, &f.k, &f.x, &f.target, 1.0, [0.0; 2]),
            )
        }
    };
    if let Some((jt, jr)) = ctx.jackknife(chosen) {
        for a in 0..3 {
            unc.x_mm[a] = unc.x_mm[a].max(jt[a]);
            unc.x_deg[a] = unc.x_deg[a].max(jr[a]);
        }
    }
    // A candidate that holds the board-only intrinsics: their own uncertainty moves X too
    // (the jackknife and the model covariance hold them), added in quadrature.
    if chosen != select::Candidate::Ml {
        let mut parts = SigmaParts {
            fit_mm: unc.x_mm,
            fit_deg: unc.x_deg,
            ..Default::default()
        };
        // The intrinsics' covariance: the view jackknife of the board-only fit when it is
        // larger (one view's corners share errors — focus, the board's flatness there — that
        // the model covariance, every corner independent, does not see).
        let jk = k1_fit
            .as_ref()
            .and_then(|f| boardonly::jackknife(&kept_obs, f, model.mask()));
        let k1_cov = match jk {
            Some(j) if j.trace() > k1_cov_model.trace() => j,
            _ => k1_cov_model,
        };
        if let Some((pt, pr)) = intrinsics_propagation(&ctx, chosen, &k1_cov, &kept_obs, &all) {
            for a in 0..3 {
                unc.x_mm[a] = unc.x_mm[a].hypot(pt[a]);
                unc.x_deg[a] = unc.x_deg[a].hypot(pr[a]);
            }
            (parts.intrinsics_mm, parts.intrinsics_deg) = (pt, pr);
        }
        // The distortion model itself: another model whose validation error is within
        // `DIST_MODEL_PLAUSIBLE` of the best fits the views as well, and can move X (on a real
        // UR3e set the tangential terms move the principal point 16 px and X's rotation
        // 1.2–1.4°, and halves of the set choose differently). X's spread over the plausible
        // models ([`model_spread`]) is added in quadrature.
        // Plausible on the board alone is not enough: under the other model's intrinsics the
        // written candidate must also predict the training corners through the robot's poses
        // about as well (within `DIST_MODEL_PLAUSIBLE`). On a simulated cell whose views barely
        // tilt, the tangential model's board-only fit on every view went to a focal length 3 %
        // off, which the board alone could not refuse but the robot's motion does.
        let plausible: Vec<(DistModel, Intrinsics, Isometry3<f64>)> = plausible_models
            .par_iter()
            .filter(|(m, _)| *m != model)
            .filter_map(|(m, k)| {
                let b = boardonly::fit(&kept_obs, &t_list, k, m.mask(), &LmOptions::default())?;
                let f = fit_under_intrinsics_full(&ctx, &kept_obs, b.k, chosen, &all)?;
                let rms = heldout_rms(&kept, &f.k, &f.x, &f.target, 1.0, [0.0; 2]);
                (rms <= ml.train_rms_px * DIST_MODEL_PLAUSIBLE).then_some((*m, b.k, f.x))
            })
            .collect();
        plausible_models.retain(|(m, _)| *m == model || plausible.iter().any(|p| p.0 == *m));
        // Weighed by how often the calibration's own rule chooses each model when the views are
        // resampled: on a real KUKA set three models are within 1 % of each other but the rule
        // keeps the simplest in 46 of 50 resamples; on a real UR3e the tangential model is
        // chosen in most resamples although the full set chooses k1.
        // When no resample could choose (too few distinct views in every one), every plausible
        // model is counted as equally likely.
        let shares = if plausible.is_empty() {
            vec![]
        } else {
            model_shares(&kept_obs, ctx.t_list, &plausible_models, model, opts.seed).unwrap_or_else(
                || {
                    let w = 1.0 / plausible_models.len() as f64;
                    plausible_models.iter().map(|(m, _)| (*m, w)).collect()
                },
            )
        };
        let share = |m: DistModel| shares.iter().find(|(a, _)| *a == m).map_or(0.0, |s| s.1);
        let xs: Vec<(Isometry3<f64>, f64)> = plausible.iter().map(|p| (p.2, share(p.0))).collect();
        if let Some((mt, mr)) = model_spread(&ml.x, &xs) {
            for a in 0..3 {
                unc.x_mm[a] = unc.x_mm[a].hypot(mt[a]);
                unc.x_deg[a] = unc.x_deg[a].hypot(mr[a]);
            }
            (parts.distortion_model_mm, parts.distortion_model_deg) = (mt, mr);
            parts.plausible_models = plausible.iter().map(|p| p.0).collect();
            parts.model_shares = plausible_models
                .iter()
                .map(|(m, _)| (*m, share(*m)))
                .collect();
            parts.model_shares.sort_by_key(|(m, _)| *m != model);
        }
        unc.x_parts = Some(parts);
    }
    // The estimator itself: resamples of the views choose other candidates (the same per-view
    // CV errors drawn with the views, [`select::choice_shares`]), whose X on every view may be
    // millimetres from the written one. X's distance to the X of a candidate drawn with those
    // shares ([`model_spread`]) is added in quadrature, as the lens model's is.
    if !per.is_empty() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(opts.seed ^ 0x5e1e_c7ed);
        let n = views.len();
        let picks: Vec<Vec<usize>> = (0..SELECTION_RESAMPLES)
            .map(|_| (0..n).map(|_| rng.random_range(0..n)).collect())
            .collect();
        let mut shares = select::choice_shares(&per, robot_dominates, &picks);
        // The written candidate first, then the others by share.
        shares.sort_by(|a, b| {
            (a.0 != chosen)
                .cmp(&(b.0 != chosen))
                .then(b.1.total_cmp(&a.1))
        });
        let alternatives: Vec<(Isometry3<f64>, f64)> = shares
            .par_iter()
            .filter(|(c, _)| *c != chosen)
            .filter_map(|(c, w)| {
                let x = match c {
                    select::Candidate::Ml => Some(ml_free_x),
                    c => match all_fits.iter().find(|(a, _)| a == c) {
                        Some((_, f)) => f.as_ref().map(|f| f.x),
                        None => ctx.fit(*c, &all).map(|f| f.x),
                    },
                }?;
                Some((x, *w))
            })
            .collect();
        let mut parts = unc.x_parts.take().unwrap_or_else(|| SigmaParts {
            fit_mm: unc.x_mm,
            fit_deg: unc.x_deg,
            ..Default::default()
        });
        if let Some((st, sr)) = model_spread(&ml.x, &alternatives) {
            for a in 0..3 {
                unc.x_mm[a] = unc.x_mm[a].hypot(st[a]);
                unc.x_deg[a] = unc.x_deg[a].hypot(sr[a]);
            }
            (parts.estimator_mm, parts.estimator_deg) = (st, sr);
        }
        parts.estimator_shares = shares.iter().map(|(c, w)| (c.name(), *w)).collect();
        unc.x_parts = Some(parts);
    }
    if opts.bootstrap > 0 {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(opts.seed);
        // The resamples are drawn in order (the same ones as one fit after the other), the
        // refits run one per core.
        let picks: Vec<Vec<usize>> = (0..opts.bootstrap)
            .map(|_| {
                (0..views.len())
                    .map(|_| rng.random_range(0..views.len()))
                    .collect()
            })
            .collect();
        // Each resample writes the candidate its views choose (the same per-view CV errors
        // drawn with the views), as the stated 1σ's estimator part assumes.
        let xs: Vec<Isometry3<f64>> = picks
            .par_iter()
            .map(|pick| {
                let c = if per.is_empty() {
                    chosen
                } else {
                    select::choose(&select::resampled(&per, pick), robot_dominates)
                        .unwrap_or(chosen)
                };
                (c, pick)
            })
            .filter_map(|(c, pick)| match c {
                select::Candidate::Ml => {
                    let bv: Vec<View> = pick.iter().map(|&i| views[i].clone()).collect();
                    let bo = obs_of(&bv, &board);
                    let bg = motion_poses(&bv, train.mount);
                    Some(ml_fit(&bo, &bg, &kf, model.mask(), &xf, &tf, bc, sf, cf).1)
                }
                // The board-only intrinsics re-estimated on the resample too (its distinct
                // views; the distortion model re-chosen among the plausible ones by the views
                // the resample left out), every view's board pose re-solved under them: the
                // bootstrap then sees what the intrinsics and the model choice do to X.
                c => {
                    let (_, k) =
                        refit_intrinsics(&kept_obs, ctx.t_list, &plausible_models, model, pick)?;
                    fit_under_intrinsics(&ctx, &kept_obs, k, c, pick)
                }
            })
            .collect();
        let (st, sr) = select::spread(&xs, &ml.x);
        let nb = xs.len().max(2) as f64;
        let c = (nb / (nb - 1.0)).sqrt();
        unc.bootstrap = Some((xs.len(), st.map(|v| v * c), sr.map(|v| v * c)));
    }
    let incremental = if opts.incremental {
        Some(incremental(&kept, heldout, &k1, &t_list, opts.seed))
    } else {
        None
    };
    Ok(CameraResult {
        distortion: model,
        model_scores,
        intrinsics_only: k1,
        intrinsics_rms_px: k1_rms,
        closed_form: closed,
        ml,
        incremental,
        uncertainty: unc,
        board_scale: sf,
        board_bend_mm: cf,
        used_views: views.iter().map(|v| v.id).collect(),
        rejected_views,
        rejected_corners,
        residuals,
        cv_scores,
        candidates,
        pose_noise,
        implied_scale,
    })
}

fn estimate(
    name: &str,
    data: &CameraData,
    heldout: Option<&CameraData>,
    k: &Intrinsics,
    x: &Isometry3<f64>,
    target: &Isometry3<f64>,
) -> Estimate {
    Estimate {
        method: name.into(),
        x: *x,
        target: *target,
        intrinsics: *k,
        train_rms_px: heldout_rms(data, k, x, target, 1.0, [0.0; 2]),
        heldout_rms_px: heldout.map(|h| heldout_rms(h, k, x, target, 1.0, [0.0; 2])),
    }
}

/// The board-only intrinsics refitted on the distinct views of `pick` (`per_view`: each view's
/// corners, `poses`: their board poses to start from) under each of the distortion models
/// `models` (simplest first, with intrinsics to start from), the model chosen as the
/// calibration chooses it: the simplest within [`DIST_MODEL_SIMPLER`] of the best error on the
/// views `pick` left out (the `chosen` model when fewer than 3 are left out).
fn refit_intrinsics(
    per_view: &[&[Obs]],
    poses: &[Isometry3<f64>],
    models: &[(DistModel, Intrinsics)],
    chosen: DistModel,
    pick: &[usize],
) -> Option<(DistModel, Intrinsics)> {
    let mut distinct: Vec<usize> = pick.to_vec();
    distinct.sort_unstable();
    distinct.dedup();
    if distinct.len() < 4 {
        return None;
    }
    let out: Vec<usize> = (0..per_view.len())
        .filter(|v| distinct.binary_search(v).is_err())
        .collect();
    let ob: Vec<&[Obs]> = distinct.iter().map(|&v| per_view[v]).collect();
    let ps: Vec<Isometry3<f64>> = distinct.iter().map(|&v| poses[v]).collect();
    let models: Vec<&(DistModel, Intrinsics)> = if out.len() >= 3 {
        models.iter().collect()
    } else {
        models.iter().filter(|(m, _)| *m == chosen).collect()
    };
    let fits: Vec<(DistModel, Intrinsics, f64)> = models
        .iter()
        .filter_map(|(m, k)| {
            let f = boardonly::fit(&ob, &ps, k, m.mask(), &LmOptions::default())?;
            let vr = validation_rms(&f.k, out.iter().map(|&v| (per_view[v], poses[v])));
            Some((*m, f.k, vr))
        })
        .collect();
    let best = fits.iter().map(|f| f.2).fold(f64::INFINITY, f64::min);
    fits.iter()
        .find(|f| f.2 <= best * DIST_MODEL_SIMPLER)
        .map(|f| (f.0, f.1))
}

/// Resamples of the views drawn to weigh the plausible distortion models ([`model_shares`]).
pub const MODEL_SHARE_RESAMPLES: usize = 40;

/// Resamples of the views drawn to see how often each candidate estimator is chosen
/// ([`select::choice_shares`]; no refit, only the per-view CV errors redrawn).
pub const SELECTION_RESAMPLES: usize = 200;

/// How often each of `models` (the plausible distortion models, `chosen` among them) is the one
/// the calibration's rule chooses when the views are resampled with replacement: the intrinsics
/// refitted on each resample's distinct views under every model, the model chosen by the views
/// the resample left out ([`refit_intrinsics`]). In `models`' order; the shares add to 1 over
/// the resamples where a model was chosen (`None` when none was).
fn model_shares(
    per_view: &[&[Obs]],
    poses: &[Isometry3<f64>],
    models: &[(DistModel, Intrinsics)],
    chosen: DistModel,
    seed: u64,
) -> Option<Vec<(DistModel, f64)>> {
    let n = per_view.len();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x1e45_0de1);
    let picks: Vec<Vec<usize>> = (0..MODEL_SHARE_RESAMPLES)
        .map(|_| (0..n).map(|_| rng.random_range(0..n)).collect())
        .collect();
    let won: Vec<DistModel> = picks
        .par_iter()
        .filter_map(|pick| refit_intrinsics(per_view, poses, models, chosen, pick).map(|c| c.0))
        .collect();
    if won.is_empty() {
        return None;
    }
    let total = won.len() as f64;
    Some(
        models
            .iter()
            .map(|(m, _)| (*m, won.iter().filter(|w| *w == m).count() as f64 / total))
            .collect(),
    )
}

/// X of candidate `c` on the views `idx` with the board-only intrinsics replaced by `k`: every
/// view's board pose (`per_view`: each view's corners) re-solved under `k` first.
fn fit_under_intrinsics(
    ctx: &select::Ctx,
    per_view: &[&[Obs]],
    k: Intrinsics,
    c: select::Candidate,
    idx: &[usize],
) -> Option<Isometry3<f64>> {
    fit_under_intrinsics_full(ctx, per_view, k, c, idx).map(|f| f.x)
}

/// [`fit_under_intrinsics`] with the whole fit (X, target, intrinsics).
fn fit_under_intrinsics_full(
    ctx: &select::Ctx,
    per_view: &[&[Obs]],
    k: Intrinsics,
    c: select::Candidate,
    idx: &[usize],
) -> Option<select::Fit> {
    let t_list: Vec<Isometry3<f64>> = per_view
        .iter()
        .zip(ctx.t_list)
        .map(|(ob, t0)| pnp(&k, ob, *t0).0)
        .collect();
    ctx.with_intrinsics(k, &t_list).fit(c, idx)
}

/// 1σ of X (translation mm, rotation deg about X's own axes) that the board-only intrinsics'
/// uncertainty `k_cov` (free intrinsics of `ctx.mask`) causes in the candidate `c`: along each
/// principal direction of `k_cov` the intrinsics are moved by ±1σ, every view's board pose
/// re-solved under them (`per_view`: each kept view's corners) and `c` refitted on `idx`; the
/// half-differences of X add in quadrature. On a real UR3e (640×480, a 6×5 board) the principal
/// point moves 15 px between random halves of the views and X's rotation 1.2° with it, which
/// the view jackknife (intrinsics held) puts at 0.1°.
fn intrinsics_propagation(
    ctx: &select::Ctx,
    c: select::Candidate,
    k_cov: &DMatrix<f64>,
    per_view: &[&[Obs]],
    idx: &[usize],
) -> Option<([f64; 3], [f64; 3])> {
    let m = k_cov.nrows();
    if m == 0 || per_view.len() != ctx.t_list.len() {
        return None;
    }
    let free: Vec<usize> = (0..N_INTR).filter(|i| ctx.mask[*i]).collect();
    if free.len() != m {
        return None;
    }
    let eig = nalgebra::SymmetricEigen::new(k_cov.clone());
    let dirs: Vec<(usize, f64)> = (0..m)
        .filter(|&i| eig.eigenvalues[i] > 0.0 && eig.eigenvalues[i].is_finite())
        .flat_map(|i| [(i, 1.0), (i, -1.0)])
        .collect();
    let xs: Vec<Option<Isometry3<f64>>> = dirs
        .par_iter()
        .map(|&(i, sign)| {
            let step = eig.eigenvectors.column(i) * (sign * eig.eigenvalues[i].sqrt());
            let mut v = ctx.k1.to_vec();
            for (k, &f) in free.iter().enumerate() {
                v[f] += step[k];
            }
            fit_under_intrinsics(ctx, per_view, Intrinsics::from_slice(&v), c, idx)
        })
        .collect();
    let (mut st, mut sr) = ([0.0; 3], [0.0; 3]);
    for pair in xs.chunks(2) {
        let (Some(a), Some(b)) = (pair[0], pair[1]) else {
            return None;
        };
        let dt = (a.translation.vector - b.translation.vector) / 2.0;
        let dr = (b.inverse() * a).rotation.scaled_axis() / 2.0;
        for k in 0..3 {
            st[k] += dt[k] * dt[k];
            sr[k] += dr[k].to_degrees().powi(2);
        }
    }
    Some((st.map(f64::sqrt), sr.map(f64::sqrt)))
}

/// How far X may be from `x` (the written fit) because the distortion model was chosen among
/// plausible ones, whose fits of the same candidate (every view's board pose re-solved under
/// their intrinsics) are `alternatives`, each with the share of resamples of the views in
/// which the calibration's rule chooses it ([`model_shares`]): per coordinate (translation mm,
/// rotation deg about X's own axes) the root-mean-square distance from `x` to the X of a model
/// drawn with those shares (the chosen model, the rest of the shares, is at distance 0). `None`
/// without alternatives.
fn model_spread(
    x: &Isometry3<f64>,
    alternatives: &[(Isometry3<f64>, f64)],
) -> Option<([f64; 3], [f64; 3])> {
    if alternatives.is_empty() {
        return None;
    }
    let (mut st, mut sr) = ([0.0f64; 3], [0.0f64; 3]);
    for (xm, w) in alternatives {
        let dt = xm.translation.vector - x.translation.vector;
        let dr = (x.inverse() * xm).rotation.scaled_axis();
        for a in 0..3 {
            st[a] += w * dt[a] * dt[a];
            sr[a] += w * dr[a].to_degrees().powi(2);
        }
    }
    Some((st.map(f64::sqrt), sr.map(f64::sqrt)))
}

/// Standard deviations from the covariance `cov` of the parameters `x` of a hand-eye fit laid
/// out as the free intrinsics (`mask`), X, the target, then any extras: X's and the target's
/// rotations stated about their own axes ([`geom::cov_rotations_local`]).
pub fn std_local(cov: &DMatrix<f64>, x: &DVector<f64>, mask: &[bool; N_INTR]) -> Vec<f64> {
    let k = mask.iter().filter(|f| **f).count();
    let n = cov.nrows();
    let w = |o: usize| Vector3::new(x[o], x[o + 1], x[o + 2]);
    let cov = if n >= k + 12 && x.len() >= k + 12 {
        geom::cov_rotations_local(cov, &[(k, w(k)), (k + 6, w(k + 6))])
    } else {
        cov.clone()
    };
    (0..n).map(|i| cov[(i, i)].max(0.0).sqrt()).collect()
}

fn covariance(
    rep: &crate::solve::lm::LmReport,
    mask: &[bool; N_INTR],
    b: BoardModel,
) -> Uncertainty {
    let j: &DMatrix<f64> = &rep.jacobian;
    let (m, n) = (j.nrows(), j.ncols());
    let u = Uncertainty::default();
    if m <= n {
        return u;
    }
    let s2 = 2.0 * rep.cost / (m - n) as f64;
    let jtj = j.transpose() * j;
    let Some(inv) = jtj.clone().try_inverse() else {
        return u;
    };
    let _ = b;
    let sd = std_local(&(inv * s2), &rep.x, mask);
    Uncertainty::from_std(|i| sd[i], mask, None)
}

impl Uncertainty {
    /// The camera parameters' 1σ from per-parameter standard deviations `sd(i)` in the
    /// reprojection problem's layout: the free intrinsics (`mask`), X rotation + translation,
    /// then target rotation + translation (rad, mm).
    pub fn from_std(
        sd: impl Fn(usize) -> f64,
        mask: &[bool; N_INTR],
        bootstrap: Option<(usize, [f64; 3], [f64; 3])>,
    ) -> Uncertainty {
        let mut u = Uncertainty {
            bootstrap,
            ..Default::default()
        };
        let mut k = 0;
        for (i, f) in mask.iter().enumerate() {
            if *f {
                u.intrinsics[i] = sd(k);
                k += 1;
            }
        }
        for a in 0..3 {
            u.x_deg[a] = sd(k + a).to_degrees();
            u.x_mm[a] = sd(k + 3 + a);
            u.target_deg[a] = sd(k + 6 + a).to_degrees();
            u.target_mm[a] = sd(k + 9 + a);
        }
        u
    }
}

/// Seed 004's incremental Tsai–Lenz: update from 4 views on (error after each update), reject
/// views beyond mean + 2σ of their reprojection error, then average Tsai–Lenz over 50 random
/// subsets of 80/130 of the remaining views.
fn incremental(
    data: &CameraData,
    heldout: Option<&CameraData>,
    k: &Intrinsics,
    t: &[Isometry3<f64>],
    seed: u64,
) -> Incremental {
    let g = motion_poses(&data.views, data.mount);
    let n = data.views.len();
    let mut curve = vec![];
    let mut last: Option<(Isometry3<f64>, Isometry3<f64>)> = None;
    for m in 4..=n {
        let pairs = handeye::motion_pairs(&g[..m], &t[..m], 2.0);
        if let Some(x) = handeye::solve(Method::TsaiLenz, &pairs) {
            let target = target_from(&g[..m], &x, &t[..m]);
            let sub = CameraData {
                views: data.views[..m].to_vec(),
                ..data.clone()
            };
            curve.push((m, heldout_rms(&sub, k, &x, &target, 1.0, [0.0; 2])));
            last = Some((x, target));
        }
    }
    let (x, target) = last.unwrap_or((Isometry3::identity(), Isometry3::identity()));
    // 2σ rejection on per-view RMS.
    let per: Vec<f64> = data
        .views
        .iter()
        .map(|v| {
            let one = CameraData {
                views: vec![v.clone()],
                ..data.clone()
            };
            heldout_rms(&one, k, &x, &target, 1.0, [0.0; 2])
        })
        .collect();
    let mean = per.iter().sum::<f64>() / n as f64;
    let sd = (per.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (n.max(2) - 1) as f64).sqrt();
    let keep: Vec<usize> = (0..n).filter(|&i| per[i] <= mean + 2.0 * sd).collect();
    let rejected = (0..n)
        .filter(|i| !keep.contains(i))
        .map(|i| data.views[i].id)
        .collect();
    let msub = ((keep.len() * 80) as f64 / 130.0).round().max(4.0) as usize;
    let msub = msub.min(keep.len());
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x5eed_0004);
    let mut xs = vec![];
    for _ in 0..50 {
        let mut idx = keep.clone();
        idx.shuffle(&mut rng);
        idx.truncate(msub);
        idx.sort();
        let gs: Vec<Isometry3<f64>> = idx.iter().map(|&i| g[i]).collect();
        let ts: Vec<Isometry3<f64>> = idx.iter().map(|&i| t[i]).collect();
        if let Some(x) = handeye::solve(Method::TsaiLenz, &handeye::motion_pairs(&gs, &ts, 2.0)) {
            xs.push(x);
        }
    }
    let xa = if xs.is_empty() {
        x
    } else {
        geom::mean_pose(&xs)
    };
    let gk: Vec<Isometry3<f64>> = keep.iter().map(|&i| g[i]).collect();
    let tk: Vec<Isometry3<f64>> = keep.iter().map(|&i| t[i]).collect();
    let ta = target_from(&gk, &xa, &tk);
    let kept = CameraData {
        views: keep.iter().map(|&i| data.views[i].clone()).collect(),
        ..data.clone()
    };
    Incremental {
        curve,
        rejected,
        subset: (msub, xs.len()),
        estimate: estimate("incremental (seed 004)", &kept, heldout, k, &xa, &ta),
    }
}

/// The board's corner points (mm) in board order.
pub fn board_points(b: &detect::BoardSpec) -> Vec<Vector3<f64>> {
    (0..b.rows)
        .flat_map(|j| (0..b.cols).map(move |i| board_point(i, j, b.square_mm).coords))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};
    use rand_distr::{Distribution, Normal};

    /// The lens model's share of X's 1σ: the rms distance to the X of a model drawn with the
    /// shares the resamples give, the chosen model at distance 0 (one alternative at `d` with
    /// share `w`: `√w·d`); shares of 0 leave nothing.
    #[test]
    fn model_spread_weighs_each_model_by_its_share() {
        let x = Isometry3::identity();
        let alt = Isometry3::new(Vector3::new(2.0, 0.0, -1.0), Vector3::new(0.01, 0.0, 0.0));
        let (t, r) = model_spread(&x, &[(alt, 0.25)]).unwrap();
        assert!((t[0] - 1.0).abs() < 1e-12 && t[1] == 0.0 && (t[2] - 0.5).abs() < 1e-12);
        assert!((r[0] - 0.5 * 0.01f64.to_degrees()).abs() < 1e-9, "{r:?}");
        let (t, r) = model_spread(&x, &[(alt, 0.0)]).unwrap();
        assert_eq!((t, r), ([0.0; 3], [0.0; 3]));
        assert!(model_spread(&x, &[]).is_none());
    }

    /// Synthetic views with exact corners plus 0.05 px noise: the ML hand-eye recovers X.
    #[test]
    fn synthetic_eye_in_hand_and_eye_to_hand() {
        let k = Intrinsics {
            fx: 900.0,
            fy: 900.0,
            cx: 320.0,
            cy: 240.0,
            dist: [-0.05, 0.0, 0.0, 0.0, 0.0],
        };
        let board = detect::BoardSpec {
            cols: 8,
            rows: 5,
            square_mm: 30.0,
        };
        let x = Isometry3::from_parts(
            Translation3::new(0.0, 50.0, 40.0),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.01, -0.02, 0.03)),
        );
        let target = Isometry3::from_parts(
            Translation3::new(-576.9, -223.3, 0.0),
            UnitQuaternion::identity(),
        );
        let centre = target * nalgebra::Point3::new(135.0, 90.0, 0.0);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let noise = Normal::new(0.0, 0.05).unwrap();
        for mount in [Mount::Flange, Mount::Base] {
            let mut views = vec![];
            for v in 0..24 {
                let az = v as f64 * 0.9;
                let pol = 0.1 + 0.25 * ((v % 3) as f64) / 2.0;
                let r = 480.0 + 40.0 * (v % 5) as f64;
                let eye = centre
                    + Vector3::new(
                        r * pol.sin() * az.cos(),
                        r * pol.sin() * az.sin(),
                        r * pol.cos(),
                    );
                // Camera looking at the centre.
                let z = (centre - eye).normalize();
                let xa = Vector3::new(-az.sin(), az.cos(), 0.0);
                let xa = (xa - z * xa.dot(&z)).normalize();
                let y = z.cross(&xa);
                let rot =
                    nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[
                        xa, y, z,
                    ]));
                let cam = Isometry3::from_parts(
                    Translation3::from(eye.coords),
                    UnitQuaternion::from_rotation_matrix(&rot),
                );
                let (flange, cam_from_board) = match mount {
                    Mount::Flange => (cam * x.inverse(), cam.inverse() * target),
                    // Eye-to-hand: X = camera in base (fixed), target = board in flange.
                    Mount::Base => {
                        let board_in_base = x * cam.inverse() * target;
                        let tif = Isometry3::from_parts(
                            Translation3::new(10.0, -20.0, 30.0),
                            UnitQuaternion::from_scaled_axis(Vector3::new(0.1, 0.0, 0.2)),
                        );
                        (board_in_base * tif.inverse(), cam.inverse() * target)
                    }
                };
                let corners = board_points(&board)
                    .iter()
                    .map(|p| {
                        let uv = geom::project(
                            &k,
                            &(cam_from_board * nalgebra::Point3::from(*p)).coords,
                        )
                        .unwrap();
                        Some([
                            uv[0] + noise.sample(&mut rng),
                            uv[1] + noise.sample(&mut rng),
                        ])
                    })
                    .collect();
                views.push(View {
                    id: v,
                    flange,
                    corners,
                });
            }
            let data = CameraData {
                width: 640,
                height: 480,
                board,
                mount,
                views,
            };
            let res = calibrate(&data, None, &Options::default()).unwrap();
            let (dt, dr) = geom::pose_error(&res.ml.x, &x);
            eprintln!("{mount:?}: ML X error {dt:.4} mm {dr:.5} deg, rms {:.4} px, model {:?} {:?} K {:?}", res.ml.train_rms_px, res.distortion, res.model_scores, res.intrinsics_only);
            for e in &res.closed_form {
                let (dt, dr) = geom::pose_error(&e.x, &x);
                eprintln!(
                    "  {}: {dt:.4} mm {dr:.5} deg rms {:.4}",
                    e.method, e.train_rms_px
                );
            }
            let tsai = res
                .closed_form
                .iter()
                .find(|e| e.method == "tsai-lenz")
                .unwrap();
            let (tt, _) = geom::pose_error(&tsai.x, &x);
            assert!(dt < 0.5 && dr < 0.05, "{mount:?}: {dt} mm {dr} deg");
            assert!(dt < tt, "ML {dt} mm not better than Tsai–Lenz {tt} mm");
            assert!((res.ml.intrinsics.fx - 900.0).abs() < 2.0);
            assert!(res.closed_form.len() == 5);
            // Exact flange poses: every resample of the views writes the same estimator, the
            // estimator part is zero and there is no note about it.
            let p = res.uncertainty.x_parts.as_ref().expect("the CV ran");
            assert_eq!(p.estimator_shares.len(), 1, "{:?}", p.estimator_shares);
            assert_eq!(p.estimator_shares[0].0, res.ml.method);
            assert_eq!(p.estimator_mm, [0.0; 3]);
            assert!(calfile::estimator_note(&res).is_none());
            // Were the resamples split and the estimator part the largest, the note would say
            // which estimators, how often, and along which axis.
            let mut split = res.clone();
            let q = split.uncertainty.x_parts.as_mut().unwrap();
            q.estimator_shares = vec![("ml".into(), 0.52), ("park-martin".into(), 0.48)];
            q.estimator_mm = [0.1, 2.5, 0.2];
            q.fit_mm = [0.5, 0.5, 0.5];
            let note = calfile::estimator_note(&split).expect("a note");
            assert!(note.contains("ml 52 %, park-martin 48 %"), "{note}");
            assert!(note.contains("along the camera's y axis"), "{note}");
            assert!(note.contains("1σ 2.50 mm"), "{note}");
            // Below 1 mm (and no rotation part beyond 0.1°) it is not worth a note.
            split.uncertainty.x_parts.as_mut().unwrap().estimator_mm = [0.1, 0.9, 0.2];
            assert!(calfile::estimator_note(&split).is_none());
        }
    }
}
