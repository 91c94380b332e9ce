//! Residual diagnosis on camera datasets (`robocal diagnose` on a dataset whose header has a
//! `camera` block): after the maximum-likelihood camera + hand-eye fit
//! ([`crate::solve::camera`]), every candidate effect is freed in turn on top of the current
//! model and refitted on the raw corner reprojection errors:
//!
//! * `target_scale` — the printed board's scale ≠ the declared square size (the robot's
//!   translations fix the metric scale, so the scale is identifiable);
//! * `target_flatness` — a bent board: sag `c_x·((x−x₀)/R)² + c_y·((y−y₀)/R)²` (mm);
//! * `arm_kinematics` — the arm's own kinematic errors identified with the camera as the
//!   sensor (eye-in-hand): joint zeros, link lengths and twists of the MDH + Hayati model, every
//!   parameter the camera can separate from the hand-eye, the board pose and the intrinsics
//!   (a rank-revealing analysis of the reprojection Jacobian, [`crate::solve::identifiability`],
//!   fixes the rest: joint 1's parameters go into the board pose, the last joint's zero and
//!   offset into the hand-eye), so the hand-eye stops absorbing them;
//! * `distortion` — the full `k1, k2, p1, p2, k3` model when a simpler one was chosen;
//! * `flange_map` — eye-in-hand, the arm's reported flange positions off by a linear map over
//!   the workspace the views sample (`p → p + S·(p − c)`, `S` trace-free, eight parameters,
//!   [`crate::solve::camera::problem::FlangeMap`]): the arm's pose error to first order, for
//!   records without joint angles (and beside `arm_kinematics` when they have them).
//!
//! An effect is accepted when its nested-model F statistic is large (F > 25 on the training
//! corners) and, with a held-out set, the held-out reprojection error falls by ≥ 2 %; the best
//! one is added and the loop repeats. Output: one entry per effect with its parameters (units,
//! 1σ intervals), the evidence, the held-out RMS before / after and the hand-eye change — the
//! same shape as the kinematic diagnosis' `effects[]` so the two schemas unify.
use nalgebra::{DVector, Isometry3};

use crate::dataset::Dataset;
use crate::model::KinematicModel;
use crate::schema;
use crate::solve::camera::geom::{Intrinsics, N_INTR};
use crate::solve::camera::problem::{
    changed_model, map_flange, ArmModel, BoardModel, FlangeMap, Layout, Obs, Reproj,
    FLANGE_MAP_NAMES, FLANGE_MAP_PARAMS,
};
use crate::solve::camera::{
    self, bend_centre, motion_poses, CameraData, CameraError, DistModel, Estimate, Mount, Options,
};
use crate::solve::lm::{minimize, LmOptions, LmReport};

/// One accepted effect, before it is put in the file form ([`crate::schema::DiagnosedEffect`]).
#[derive(Debug, Clone)]
pub struct CameraEffect {
    pub kind: String,
    pub joint: Option<usize>,
    pub parameters: Vec<schema::EffectParameter>,
    pub evidence: schema::Evidence,
    pub summary: String,
    pub train_rms_before_px: f64,
    pub train_rms_after_px: f64,
    /// Held-out reprojection RMS before / after the effect (px; absent without held-out views).
    pub heldout_rms_before_px: Option<f64>,
    pub heldout_rms_after_px: Option<f64>,
    /// Change of the hand-eye when the effect was added (mm, deg).
    pub hand_eye_change_mm: f64,
    pub hand_eye_change_deg: f64,
}

/// A candidate that was tested and not accepted.
#[derive(Debug, Clone)]
pub struct Rejected {
    pub kind: String,
    pub f_stat: f64,
    pub heldout_rms_px: Option<f64>,
}

fn pose_of(x: &Isometry3<f64>) -> schema::PoseMmQuat {
    let t = x.translation.vector;
    let q = x.rotation;
    let q = if q.w < 0.0 {
        -q.into_inner()
    } else {
        q.into_inner()
    };
    schema::PoseMmQuat {
        xyz_mm: [t.x, t.y, t.z],
        quat: [q.w, q.i, q.j, q.k],
    }
}

/// What [`diagnose`] returns.
#[derive(Debug, Clone)]
pub struct CameraDiagnosis {
    /// The camera calibration the diagnosis starts from (`robocal calibrate camera`'s).
    pub calibration: camera::CameraResult,
    pub baseline: Estimate,
    pub effects: Vec<CameraEffect>,
    pub rejected: Vec<Rejected>,
    /// Every candidate scored per round (round 0 on top of the calibration), best first.
    pub rounds: Vec<Vec<schema::Evidence>>,
    /// The final estimate with every accepted effect.
    pub final_estimate: Option<Estimate>,
    /// 1σ of the final fit (the calibration's when no effect was added).
    pub uncertainty: camera::Uncertainty,
    pub scale: f64,
    pub bend_mm: [f64; 2],
    /// The arm's identified kinematics (`arm_kinematics`), when that effect was accepted.
    pub arm: Option<ArmFit>,
    /// The flange-position map (`flange_map`), when that effect was accepted.
    pub flange_map: Option<FlangeMapFit>,
    /// Training / held-out views scored.
    pub n_train: usize,
    pub n_heldout: usize,
    /// Candidates that could not be tested, and why.
    pub untestable: Vec<(String, String)>,
    /// The declared square size (mm).
    pub square_mm: f64,
}

/// Above this ratio of the final training RMS to the board-only RMS, the residual is the
/// robot's, not the camera model's (a real arm 1 mm off leaves 10–30× the board-only RMS; a
/// simulated cell whose flange poses are exact leaves ~1×).
pub const ROBOT_DOMINATES_RATIO: f64 = 5.0;

/// Above this ratio of the final training RMS to the board-only RMS (the robot's pose error is
/// then at least three quarters of the residual's variance), a diagnosis that accepted an
/// effect states X's 1σ as the larger of the model covariance and the view jackknife.
pub const JACKKNIFE_RATIO: f64 = 2.0;

impl CameraDiagnosis {
    /// Final training RMS over the board-only RMS (what the camera model alone leaves).
    pub fn residual_over_board_only(&self) -> f64 {
        self.last().train_rms_px / self.calibration.intrinsics_rms_px
    }

    /// Whether the robot poses dominate the residual ([`ROBOT_DOMINATES_RATIO`]).
    pub fn robot_dominates(&self) -> bool {
        self.residual_over_board_only() > ROBOT_DOMINATES_RATIO
    }

