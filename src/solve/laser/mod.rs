//! Hand-eye calibration of a laser range sensor on the flange from planes (seed 000), and
//! its validation.
//!
//! The beam is a variable-length probe: a spot measured at flange pose `(R_b, t_b)` with range
//! `d` is `x_b = R_b (r + d v) + t_b` (seed 000 eq. 19), where `r` (mm) is a point of the beam
//! in the flange frame and `v` the unit beam direction. Four estimators are implemented and
//! compared side by side ([`compare`]):
//!
//! 1. [`Method::SinglePlane`]: the seed's closed form (§1.3) on one plane, generalised to any
//!    number of translation groups: translation-only moves give `n_bᵀ(Δt + Δd R₀ v) = 0`
//!    (eq. 13 in the base frame), linear in `(n_b, n_b vᵀ)`; rotation+translation moves then
//!    give `r` and the plane offset linearly (eq. 15).
//! 2. [`Method::Selected`]: the seed's data selection (§1.4, §2.2): per plane, repeatedly drop
//!    the point farthest from the PCA plane of the measured points and keep the iteration whose
//!    parameters give the smallest 5-direction spread on the validation targets.
//! 3. [`Method::OrthogonalPlanes`]: the seed's Levenberg–Marquardt on three planes (eq. 16–18):
//!    start from the mean of the single-plane results; objective = closed-form consistency
//!    (eq. 13 residual of every translation pair) + weighted coplanarity, `|v| = 1`, `v_z > 0`.
//! 4. [`Method::Direct`]: joint maximum-likelihood fit over `r`, `v` and every plane
//!    `(n_i, c_i)` minimising the point-to-plane distance of all raw data (optional Huber loss).
//!
//! Units: mm and radians inside; the calibration file stores `r` in mm and `v` as a unit vector.

pub mod arm_refine;
pub mod effects;
pub mod fit;
pub mod predict;
pub mod stage;
pub mod validate;

use crate::dataset::{CalParam, CalibrationFile, Dataset, PoseRecord};
use crate::model::KinematicModel;
use nalgebra::{Isometry3, Point3, Unit, Vector3};
use std::collections::BTreeMap;

pub use fit::{
    closed_form_single_plane, fit_direct, fit_orthogonal_planes, select_data, DirectOptions,
    SelectionTrace,
};
pub use validate::{
    compare, compare_split, face_angles, five_direction_spread, fre_tre, plane_stats, ply, table,
    Comparison, MethodRow,
};

/// The unknowns of the laser hand-eye problem.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Beam {
    /// A point of the beam in the flange frame (mm).
    pub r: Vector3<f64>,
    /// Unit beam direction in the flange frame.
    pub v: Unit<Vector3<f64>>,
}

impl Beam {
    /// The laser spot in the robot base frame for flange pose `flange` and range `d` (mm).
    pub fn spot(&self, flange: &Isometry3<f64>, d: f64) -> Point3<f64> {
        flange * Point3::from(self.r + self.v.into_inner() * d)
    }
}

/// A plane `n·x + c = 0` in the robot base frame (`n` unit).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// Unit normal.
    pub n: Unit<Vector3<f64>>,
    /// Offset (mm).
    pub c: f64,
}

impl Plane {
    /// Signed distance of `p` (mm).
    pub fn distance(&self, p: &Point3<f64>) -> f64 {
        self.n.dot(&p.coords) + self.c
    }
}

/// The kind of move of a calibration pose (seed 000's groups).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MoveKind {
    /// Translation only, relative to the first pose of its block.
    Translate,
    /// Rotation + translation.
    Rotate,
}

/// One usable laser observation.
#[derive(Debug, Clone, PartialEq)]
pub struct LaserObs {
    /// Record id.
    pub id: u64,
    /// Flange pose in the robot base frame (mm).
    pub flange: Isometry3<f64>,
    /// Range (mm).
    pub d: f64,
    /// Calibration plane label (`P1`…), if any.
    pub plane: Option<String>,
    /// Move kind, if labelled.
    pub move_kind: Option<MoveKind>,
    /// Block index within the plane, if labelled.
    pub block: Option<u64>,
    /// Validation target label, if any.
    pub target: Option<String>,
    /// Group (`train`, `validation`, …).
    pub group: Option<String>,
}

/// Errors of the laser calibration.
#[derive(Debug, thiserror::Error)]
pub enum LaserError {
    /// Not enough data for an estimator.
    #[error("{what}: need at least {need}, got {got}")]
    TooFewData {
        /// What was being estimated.
        what: String,
        /// Minimum.
        need: usize,
        /// Available.
        got: usize,
    },
    /// Data that cannot determine the unknowns.
    #[error("degenerate data: {0}")]
    Degenerate(String),
    /// A record without a usable flange pose.
    #[error("pose {id}: {reason}")]
    BadRecord {
        /// Record id.
        id: u64,
        /// Why.
        reason: String,
    },
    /// A calibration file that is not a laser calibration or lacks parameters.
    #[error("calibration: {0}")]
    Calibration(String),
}