    /// What the residual says beyond the effects (written to `diagnosis.json`'s `warnings`
    /// and printed by `robocal diagnose`): [`robot_dominance_note`] and [`board_scale_note`].
    pub fn findings(&self) -> Vec<String> {
        let arm = if self.arm.is_some() {
            ArmState::Identified
        } else if let Some((_, why)) = self.untestable.iter().find(|(k, _)| k == "arm_kinematics") {
            ArmState::Untestable(why.clone())
        } else {
            ArmState::NotSignificant
        };
        let fitted = self
            .effects
            .iter()
            .any(|e| e.kind == "target_scale")
            .then_some(self.scale);
        robot_dominance_note(
            self.last().train_rms_px,
            self.calibration.intrinsics_rms_px,
            self.calibration.pose_noise,
            &arm,
        )
        .into_iter()
        .chain(board_scale_note(
            self.calibration.implied_scale,
            self.square_mm,
            fitted,
        ))
        .chain(
            self.flange_map
                .as_ref()
                .map(|m| m.note(&self.calibration.uncertainty.x_mm, &self.uncertainty.x_mm)),
        )
        .collect()
    }
}

/// The accepted flange-position map.
#[derive(Debug, Clone, PartialEq)]
pub struct FlangeMapFit {
    /// The point left in place (mm, base frame).
    pub centre: [f64; 3],
    /// `S` ([`crate::solve::camera::problem::flange_map_matrix`]), row-major, trace-free.
    pub matrix: [[f64; 3]; 3],
    /// Largest and RMS shift `|S·(p − c)|` over the training views' flange positions (mm).
    pub max_shift_mm: f64,
    pub rms_shift_mm: f64,
}

impl FlangeMapFit {
    fn new(centre: nalgebra::Vector3<f64>, sv: &[f64], flanges: &[Isometry3<f64>]) -> Self {
        let m = crate::solve::camera::problem::flange_map_matrix(sv);
        let shifts: Vec<f64> = flanges
            .iter()
            .map(|f| (m * (f.translation.vector - centre)).norm())
            .collect();
        let n = shifts.len().max(1) as f64;
        FlangeMapFit {
            centre: [centre.x, centre.y, centre.z],
            matrix: std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)])),
            max_shift_mm: shifts.iter().copied().fold(0.0, f64::max),
            rms_shift_mm: (shifts.iter().map(|v| v * v).sum::<f64>() / n).sqrt(),
        }
    }

    /// What the map says about the arm (a `diagnosis.json` warning and a console line), with
    /// X's translation 1σ before (the calibration's) and after (the diagnosis') in mm.
    pub fn note(&self, sigma_before: &[f64; 3], sigma_after: &[f64; 3]) -> String {
        let f = |v: &[f64; 3]| format!("[{:.2}, {:.2}, {:.2}]", v[0], v[1], v[2]);
        let max = |v: &[f64; 3]| v.iter().copied().fold(0.0, f64::max);
        let x = if max(sigma_after) > 1.5 * max(sigma_before) {
            format!(
                "the pair predicts the camera, but X alone is less determined (translation 1σ \
                 {} mm, {} mm before), because over views of one board a shift of X and the map \
                 trade",
                f(sigma_after),
                f(sigma_before)
            )
        } else {
            format!(
                "X's translation 1σ {} mm ({} mm before)",
                f(sigma_after),
                f(sigma_before)
            )
        };
        format!(
            "flange positions: the arm's reported positions are off by a linear map over the \
             workspace of the views, {:.2} mm RMS and up to {:.2} mm from their centre \
             ({:.0}, {:.0}, {:.0}) mm; the hand-eye is fitted with it and the calibration \
             carries it (camera.flange_map): {x}; it holds for this arm in this workspace only: \
             calibrate the arm (joint angles `q` in the records for arm_kinematics, or a \
             tracker) to remove it at its source",
            self.rms_shift_mm, self.max_shift_mm, self.centre[0], self.centre[1], self.centre[2],
        )
    }

    /// The calibration file's form.
    pub fn block(&self) -> crate::dataset::camera::FlangeMapBlock {
        crate::dataset::camera::FlangeMapBlock {
            centre_mm: self.centre,
            matrix: self.matrix,
        }
    }
}

/// What the diagnosis could say about the arm's kinematics.
#[derive(Debug, Clone, PartialEq)]
pub enum ArmState {
    /// `arm_kinematics` accepted.
    Identified,
    /// Tested, not significant.
    NotSignificant,
    /// Not testable, and why (no joint angles, eye-to-hand, ...).
    Untestable(String),
}

/// When the residual (`res_px`, final training RMS) is more than [`ROBOT_DOMINATES_RATIO`]×
/// the board-only RMS (`board_px`): say that the robot poses dominate it, with the pose noise
/// the data imply (`(deg, mm)`), and what would separate them.
pub fn robot_dominance_note(
    res_px: f64,
    board_px: f64,
    pose_noise: Option<(f64, f64)>,
    arm: &ArmState,
) -> Option<String> {
    if !res_px.is_finite() || !board_px.is_finite() || res_px <= ROBOT_DOMINATES_RATIO * board_px {
        return None;
    }
    let noise = pose_noise.map_or(String::new(), |(deg, mm)| {
        format!("; the data imply flange poses wrong by {mm:.2} mm and {deg:.3}° (1σ per axis)")
    });
    let tracker = "an external tracker on the flange would measure the pose error directly";
    let separate = match arm {
        ArmState::Identified => format!(
            "the arm's kinematic errors were identified (arm_kinematics); what remains is pose \
             error the joint angles do not explain (repeatability, image/pose timing, a camera \
             moving on its mount): {tracker}"
        ),
        ArmState::Untestable(why) => format!(
            "to separate the arm's kinematic errors from the hand-eye, record the joint angles \
             `q` with every image and the robot model in the header, so that arm_kinematics can \
             be identified with the camera as the sensor (untested here: {why}); {tracker}"
        ),
        ArmState::NotSignificant => format!(
            "arm_kinematics was tested and is not significant, so the pose error is not the \
             arm's geometry (repeatability, image/pose timing, a camera moving on its mount): \
             {tracker}"
        ),
    };
    Some(format!(
        "the robot poses dominate the residual: {res_px:.3} px is {:.0}x what the board alone \
         leaves ({board_px:.3} px), so the camera model is not what limits the hand-eye{noise}; \
         {separate}",
        res_px / board_px
    ))
}

/// The board-scale evidence: the square size the robot's motion implies (`implied`, printed /
/// declared, from [`camera::CameraResult::implied_scale`]) against the declared `square_mm`,
/// beside the diagnosis' fitted `target_scale` when it was accepted. Said when the implied
/// scale is more than 1 % off or a scale was fitted.
pub fn board_scale_note(implied: f64, square_mm: f64, fitted: Option<f64>) -> Option<String> {
    if !(implied.is_finite() && implied > 0.0 && ((implied - 1.0).abs() > 0.01 || fitted.is_some()))
    {
        return None;
    }
    let fit = fitted.map_or(String::new(), |f| {
        format!(
            "; the diagnosis fitted target_scale {f:.5} ({:.3} mm squares)",
            f * square_mm
        )
    });
    Some(format!(
        "board scale: the robot's motion implies {:.3} mm squares against the declared {:.3} mm \
         ({:+.1} %){fit}",
        implied * square_mm,
        square_mm,
        (implied - 1.0) * 100.0
    ))
}