/// Parse a file quaternion `[w, x, y, z]` and position into an isometry.
pub fn file_pose(p: &[f64; 3], quat: &[f64; 4]) -> Option<Isometry3<f64>> {
    crate::plausible::quat::pose(p, quat).ok()
}

/// The flange pose of a record: its `flange` block, else the model's FK of `q`.
pub fn record_flange(
    rec: &PoseRecord,
    model: Option<&KinematicModel>,
) -> Result<Isometry3<f64>, LaserError> {
    if let Some(f) = &rec.flange {
        return file_pose(&f.p, &f.quat).ok_or_else(|| LaserError::BadRecord {
            id: rec.id,
            reason: "flange pose is not finite or its quaternion is not unit".into(),
        });
    }
    match (&rec.q, model) {
        (Some(q), Some(m)) if q.len() == m.dof() => {
            let q: Vec<f64> = q.iter().map(|x| x.to_radians()).collect();
            Ok(m.flange_pose(&q))
        }
        (Some(_), Some(_)) => Err(LaserError::BadRecord {
            id: rec.id,
            reason: "joint count does not match the robot".into(),
        }),
        _ => Err(LaserError::BadRecord {
            id: rec.id,
            reason: "no flange pose and no joints to compute it from".into(),
        }),
    }
}

/// Every pose record with a valid range, as observations (records with `range: null` are skipped).
pub fn observations(ds: &Dataset) -> Result<Vec<LaserObs>, LaserError> {
    observations_through(ds, None)
}

/// [`observations`] with the flange of every record computed from its joints `q` by
/// `identified` (the arm's kinematic calibration: geometry and joint effects) instead of the
/// recorded controller flange: the spots then carry the identified arm's accuracy, not the
/// nominal kinematic errors. A record without joints is an error (its flange cannot go
/// through the identified arm).
pub fn observations_through(
    ds: &Dataset,
    identified: Option<&IdentifiedArm>,
) -> Result<Vec<LaserObs>, LaserError> {
    let model = KinematicModel::from_robot_block(&ds.header.robot).ok();
    let ctx: std::collections::HashMap<u64, crate::solve::obs::PoseCtx> = match identified {
        Some(a) => {
            let recs: Vec<&PoseRecord> = ds.poses().collect();
            crate::solve::obs::contexts(&recs, a.model.dof())
                .into_iter()
                .map(|(_, c)| (c.id, c))
                .collect()
        }
        None => Default::default(),
    };
    let mut out = Vec::new();
    for rec in ds.poses() {
        let Some(Some(d)) = rec.range else { continue };
        if !d.is_finite() {
            continue;
        }
        let flange = match identified {
            Some(a) => {
                let c = ctx.get(&rec.id).ok_or_else(|| LaserError::BadRecord {
                    id: rec.id,
                    reason: "no usable joint angles `q`: the flange cannot be computed through \
                             the identified arm (--calibration)"
                        .into(),
                })?;
                a.flange(c)
            }
            None => record_flange(rec, model.as_ref())?,
        };
        let move_kind = match rec.move_kind.as_deref() {
            Some("translate") => Some(MoveKind::Translate),
            Some("rotate") => Some(MoveKind::Rotate),
            _ => None,
        };
        let block = rec.extra.get("block").and_then(|b| b.as_u64());
        out.push(LaserObs {
            id: rec.id,
            flange,
            d,
            plane: rec.plane.clone(),
            move_kind,
            block,
            target: rec.target.clone(),
            group: rec.group.clone(),
        });
    }
    Ok(out)
}

/// Observations grouped by calibration plane label (sorted by label).
pub fn by_plane(obs: &[LaserObs]) -> BTreeMap<String, Vec<LaserObs>> {
    let mut m: BTreeMap<String, Vec<LaserObs>> = BTreeMap::new();
    for o in obs {
        if let Some(p) = &o.plane {
            m.entry(p.clone()).or_default().push(o.clone());
        }
    }
    m
}

/// Validation observations grouped by target label (sorted by label).
pub fn by_target(obs: &[LaserObs]) -> BTreeMap<String, Vec<LaserObs>> {
    let mut m: BTreeMap<String, Vec<LaserObs>> = BTreeMap::new();
    for o in obs {
        if let Some(t) = &o.target {
            m.entry(t.clone()).or_default().push(o.clone());
        }
    }
    m
}

/// Parameter names of a laser calibration file.
pub const PARAM_NAMES: [&str; 6] = [
    "laser_rx", "laser_ry", "laser_rz", "laser_vx", "laser_vy", "laser_vz",
];