impl CameraDiagnosis {
    /// The final estimate (the baseline when no effect was accepted).
    pub fn last(&self) -> &Estimate {
        self.final_estimate.as_ref().unwrap_or(&self.baseline)
    }

    /// The `diagnosis.json` form: the one shape of every sensor (`robocal-diagnosis/2`,
    /// [`schema::DiagnosisFile`]) with its RMS figures in `_px` fields.
    pub fn to_file(&self) -> schema::DiagnosisFile {
        let fin = schema::fin;
        let last = self.last();
        let effects = self
            .effects
            .iter()
            .map(|e| {
                let mut params = serde_json::Map::new();
                for p in &e.parameters {
                    params.insert(p.name.clone(), serde_json::json!(fin(p.value)));
                }
                schema::DiagnosedEffect {
                    kind: e.kind.clone(),
                    joint: e.joint,
                    label: e.kind.clone(),
                    parameters: e.parameters.clone(),
                    evidence: e.evidence.clone(),
                    train_rms_mm_before: None,
                    train_rms_mm_after: None,
                    heldout_rms_mm_before: None,
                    heldout_rms_mm_after: None,
                    train_rms_px_before: fin(e.train_rms_before_px),
                    train_rms_px_after: fin(e.train_rms_after_px),
                    heldout_rms_px_before: e.heldout_rms_before_px.and_then(fin),
                    heldout_rms_px_after: e.heldout_rms_after_px.and_then(fin),
                    hand_eye_change_mm: fin(e.hand_eye_change_mm),
                    hand_eye_change_deg: fin(e.hand_eye_change_deg),
                    calibration: crate::dataset::CalEffect {
                        kind: e.kind.clone(),
                        joint: e.joint,
                        params,
                        extra: Default::default(),
                    },
                }
            })
            .collect();
        let px = |base: Option<f64>, fin_: Option<f64>| schema::StageRms {
            base_model_px: base.and_then(fin),
            final_px: fin_.and_then(fin),
            ..Default::default()
        };
        schema::DiagnosisFile {
            format: schema::DIAGNOSIS_FORMAT.into(),
            sensor: schema::DiagnosisSensor::Camera,
            residual: "board corner reprojection error (px)".into(),
            n_train: self.n_train,
            n_heldout: self.n_heldout,
            n_heldout_excluded: 0,
            train_rms: px(Some(self.baseline.train_rms_px), Some(last.train_rms_px)),
            heldout_rms: px(self.baseline.heldout_rms_px, last.heldout_rms_px),
            train_rms_near_heldout: None,
            effects,
            nonparametric_used: false,
            rounds: self.rounds.clone(),
            not_identifiable: vec![],
            untestable: self
                .untestable
                .iter()
                .map(|(a, b)| schema::Untestable {
                    effect: a.clone(),
                    reason: b.clone(),
                })
                .collect(),
            ambiguous_heldout: vec![],
            warnings: self.findings(),
            hand_eye_before: Some(pose_of(&self.baseline.x)),
            hand_eye_after: Some(pose_of(&last.x)),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Cand {
    Scale,
    Bend,
    Arm,
    Distortion,
    Map,
}

impl Cand {
    fn kind(self) -> &'static str {
        match self {
            Cand::Scale => "target_scale",
            Cand::Bend => "target_flatness",
            Cand::Arm => "arm_kinematics",
            Cand::Distortion => "distortion",
            Cand::Map => "flange_map",
        }
    }
}

/// The current model.
#[derive(Debug, Clone)]
struct St {
    k: Intrinsics,
    mask: [bool; N_INTR],
    x: Isometry3<f64>,
    target: Isometry3<f64>,
    scale: f64,
    bend: [f64; 2],
    deltas: Vec<f64>,
    /// The flange map's parameters (empty when off).
    map: Vec<f64>,
    on: Vec<Cand>,
}

struct Ctx<'a> {
    obs: Vec<Obs>,
    g: Vec<Isometry3<f64>>,
    q: Vec<Vec<f64>>,
    model: Option<&'a KinematicModel>,
    /// Model parameters `arm_kinematics` frees (the identifiable ones).
    arm_params: Vec<usize>,
    centre: [f64; 3],
    /// The flange map's centre: the training flange positions' mean (mm).
    map_centre: nalgebra::Vector3<f64>,
    held: Option<(CameraData, Vec<Vec<f64>>)>,
}

/// The reprojection problem of state `s`, with the arm parameters `arm` free when given.
fn problem<'a>(c: &'a Ctx, s: &St, arm: Option<Vec<usize>>) -> Reproj<'a> {
    Reproj {
        obs: &c.obs,
        flange: &c.g,
        layout: Layout::HandEye,
        intr_free: s.mask,
        intr_fixed: s.k,
        board: BoardModel {
            scale: s.on.contains(&Cand::Scale),
            bend: s.on.contains(&Cand::Bend),
            centre: c.centre,
        },
        arm: c.model.zip(arm).map(|(model, params)| ArmModel {
            model,
            q: &c.q,
            params,
        }),
        flange_map: s.on.contains(&Cand::Map).then_some(FlangeMap {
            centre: c.map_centre,
        }),
    }
}

fn fit(c: &Ctx, s: &St) -> (St, LmReport) {
    let arm = s.on.contains(&Cand::Arm) && c.model.is_some();
    let p = problem(c, s, arm.then(|| c.arm_params.clone()));
    let mut x0 = p.pack(&s.k, &[s.x, s.target], s.scale, s.bend);
    if arm && s.deltas.len() == c.arm_params.len() {
        let o = p.arm_offset();
        for (k, v) in s.deltas.iter().enumerate() {
            x0[o + k] = *v;
        }
    }
    if p.flange_map.is_some() && s.map.len() == FLANGE_MAP_PARAMS {
        let o = p.map_offset();
        for (k, v) in s.map.iter().enumerate() {
            x0[o + k] = *v;
        }
    }
    let rep = minimize(
        &p,
        x0,
        &LmOptions {
            max_iter: 200,
            ..LmOptions::default()
        },
    );
    let (scale, bend) = p.board_params(&rep.x);
    let st = St {
        k: p.intrinsics(&rep.x),
        x: p.pose(&rep.x, 0),
        target: p.pose(&rep.x, 1),
        scale,
        bend,
        deltas: if arm { p.arm_deltas(&rep.x) } else { vec![] },
        map: p.map_params(&rep.x),
        ..s.clone()
    };
    (st, rep)
}