/// Calibration parameters for `beam` (with standard deviations when known).
pub fn beam_params(beam: &Beam, std: Option<[f64; 6]>) -> Vec<CalParam> {
    let vals = [beam.r.x, beam.r.y, beam.r.z, beam.v.x, beam.v.y, beam.v.z];
    PARAM_NAMES
        .iter()
        .enumerate()
        .map(|(i, name)| CalParam {
            name: (*name).to_string(),
            value: vals[i],
            std: std.map(|s| s[i]),
            unit: if i < 3 { "mm".into() } else { "1".into() },
            free: true,
            extra: Default::default(),
        })
        .collect()
}

/// The beam stored in a laser calibration file.
pub fn beam_from_calibration(cal: &CalibrationFile) -> Result<Beam, LaserError> {
    let mut vals = [0.0; 6];
    for (i, name) in PARAM_NAMES.iter().enumerate() {
        let p = cal
            .params
            .iter()
            .find(|p| p.name == *name)
            .ok_or_else(|| LaserError::Calibration(format!("parameter `{name}` is missing")))?;
        let expect = if i < 3 { "mm" } else { "1" };
        if p.unit != expect {
            return Err(LaserError::Calibration(format!(
                "parameter `{name}` has unit `{}`, expected `{expect}`",
                p.unit
            )));
        }
        if !p.value.is_finite() {
            return Err(LaserError::Calibration(format!(
                "parameter `{name}` is not finite"
            )));
        }
        vals[i] = p.value;
    }
    let v = Vector3::new(vals[3], vals[4], vals[5]);
    if v.norm() < 1e-9 {
        return Err(LaserError::Calibration("beam direction is zero".into()));
    }
    Ok(Beam {
        r: Vector3::new(vals[0], vals[1], vals[2]),
        v: Unit::new_normalize(v),
    })
}

/// The laser spot (robot base frame, mm) of one record under a laser calibration and its
/// range effects (`laser_scale`, `laser_nonlinearity`; `laser_incidence` needs the surface
/// normal, which a record does not carry, so it is not applied here).
pub fn predict_spot(
    beam: &Beam,
    effects: &[crate::dataset::CalEffect],
    rec: &PoseRecord,
    model: Option<&KinematicModel>,
) -> Result<Option<Point3<f64>>, LaserError> {
    let Some(Some(d)) = rec.range else {
        return Ok(None);
    };
    let flange = record_flange(rec, model)?;
    let d = effects::corrected_range(d, effects, None);
    Ok(Some(beam.spot(&flange, d)))
}

/// The laser calibration file of a comparison: the final (direct ML) beam with its standard
/// deviations, the plane RMS, the spread / TRE of the last method, the fitted planes.
pub fn calibration_file(
    robot: crate::dataset::RobotBlock,
    cmp: &Comparison,
) -> Result<CalibrationFile, LaserError> {
    let beam = cmp
        .final_beam
        .ok_or_else(|| LaserError::Degenerate("no final beam".into()))?;
    let mut cal = CalibrationFile::new(robot, beam_params(&beam, cmp.final_std));
    cal.set_kind("laser");
    let final_row = cmp
        .rows
        .last()
        .ok_or_else(|| LaserError::Degenerate("no method row".into()))?;
    let m = &mut cal.metrics;
    m.insert("plane_rms_mm".into(), cmp.final_plane_rms_mm.into());
    if final_row.spread_mean_mm.is_finite() {
        m.insert("spread_mean_mm".into(), final_row.spread_mean_mm.into());
    }
    if let Some(x) = final_row.spot_rms_vs_truth_mm {
        m.insert("heldout_rms_mm_after".into(), x.into());
    }
    if let Some(x) = final_row.tre_mm {
        m.insert("tre_mm".into(), x.into());
    }
    cal.extra.insert(
        "planes".into(),
        serde_json::Value::Array(
            cmp.final_planes
                .iter()
                .map(|(l, p)| {
                    serde_json::json!({"label": l, "normal": [p.n.x, p.n.y, p.n.z], "offset_mm": p.c})
                })
                .collect(),
        ),
    );
    cal.extra.insert(
        "method".into(),
        "direct point-to-plane ML (seed 000 methods compared in laser_report.json)".into(),
    );
    Ok(cal)
}

/// Effects of a kinematic calibration that act on the arm's joints (they move the flange);
/// the others describe the tracker or that session's clock (scale, base shift, drift in time,
/// latency, a residual learnt on tracker data) and do not carry to another sensor.
pub const ARM_EFFECTS: [&str; 7] = [
    "joint_compliance",
    "backlash",
    "joint_eccentricity",
    "transmission_ratio",
    "transmission_ripple",
    "joint_coupling",
    "wave_generator",
];