/// View jackknife 1σ of X (translation mm, rotation deg) and of the flange map's parameters
/// (empty without a map) of the fit of state `s`: one refit per training view left out, from `s`.
fn jackknife(c: &Ctx, s: &St) -> Option<([f64; 3], [f64; 3], Vec<f64>)> {
    use rayon::prelude::*;
    let mut views: Vec<usize> = c.obs.iter().map(|o| o.view).collect();
    views.sort_unstable();
    views.dedup();
    let fits: Vec<St> = views
        .par_iter()
        .filter_map(|&v| {
            let c2 = Ctx {
                obs: c.obs.iter().filter(|o| o.view != v).copied().collect(),
                g: c.g.clone(),
                q: c.q.clone(),
                model: c.model,
                arm_params: c.arm_params.clone(),
                centre: c.centre,
                map_centre: c.map_centre,
                held: None,
            };
            let (s1, r1) = fit(&c2, s);
            r1.cost.is_finite().then_some(s1)
        })
        .collect();
    if fits.len() + 1 < views.len() || fits.len() < 3 {
        return None;
    }
    let xs: Vec<Isometry3<f64>> = fits.iter().map(|f| f.x).collect();
    let mean = crate::solve::camera::geom::mean_pose(&xs);
    let (st, sr) = crate::solve::camera::select::spread(&xs, &mean);
    // (n−1)/n · Σ (θ_i − θ̄)² = (n−1) · the mean square deviation.
    let n = fits.len() as f64;
    let f = (n - 1.0).sqrt();
    let map_sd = (0..s.map.len())
        .map(|k| {
            let m = fits.iter().map(|t| t.map[k]).sum::<f64>() / n;
            let ms = fits.iter().map(|t| (t.map[k] - m).powi(2)).sum::<f64>() / n;
            ms.sqrt() * f
        })
        .collect();
    Some((st.map(|v| v * f), sr.map(|v| v * f), map_sd))
}

/// `name = value ± std unit, …` of an effect's parameters.
fn summary_of(params: &[schema::EffectParameter]) -> String {
    params
        .iter()
        .map(|p| {
            format!(
                "{} = {:.5} ± {:.5} {}",
                p.name,
                p.value,
                p.std.unwrap_or(f64::NAN),
                p.unit
            )
        })
        .collect::<Vec<_>>()
        .join(", ")
}

fn heldout(c: &Ctx, s: &St) -> Option<f64> {
    let (h, q) = c.held.as_ref()?;
    let mut h = h.clone();
    if s.on.contains(&Cand::Arm) && !s.deltas.is_empty() {
        let m = changed_model(c.model?, &c.arm_params, &s.deltas);
        for (v, qv) in h.views.iter_mut().zip(q) {
            v.flange = m.flange_pose(qv);
        }
    }
    if s.on.contains(&Cand::Map) && s.map.len() == FLANGE_MAP_PARAMS {
        for v in &mut h.views {
            v.flange = map_flange(&v.flange, &s.map, &c.map_centre);
        }
    }
    Some(camera::heldout_rms(
        &h, &s.k, &s.x, &s.target, s.scale, s.bend,
    ))
}

fn rms(r: &DVector<f64>) -> f64 {
    (r.norm_squared() / (r.len() / 2).max(1) as f64).sqrt()
}

/// Joint angles (rad) of the views, matched by record id.
fn joints_of(data: &CameraData, ds: &Dataset) -> Option<Vec<Vec<f64>>> {
    data.views
        .iter()
        .map(|v| {
            ds.poses()
                .find(|r| r.id == v.id)
                .and_then(|r| r.q.as_ref())
                .map(|q| q.iter().map(|d| d.to_radians()).collect())
        })
        .collect()
}

/// Diagnose a camera calibration (see the module docs). `train_ds` / `held_ds` give the joint
/// angles (`q`) for `arm_kinematics`; without them (or eye-to-hand) that candidate is skipped.
pub fn diagnose(
    train: &CameraData,
    held: Option<&CameraData>,
    train_ds: &Dataset,
    held_ds: Option<&Dataset>,
) -> Result<CameraDiagnosis, CameraError> {
    diagnose_from(None, train, held, train_ds, held_ds)
}

/// As [`diagnose`], starting from `base`, the calibration of the same views already made (a
/// session hands over its calibrate stage's result instead of calibrating again); `None`:
/// calibrate here.
pub fn diagnose_from(
    base: Option<camera::CameraResult>,
    train: &CameraData,
    held: Option<&CameraData>,
    train_ds: &Dataset,
    held_ds: Option<&Dataset>,
) -> Result<CameraDiagnosis, CameraError> {
    let base = match base {
        Some(b) => b,
        None => camera::calibrate(train, held, &Options::default())?,
    };
    // The views the calibration kept, with its corner rejection.
    let kept: Vec<camera::View> = train
        .views
        .iter()
        .filter(|v| base.used_views.contains(&v.id))
        .cloned()
        .collect();
    let data = CameraData {
        views: kept,
        ..train.clone()
    };
    let model = KinematicModel::from_robot_block(&train_ds.header.robot).ok();
    let q = joints_of(&data, train_ds);
    let held_q = match (held, held_ds) {
        (Some(h), Some(d)) => joints_of(h, d),
        _ => None,
    };
    let arm_ok = train.mount == Mount::Flange
        && model.is_some()
        && q.is_some()
        && (held.is_none() || held_q.is_some());
    // The arm model the camera sees: base and tool at identity (the board pose and the
    // hand-eye take their place).
    let model = model.map(|m| changed_model(&m, &[], &[]));
    let flanges = motion_poses(&data.views, data.mount);
    let mut ctx = Ctx {
        obs: {
            // Same corners as the final fit (its rejected ones stay out).
            let used: std::collections::HashSet<(u64, usize)> =
                base.residuals.iter().map(|(v, c, _, _)| (*v, *c)).collect();
            let views: Vec<camera::View> = data
                .views
                .iter()
                .map(|v| camera::View {
                    corners: v
                        .corners
                        .iter()
                        .enumerate()
                        .map(|(k, c)| c.filter(|_| used.contains(&(v.id, k))))
                        .collect(),
                    ..v.clone()
                })
                .collect();
            camera_obs(&views, &data)
        },
        map_centre: flanges
            .iter()
            .map(|f| f.translation.vector)
            .sum::<nalgebra::Vector3<f64>>()
            / flanges.len().max(1) as f64,
        g: flanges,
        q: q.clone().unwrap_or_default(),
        model: model.as_ref().filter(|_| arm_ok),
        arm_params: vec![],
        centre: bend_centre(&data.board),
        held: held.map(|h| (h.clone(), held_q.clone().unwrap_or_default())),
    };
    let mut st = St {
        k: base.ml.intrinsics,
        mask: base.distortion.mask(),
        x: base.ml.x,
        target: base.ml.target,
        scale: 1.0,
        bend: [0.0; 2],
        deltas: vec![],
        map: vec![],
        on: vec![],
    };
    let (s0, mut rep) = fit(&ctx, &st);
    let mut arm_fixed = vec![];
    if ctx.model.is_some() {
        let (kept, fixed) = select_arm_params(&ctx, &s0);
        ctx.arm_params = kept;
        arm_fixed = fixed;
    }
    st = s0;
    let mut cur_held = heldout(&ctx, &st);
    let mut effects = vec![];
    let mut rejected = vec![];
    let mut rounds: Vec<Vec<schema::Evidence>> = vec![];
    let mut untestable = vec![];
    let mut cands = vec![Cand::Scale, Cand::Bend];
    if ctx.model.is_some() && !ctx.arm_params.is_empty() {
        cands.push(Cand::Arm);
    } else {
        untestable.push((
            Cand::Arm.kind().to_string(),
            if train.mount != Mount::Flange {
                "eye-to-hand: the arm's joint offsets are not separable from the board on the flange".to_string()
            } else if ctx.model.is_some() {
                "no kinematic parameter of the arm is separable from the hand-eye and the board \
                 pose with these views"
                    .to_string()
            } else {
                "the records carry no joint angles `q` (or the robot model is unknown)".to_string()
            },
        ));
    }
    if base.distortion != DistModel::K1K2P1P2K3 {
        cands.push(Cand::Distortion);
    }
    if train.mount == Mount::Flange {
        cands.push(Cand::Map);
    } else {
        untestable.push((
            Cand::Map.kind().to_string(),
            "eye-to-hand: the camera sees the board on the flange, whose position error the \
             board pose absorbs"
                .to_string(),
        ));
    }
    loop {
        // The candidates rejected on top of the final model are the ones reported.
        rejected.clear();
        let mut round = vec![];
        let mut best: Option<(Cand, St, LmReport, f64, Option<f64>)> = None;
        for &c in cands.iter().filter(|c| !st.on.contains(c)) {
            let mut s = st.clone();
            s.on.push(c);
            if c == Cand::Distortion {
                s.mask = DistModel::K1K2P1P2K3.mask();
            }
            let (s1, r1) = fit(&ctx, &s);
            let (m, n0, n1) = (
                r1.residuals.len(),
                rep.jacobian.ncols(),
                r1.jacobian.ncols(),
            );
            let p = n1.saturating_sub(n0).max(1);
            let f = ((rep.cost - r1.cost) / p as f64) / (r1.cost / (m - n1).max(1) as f64);
            let h = heldout(&ctx, &s1);
            let held_ok = match (cur_held, h) {
                (Some(a), Some(b)) => b < 0.98 * a,
                _ => true,
            };
            round.push(schema::Evidence {
                candidate: c.kind().into(),
                kind: c.kind().into(),
                joint: None,
                df: Some(p),
                f: schema::fin(f),
                cv_gain: match (cur_held, h) {
                    (Some(a), Some(b)) if a > 0.0 => schema::fin((a - b) / a),
                    _ => None,
                },
                ..Default::default()
            });
            if f > 25.0 && held_ok {
                if best.as_ref().is_none_or(|b| f > b.3) {
                    best = Some((c, s1, r1, f, h));
                }
            } else {
                rejected.push(Rejected {
                    kind: c.kind().into(),
                    f_stat: f,
                    heldout_rms_px: h,
                });
            }
        }
        round.sort_by(|a, b| b.f.unwrap_or(f64::MIN).total_cmp(&a.f.unwrap_or(f64::MIN)));
        if !round.is_empty() {
            rounds.push(round);
        }
        let Some((c, s1, r1, f, h)) = best else {
            break;
        };
        rejected.retain(|r| r.kind != c.kind());
        let (dmm, ddeg) = crate::solve::camera::geom::pose_error(&st.x, &s1.x);
        let std = stds(&r1, &s1.mask);
        let params = effect_params(c, &s1, &std, &ctx, r1.jacobian.ncols());
        let summary = summary_of(&params);
        let df = r1.jacobian.ncols() - rep.jacobian.ncols();
        effects.push(CameraEffect {
            kind: c.kind().into(),
            joint: None,
            parameters: params,
            evidence: schema::Evidence {
                candidate: c.kind().into(),
                kind: c.kind().into(),
                joint: None,
                df: Some(df),
                f: schema::fin(f),
                cv_gain: match (cur_held, h) {
                    (Some(a), Some(b)) if a > 0.0 => schema::fin((a - b) / a),
                    _ => None,
                },
                ..Default::default()
            },
            summary,
            train_rms_before_px: rms(&rep.residuals),
            train_rms_after_px: rms(&r1.residuals),
            heldout_rms_before_px: cur_held,
            heldout_rms_after_px: h,
            hand_eye_change_mm: dmm,
            hand_eye_change_deg: ddeg,
        });
        st = s1;
        rep = r1;
        cur_held = h;
    }
    let final_estimate = (!effects.is_empty()).then(|| Estimate {
        method: "ml+diagnosis".into(),
        x: st.x,
        target: st.target,
        intrinsics: st.k,
        train_rms_px: rms(&rep.residuals),
        heldout_rms_px: cur_held,
    });
    let n_heldout = held.map_or(0, |h| h.views.len());
    let mut uncertainty = if effects.is_empty() {
        base.uncertainty.clone()
    } else {
        uncertainty_of(&stds(&rep, &st.mask), &st.mask, base.uncertainty.bootstrap)
    };
    // Where the robot's pose error dominates the residual, the corners of one view share it and
    // the model covariance (every corner independent) is too small: X's 1σ is then the larger
    // of it and the view jackknife of the final fit, per coordinate (as the calibration's).
    let dominated = rms(&rep.residuals) > JACKKNIFE_RATIO * base.intrinsics_rms_px;
    if !effects.is_empty() && dominated {
        if let Some((jt, jr, map_sd)) = jackknife(&ctx, &st) {
            for a in 0..3 {
                uncertainty.x_mm[a] = uncertainty.x_mm[a].max(jt[a]);
                uncertainty.x_deg[a] = uncertainty.x_deg[a].max(jr[a]);
            }
            // The map's parameters: the larger of their model 1σ and the jackknife's too.
            if let Some(e) = effects.iter_mut().find(|e| e.kind == Cand::Map.kind()) {
                for (p, sd) in e.parameters.iter_mut().zip(&map_sd) {
                    let sd = p.std.unwrap_or(0.0).max(1e3 * sd);
                    *p = schema::EffectParameter::new(&p.name, &p.unit, p.value, sd);
                }
                e.summary = summary_of(&e.parameters);
            }
        }
    }
    Ok(CameraDiagnosis {
        uncertainty,
        baseline: base.ml.clone(),
        n_train: base.used_views.len(),
        n_heldout,
        calibration: base,
        effects,
        rejected,
        rounds,
        final_estimate,
        scale: st.scale,
        bend_mm: st.bend,
        arm: match (st.on.contains(&Cand::Arm), ctx.model) {
            (true, Some(m)) => {
                let std = stds(&rep, &st.mask);
                let i_arm = arm_index(&st);
                Some(ArmFit {
                    model: changed_model(m, &ctx.arm_params, &st.deltas),
                    changes: arm_changes(m, &ctx.arm_params, &st.deltas, |k| {
                        std.get(i_arm + k).copied().unwrap_or(f64::NAN)
                    }),
                    fixed: arm_fixed,
                })
            }
            _ => None,
        },
        flange_map: (st.on.contains(&Cand::Map) && st.map.len() == FLANGE_MAP_PARAMS)
            .then(|| FlangeMapFit::new(ctx.map_centre, &st.map, &ctx.g)),
        untestable,
        square_mm: train.board.square_mm,
    })
}