/// The identified arm of a kinematic calibration: its geometry and its joint effects.
#[derive(Debug, Clone)]
pub struct IdentifiedArm {
    pub model: KinematicModel,
    pub effects: Vec<crate::diagnose::effects::Effect>,
    /// Effect kinds applied / left out (not acting on the arm's joints).
    pub applied: Vec<String>,
    pub left_out: Vec<String>,
}

impl IdentifiedArm {
    /// The flange pose (robot base, mm) of one pose: the identified geometry at the joints
    /// corrected by the joint effects.
    pub fn flange(&self, ctx: &crate::solve::obs::PoseCtx) -> Isometry3<f64> {
        use crate::diagnose::effects::{joint_offsets, pose_model};
        let d = joint_offsets(&self.model, &self.effects, ctx);
        let th: Vec<f64> = ctx.q.iter().zip(&d).map(|(q, d)| q + d).collect();
        pose_model(&self.model, &self.effects, ctx).flange_pose(&th)
    }
}

/// The identified arm of a kinematic calibration file (its geometric parameters and joint
/// effects on the dataset's robot model): refused when it is a calibration of another robot
/// model or serial, or not a kinematic calibration (a laser or camera calibration has no arm
/// parameters).
pub fn identified_arm(
    cal_path: &std::path::Path,
    ds: &Dataset,
    data: &std::path::Path,
) -> anyhow::Result<IdentifiedArm> {
    use anyhow::{bail, Context as _};
    let cal = CalibrationFile::load(cal_path)
        .with_context(|| format!("reading the arm calibration {}", cal_path.display()))?;
    if cal.robot.model != ds.header.robot.model {
        bail!(
            "{}: a calibration of robot {:?}, but {} was recorded with {:?}: give the kinematic \
             calibration of this arm",
            cal_path.display(),
            cal.robot.model,
            data.display(),
            ds.header.robot.model
        );
    }
    if let (Some(a), Some(b)) = (&cal.robot.serial, &ds.header.robot.serial) {
        if a != b {
            bail!(
                "{}: a calibration of robot serial {a:?}, but {} was recorded on serial {b:?}",
                cal_path.display(),
                data.display()
            );
        }
    }
    let mut model = KinematicModel::from_robot_block(&cal.robot)
        .with_context(|| format!("{}: robot block", cal_path.display()))?;
    let arm: Vec<CalParam> = cal
        .params
        .iter()
        .filter(|p| model.param_index(&p.name).is_some())
        .cloned()
        .collect();
    if arm.is_empty() {
        bail!(
            "{}: no kinematic parameter of {:?} in it (a laser or camera calibration?): give \
             the arm's kinematic calibration (`robocal calibrate kinematics`)",
            cal_path.display(),
            cal.robot.model
        );
    }
    model
        .apply_cal_params(&arm)
        .with_context(|| format!("{}: parameters", cal_path.display()))?;
    let (mut effects, mut applied, mut left_out) = (Vec::new(), Vec::new(), Vec::new());
    for e in &cal.effects {
        if ARM_EFFECTS.contains(&e.kind.as_str()) {
            effects.push(
                crate::diagnose::effects::Effect::from_cal(e)
                    .with_context(|| format!("{}: effect {}", cal_path.display(), e.kind))?,
            );
            applied.push(e.kind.clone());
        } else {
            left_out.push(e.kind.clone());
        }
    }
    Ok(IdentifiedArm {
        model,
        effects,
        applied,
        left_out,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    #[test]
    fn spot_follows_eq_19() {
        let beam = Beam {
            r: Vector3::new(10.0, 0.0, 50.0),
            v: Vector3::z_axis(),
        };
        let f = Isometry3::from_parts(
            Translation3::new(100.0, 0.0, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), std::f64::consts::FRAC_PI_2),
        );
        let p = beam.spot(&f, 200.0);
        // Flange z maps to base x; flange x maps to base -z.
        assert!((p - Point3::new(100.0 + 250.0, 0.0, -10.0)).norm() < 1e-9);
    }

    #[test]
    fn calibration_round_trip_and_errors() {
        let beam = Beam {
            r: Vector3::new(1.0, 2.0, 3.0),
            v: Unit::new_normalize(Vector3::new(0.01, 0.0, 1.0)),
        };
        let robot = crate::dataset::RobotBlock::named("denso-vs060");
        let mut cal = CalibrationFile::new(robot, beam_params(&beam, None));
        cal.set_kind("laser");
        let back = beam_from_calibration(&cal).unwrap();
        assert!(
            (back.r - beam.r).norm() < 1e-12
                && (back.v.into_inner() - beam.v.into_inner()).norm() < 1e-12
        );
        cal.params.retain(|p| p.name != "laser_vy");
        let e = beam_from_calibration(&cal).unwrap_err();
        assert!(e.to_string().contains("laser_vy"), "{e}");
    }
}