/// The arm's kinematics identified through the camera.
#[derive(Debug, Clone)]
pub struct ArmFit {
    /// The robot model with the identified changes (base and tool groups at identity).
    pub model: KinematicModel,
    /// The changed parameters, in file units.
    pub changes: Vec<ArmChange>,
    /// Parameters kept at nominal because the camera cannot separate them, and why.
    pub fixed: Vec<(String, String)>,
}

impl ArmFit {
    /// Put the identified arm into a camera calibration file: every joint parameter of the
    /// changed model in `params` (file units; the changed ones `free` with their 1σ), read back
    /// by [`crate::solve::camera::calfile::arm_model`]; the changes and the parameters kept at
    /// nominal in `metrics.arm_kinematics`.
    pub fn write_into(&self, cal: &mut crate::dataset::CalibrationFile) {
        let changed: std::collections::HashMap<&str, &ArmChange> =
            self.changes.iter().map(|c| (c.name.as_str(), c)).collect();
        cal.params = self
            .model
            .to_cal_params()
            .into_iter()
            .zip(self.model.params())
            .filter(|(_, p)| matches!(p.group, crate::model::ParamGroup::Joint(_)))
            .map(|(mut c, _)| {
                let ch = changed.get(c.name.as_str());
                c.free = ch.is_some();
                c.std = ch.and_then(|ch| schema::fin(ch.std));
                c
            })
            .collect();
        cal.metrics.insert(
            "arm_kinematics".into(),
            serde_json::json!({
                "changed": self.changes.iter().map(|c| serde_json::json!({
                    "param": c.name, "change": schema::fin(c.change), "std": schema::fin(c.std), "unit": c.unit,
                })).collect::<Vec<_>>(),
                "kept_at_nominal": self.fixed.iter().map(|(n, why)| serde_json::json!({"param": n, "why": why})).collect::<Vec<_>>(),
            }),
        );
    }
}

/// One identified change of a model parameter.
#[derive(Debug, Clone, PartialEq)]
pub struct ArmChange {
    /// Model parameter name (`phi3`, `a2`, `d4`, `alpha5`, `beta3`, …).
    pub name: String,
    /// Change from the nominal model (mm or deg).
    pub change: f64,
    /// Its 1σ (mm or deg).
    pub std: f64,
    pub unit: &'static str,
}

fn arm_changes(
    m: &KinematicModel,
    params: &[usize],
    deltas: &[f64],
    std: impl Fn(usize) -> f64,
) -> Vec<ArmChange> {
    params
        .iter()
        .zip(deltas)
        .enumerate()
        .map(|(k, (&i, &d))| {
            let p = &m.params()[i];
            let (f, unit) = match p.unit {
                crate::model::Unit::Mm => (1.0, "mm"),
                crate::model::Unit::Rad => (1f64.to_degrees(), "deg"),
            };
            ArmChange {
                name: p.name.clone(),
                change: d * f,
                std: std(k) * f,
                unit,
            }
        })
        .collect()
}

/// Index of the first arm parameter in a fit of state `s`: free intrinsics, 12 pose
/// parameters, then scale and bend when on.
fn arm_index(s: &St) -> usize {
    s.mask.iter().filter(|f| **f).count()
        + 12
        + s.on.contains(&Cand::Scale) as usize
        + 2 * s.on.contains(&Cand::Bend) as usize
}

/// The arm parameters the camera can separate, by a rank-revealing analysis of the
/// reprojection Jacobian at `s` (intrinsics, hand-eye, board pose and board parameters first,
/// then the joints from the flange down), and the ones fixed with the reason.
fn select_arm_params(c: &Ctx, s: &St) -> (Vec<usize>, Vec<(String, String)>) {
    let Some(m) = c.model else {
        return (vec![], vec![]);
    };
    let cand: Vec<usize> = m
        .params()
        .iter()
        .enumerate()
        .filter(|(_, p)| p.free && matches!(p.group, crate::model::ParamGroup::Joint(_)))
        .map(|(i, _)| i)
        .collect();
    let p = problem(c, s, Some(cand.clone()));
    let x0 = p.pack(&s.k, &[s.x, s.target], s.scale, s.bend);
    let (_, j) = crate::solve::lm::LsqProblem::residuals_jacobian(&p, &x0);
    let ao = p.arm_offset();
    let names: Vec<String> = (0..j.ncols())
        .map(|i| {
            if i >= ao {
                m.params()[cand[i - ao]].name.clone()
            } else if i >= p.pose_offset(1) {
                "board pose".to_string()
            } else if i >= p.pose_offset(0) {
                "hand-eye".to_string()
            } else {
                "intrinsics".to_string()
            }
        })
        .collect();
    let mut priority: Vec<usize> = (0..ao).collect();
    priority.extend(
        crate::solve::identifiability::priority_order(m, &cand, cand.len())
            .into_iter()
            .map(|k| ao + k),
    );
    // The kinematic identification's threshold. On the seed 004 shell the exact redundancies
    // (joint 1 into the board pose, the last joint's zero and offset into the hand-eye) sit at
    // sines of 1e-15; the weakest separable parameters (a2, a3, φ3, β3) at 5e-3 – 9e-3, and
    // freeing them brings the held-out pixels to the detection noise.
    let an = crate::solve::identifiability::analyse(
        &j,
        &names,
        &priority,
        crate::solve::identifiability::DEFAULT_TOL,
    );
    let mut kept: Vec<usize> = an
        .kept
        .iter()
        .filter(|(i, _)| *i >= ao)
        .map(|(i, _)| cand[i - ao])
        .collect();
    kept.sort_unstable();
    let fixed = an
        .dropped
        .iter()
        .filter(|d| d.index >= ao)
        .map(|d| {
            let mut partners: Vec<&str> = vec![];
            for (n, _) in &d.partners {
                if !partners.contains(&n.as_str()) {
                    partners.push(n);
                }
            }
            (
                names[d.index].clone(),
                format!(
                    "not separable through the camera (sine {:.1e} to the span of {}): kept at nominal",
                    d.sine,
                    if partners.is_empty() {
                        "the other parameters".to_string()
                    } else {
                        partners.join(", ")
                    }
                ),
            )
        })
        .collect();
    (kept, fixed)
}

fn camera_obs(views: &[camera::View], data: &CameraData) -> Vec<Obs> {
    let pts = camera::board_points(&data.board);
    let mut out = vec![];
    for (v, view) in views.iter().enumerate() {
        for (k, c) in view.corners.iter().enumerate() {
            if let Some(uv) = c {
                out.push(Obs {
                    view: v,
                    pt: pts[k],
                    uv: *uv,
                });
            }
        }
    }
    out
}

/// The camera parameters' 1σ from the final fit's standard deviations (same layout as the
/// calibration: free intrinsics, X rotation + translation, target rotation + translation).
fn uncertainty_of(
    std: &[f64],
    mask: &[bool; N_INTR],
    bootstrap: Option<(usize, [f64; 3], [f64; 3])>,
) -> camera::Uncertainty {
    camera::Uncertainty::from_std(|i| std.get(i).copied().unwrap_or(f64::NAN), mask, bootstrap)
}

/// Standard deviations of the fit's parameters (`mask`: the free intrinsics, which come first;
/// then X and the target, whose rotations are stated about their own axes,
/// [`crate::solve::camera::geom::cov_rotations_local`]).
fn stds(r: &LmReport, mask: &[bool; N_INTR]) -> Vec<f64> {
    let (m, n) = (r.jacobian.nrows(), r.jacobian.ncols());
    let s2 = 2.0 * r.cost / (m.saturating_sub(n)).max(1) as f64;
    let jtj = r.jacobian.transpose() * &r.jacobian;
    match jtj.try_inverse() {
        Some(inv) => crate::solve::camera::std_local(&(inv * s2), &r.x, mask),
        None => vec![f64::NAN; n],
    }
}

fn effect_params(
    c: Cand,
    s: &St,
    std: &[f64],
    ctx: &Ctx,
    n: usize,
) -> Vec<schema::EffectParameter> {
    let p = |name: String, value: f64, sd: f64, unit: &str| {
        schema::EffectParameter::new(&name, unit, value, sd)
    };
    // Index of the extras: intrinsics, 12 pose params, then scale, bend (2), offsets.
    let ni = s.mask.iter().filter(|f| **f).count();
    let mut o = ni + 12;
    let has = |k: Cand| s.on.contains(&k);
    let i_scale = has(Cand::Scale).then(|| {
        o += 1;
        o - 1
    });
    let i_bend = has(Cand::Bend).then(|| {
        o += 2;
        o - 2
    });
    let sd = |i: Option<usize>, k: usize| {
        i.map_or(f64::NAN, |i| std.get(i + k).copied().unwrap_or(f64::NAN))
    };
    let _ = n;
    match c {
        Cand::Scale => vec![p("scale".into(), s.scale, sd(i_scale, 0), "1")],
        Cand::Bend => vec![
            p("sag_x_mm".into(), s.bend[0], sd(i_bend, 0), "mm"),
            p("sag_y_mm".into(), s.bend[1], sd(i_bend, 1), "mm"),
        ],
        Cand::Arm => match ctx.model {
            Some(m) => arm_changes(m, &ctx.arm_params, &s.deltas, |k| sd(Some(arm_index(s)), k))
                .into_iter()
                .map(|c| p(format!("delta_{}", c.name), c.change, c.std, c.unit))
                .collect(),
            None => vec![],
        },
        Cand::Distortion => ["k1", "k2", "p1", "p2", "k3"]
            .iter()
            .enumerate()
            .map(|(k, nm)| p((*nm).into(), s.k.dist[k], f64::NAN, "1"))
            .collect(),
        // In mm per m of distance from the centre (the matrix entries × 1000).
        Cand::Map => {
            let i0 = arm_index(s) + if has(Cand::Arm) { s.deltas.len() } else { 0 };
            FLANGE_MAP_NAMES
                .iter()
                .enumerate()
                .map(|(k, nm)| {
                    let v = s.map.get(k).copied().unwrap_or(f64::NAN);
                    p((*nm).into(), 1e3 * v, 1e3 * sd(Some(i0), k), "mm/m")
                })
                .collect()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Eye-in-hand views of a board from a shell of viewpoints (`n` views, `phase` shifts the
    /// azimuths), corners with 0.05 px noise; the flange poses as reported by an arm whose
    /// positions are off by the trace-free map `s` about `c` (the true flange is the reported
    /// one read through the map).
    fn mapped_views(
        n: usize,
        phase: f64,
        s: &[f64],
        c: nalgebra::Vector3<f64>,
        seed: u64,
    ) -> CameraData {
        use nalgebra::{Translation3, UnitQuaternion, Vector3};
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let k = Intrinsics {
            fx: 900.0,
            fy: 900.0,
            cx: 320.0,
            cy: 240.0,
            dist: [-0.05, 0.0, 0.0, 0.0, 0.0],
        };
        let board = crate::solve::camera::detect::BoardSpec {
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
        let inv = (nalgebra::Matrix3::identity()
            + crate::solve::camera::problem::flange_map_matrix(s))
        .try_inverse()
        .unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let noise = Normal::new(0.0, 0.05).unwrap();
        let views =
            (0..n)
                .map(|v| {
                    let az = phase + v as f64 * 0.9;
                    let pol = 0.15 + 0.3 * ((v % 3) as f64) / 2.0;
                    let r = 450.0 + 50.0 * (v % 5) as f64;
                    let eye = centre
                        + Vector3::new(
                            r * pol.sin() * az.cos(),
                            r * pol.sin() * az.sin(),
                            r * pol.cos(),
                        );
                    let z = (centre - eye).normalize();
                    let xa = Vector3::new(-az.sin(), az.cos(), 0.0);
                    let xa = (xa - z * xa.dot(&z)).normalize();
                    let rot = nalgebra::Rotation3::from_matrix_unchecked(
                        nalgebra::Matrix3::from_columns(&[xa, z.cross(&xa), z]),
                    );
                    let cam = Isometry3::from_parts(
                        Translation3::from(eye.coords),
                        UnitQuaternion::from_rotation_matrix(&rot),
                    );
                    let truth = cam * x.inverse();
                    let mut reported = truth;
                    reported.translation.vector = c + inv * (truth.translation.vector - c);
                    let corners = crate::solve::camera::board_points(&board)
                        .iter()
                        .map(|p| {
                            let uv = crate::solve::camera::geom::project(
                                &k,
                                &(cam.inverse() * target * nalgebra::Point3::from(*p)).coords,
                            )
                            .unwrap();
                            Some([
                                uv[0] + noise.sample(&mut rng),
                                uv[1] + noise.sample(&mut rng),
                            ])
                        })
                        .collect();
                    camera::View {
                        id: seed * 1000 + v as u64,
                        flange: reported,
                        corners,
                    }
                })
                .collect();
        CameraData {
            width: 640,
            height: 480,
            board,
            mount: Mount::Flange,
            views,
        }
    }

    fn no_robot() -> Dataset {
        Dataset {
            header: crate::dataset::Header {
                format: crate::dataset::DATASET_FORMAT.into(),
                created: None,
                robot: crate::dataset::RobotBlock {
                    model: crate::dataset::NO_ROBOT_MODEL.into(),
                    serial: None,
                    chain: None,
                    flange: None,
                    extra: Default::default(),
                },
                tool: None,
                tracker: None,
                range_sensor: None,
                plan: None,
                notes: None,
                extra: Default::default(),
            },
            records: vec![],
        }
    }

    /// An arm whose reported positions are off by a linear map (up to ~2.5 mm over the shell,
    /// no joint angles recorded): the diagnosis names `flange_map`, recovers the map, predicts
    /// the held-out views to the detection noise, and the calibration block reads the flanges
    /// through the same map. Exact flange poses: no map.
    #[test]
    fn a_linear_error_of_the_flange_positions_is_named_and_recovered() {
        let s = [0.002, -0.003, 0.004, 0.001, -0.001, 0.0025, -0.002, 0.0015];
        let c = nalgebra::Vector3::new(-450.0, -130.0, 420.0);
        let train = mapped_views(24, 0.0, &s, c, 1);
        let held = mapped_views(10, 0.45, &s, c, 2);
        let d = diagnose(&train, Some(&held), &no_robot(), Some(&no_robot())).unwrap();
        let kinds: Vec<&str> = d.effects.iter().map(|e| e.kind.as_str()).collect();
        assert!(kinds.contains(&"flange_map"), "{kinds:?}");
        let (before, after) = (
            d.baseline.heldout_rms_px.unwrap(),
            d.last().heldout_rms_px.unwrap(),
        );
        eprintln!("held-out {before:.4} -> {after:.4} px; effects {kinds:?}");
        assert!(before > 0.5 && after < 0.1, "{before} -> {after}");
        let m = d.flange_map.as_ref().unwrap();
        // The map is fitted about the training flanges' mean, not `c`: the difference is a
        // constant shift the board pose takes; `S` itself is the same.
        let truth = crate::solve::camera::problem::flange_map_matrix(&s);
        for r in 0..3 {
            for k in 0..3 {
                assert!(
                    (m.matrix[r][k] - truth[(r, k)]).abs() < 3e-4,
                    "S[{r}][{k}] {} vs {}",
                    m.matrix[r][k],
                    truth[(r, k)]
                );
            }
        }
        assert!(m.max_shift_mm > 1.0, "{m:?}");
        assert!(d.findings().iter().any(|f| f.contains("flange positions")));
        // The file block reads a flange exactly as the fit did.
        let f = train.views[3].flange;
        let sv: Vec<f64> = [
            (0, 0),
            (0, 1),
            (0, 2),
            (1, 0),
            (1, 1),
            (1, 2),
            (2, 0),
            (2, 1),
        ]
        .iter()
        .map(|&(r, k)| m.matrix[r][k])
        .collect();
        let a = crate::solve::camera::calfile::read_through_map(&m.block(), &f);
        let b = map_flange(&f, &sv, &nalgebra::Vector3::from(m.centre));
        assert!((a.translation.vector - b.translation.vector).norm() < 1e-9);
        // Exact flange poses: the map is not accepted.
        let zero = [0.0; FLANGE_MAP_PARAMS];
        let d0 = diagnose(
            &mapped_views(24, 0.0, &zero, c, 1),
            Some(&mapped_views(10, 0.45, &zero, c, 2)),
            &no_robot(),
            Some(&no_robot()),
        )
        .unwrap();
        assert!(
            d0.flange_map.is_none(),
            "{:?}",
            d0.effects.iter().map(|e| &e.kind).collect::<Vec<_>>()
        );
    }

    #[test]
    fn robot_dominance_is_said_only_far_above_the_board_only_rms() {
        // Simulated cell, exact flange poses: 1.1x the board-only RMS: nothing to say.
        assert!(robot_dominance_note(0.15, 0.14, None, &ArmState::NotSignificant).is_none());
        // Real KUKA: 3.0 px against 0.11 px from the board alone, no joint angles recorded.
        let n = robot_dominance_note(
            3.0,
            0.11,
            Some((0.05, 1.2)),
            &ArmState::Untestable("the records carry no joint angles `q`".into()),
        )
        .unwrap();
        assert!(
            n.contains("robot poses dominate") && n.contains("27x"),
            "{n}"
        );
        assert!(
            n.contains("1.20 mm") && n.contains("joint angles `q`"),
            "{n}"
        );
        assert!(n.contains("arm_kinematics") && n.contains("tracker"), "{n}");
        // A NaN residual says nothing (never a false claim).
        assert!(robot_dominance_note(f64::NAN, 0.1, None, &ArmState::Identified).is_none());
    }

    #[test]
    fn board_scale_evidence_names_the_implied_square() {
        // 14.07 mm implied on a declared 15 mm board (the real KUKA set): -6.2 %.
        let n = board_scale_note(14.07 / 15.0, 15.0, None).unwrap();
        assert!(
            n.contains("14.070 mm") && n.contains("15.000 mm") && n.contains("-6.2 %"),
            "{n}"
        );
        let n = board_scale_note(1.004, 30.0, Some(1.0041)).unwrap();
        assert!(
            n.contains("30.120 mm") && n.contains("target_scale 1.00410"),
            "{n}"
        );
        // Within 1 % and nothing fitted: no note.
        assert!(board_scale_note(1.005, 30.0, None).is_none());
        assert!(board_scale_note(f64::NAN, 30.0, Some(1.0)).is_none());
    }
}
