//! Pose constraints. Each check returns the reason a pose is rejected, or `None`.
//!
//! Pose-level checks (`tracker_*`, `laser_*`, envelope of the tool point) depend only on the
//! tool pose; arm-level checks (joint limits, table, self-collision, envelope of the arm
//! points) depend on the IK branch. All lengths mm, angles rad.
use nalgebra::{Isometry3, Point3, Vector3};
use robocal_drivers::safety::{Envelope, TablePlane};
use std::fmt;

use super::gen::HitPlane;
use super::spec::{ConstraintSpec, LaserSpec, TrackerKind, TrackerSpec};
use crate::model::KinematicModel;

/// Why a pose (or a whole target) was rejected.
#[derive(Debug, Clone, PartialEq)]
pub enum RejectReason {
    /// IK has no solution (outside the reach of every branch).
    Unreachable,
    /// The branch exceeds a joint limit (1-based joint).
    JointLimit { joint: usize },
    /// A point of the arm is below the table plane plus clearance.
    Table { margin_mm: f64 },
    /// Two non-adjacent link capsules intersect.
    SelfCollision { a: usize, b: usize },
    /// A check point leaves the Cartesian envelope.
    Envelope,
    /// The marker is outside the tracker's measurement volume.
    TrackerVolume,
    /// The marker faces away from the tracker.
    TrackerAngle { angle_deg: f64 },
    /// The laser range is outside the sensor window (or the beam misses the plane).
    LaserRange { range_mm: f64 },
    /// The beam hits the plane too obliquely.
    LaserIncidence { angle_deg: f64 },
    /// Fewer feasible IK branches than the validation set needs.
    TooFewBranches { got: usize },
    /// Something in the cell (an occluder of the cell geometry) blocks the line of sight.
    Occluded,
}

impl RejectReason {
    /// Short key used to count reasons in the summary.
    pub fn key(&self) -> &'static str {
        match self {
            RejectReason::Unreachable => "unreachable",
            RejectReason::JointLimit { .. } => "joint-limit",
            RejectReason::Table { .. } => "table",
            RejectReason::SelfCollision { .. } => "self-collision",
            RejectReason::Envelope => "envelope",
            RejectReason::TrackerVolume => "tracker-volume",
            RejectReason::TrackerAngle { .. } => "tracker-angle",
            RejectReason::LaserRange { .. } => "laser-range",
            RejectReason::LaserIncidence { .. } => "laser-incidence",
            RejectReason::TooFewBranches { .. } => "too-few-branches",
            RejectReason::Occluded => "occluded",
        }
    }
}

impl fmt::Display for RejectReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RejectReason::Unreachable => write!(f, "unreachable (no IK solution)"),
            RejectReason::JointLimit { joint } => write!(f, "joint {joint} outside its limits"),
            RejectReason::Table { margin_mm } => {
                write!(f, "arm {:.1} mm past the table clearance", -margin_mm)
            }
            RejectReason::SelfCollision { a, b } => {
                write!(f, "self-collision between capsules {a} and {b}")
            }
            RejectReason::Envelope => write!(f, "outside the safety envelope"),
            RejectReason::TrackerVolume => write!(f, "marker outside the tracker volume"),
            RejectReason::TrackerAngle { angle_deg } => {
                write!(f, "marker turned {angle_deg:.1}° from the line of sight")
            }
            RejectReason::LaserRange { range_mm } => {
                write!(f, "laser range {range_mm:.1} mm outside the window")
            }
            RejectReason::LaserIncidence { angle_deg } => {
                write!(f, "laser incidence {angle_deg:.1}° too large")
            }
            RejectReason::TooFewBranches { got } => {
                write!(f, "only {got} feasible IK branches")
            }
            RejectReason::Occluded => write!(f, "line of sight blocked by an occluder"),
        }
    }
}

/// Approximate measurement volume of a tracker: a frustum along the tracker's −z between
/// `near` and `far` (mm) with half-angles (rad) horizontally (x) and vertically (y).
///
/// **Approximate:** the published NDI volumes are pyramids with a flat near face and a
/// stepped/curved far face; this keeps their depth range and far-face width/height only.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frustum {
    pub near_mm: f64,
    pub far_mm: f64,
    pub half_x: f64,
    pub half_y: f64,
}

impl Frustum {
    /// The approximate published volume of a tracker model.
    ///
    /// - Polaris Vega / Spectra pyramid: 950–2400 mm deep, far face ≈ 1566 × 1312 mm.
    /// - Polaris Vega extended pyramid: 950–3000 mm, far face ≈ 1856 × 1470 mm.
    /// - Optotrak Certus: ≈ 1500–6000 mm deep, ≈ 3.0 × 2.0 m at 2.25 m (about ±34° × ±24°).
    pub fn of(kind: TrackerKind) -> Frustum {
        let fr = |near: f64, far: f64, w: f64, h: f64| Frustum {
            near_mm: near,
            far_mm: far,
            half_x: (w / 2.0 / far).atan(),
            half_y: (h / 2.0 / far).atan(),
        };
        match kind {
            TrackerKind::PolarisVega | TrackerKind::PolarisSpectra => {
                fr(950.0, 2400.0, 1566.0, 1312.0)
            }
            TrackerKind::PolarisVegaExtended => fr(950.0, 3000.0, 1856.0, 1470.0),
            TrackerKind::OptotrakCertus => Frustum {
                near_mm: 1500.0,
                far_mm: 6000.0,
                half_x: (1500.0f64 / 2250.0).atan(),
                half_y: (1000.0f64 / 2250.0).atan(),
            },
        }
    }

    /// Whether a point in the tracker frame is inside.
    pub fn contains(&self, p: &Point3<f64>) -> bool {
        let depth = -p.z;
        depth >= self.near_mm
            && depth <= self.far_mm
            && p.x.abs() <= depth * self.half_x.tan()
            && p.y.abs() <= depth * self.half_y.tan()
    }
}

/// Tracker visibility of a marker at `tool_in_base`.
pub fn tracker_check(
    t: &TrackerSpec,
    tracker_in_base: &Isometry3<f64>,
    tool_in_base: &Isometry3<f64>,
) -> Option<RejectReason> {
    let p_base = Point3::from(tool_in_base.translation.vector);
    let p_trk = tracker_in_base.inverse_transform_point(&p_base);
    if !Frustum::of(t.kind).contains(&p_trk) {
        return Some(RejectReason::TrackerVolume);
    }
    let n_tool = Vector3::from(t.marker_normal);
    if n_tool.norm() < 1e-12 {
        return Some(RejectReason::TrackerAngle { angle_deg: 180.0 });
    }
    let n = tool_in_base.rotation * n_tool.normalize();
    let sight = (Point3::from(tracker_in_base.translation.vector) - p_base).normalize();
    let ang = n.dot(&sight).clamp(-1.0, 1.0).acos();
    if ang > t.max_angle_deg.to_radians() {
        return Some(RejectReason::TrackerAngle {
            angle_deg: ang.to_degrees(),
        });
    }
    None
}

/// Laser beam (tool z from the tool origin) against the plane it must hit.
pub fn laser_check(
    l: &LaserSpec,
    tool_in_base: &Isometry3<f64>,
    plane: &HitPlane,
) -> Option<RejectReason> {
    let o = Point3::from(tool_in_base.translation.vector);
    let b = tool_in_base.rotation * Vector3::z();
    let n = plane.normal.normalize();
    let denom = b.dot(&n);
    if denom >= -1e-9 {
        // Beam parallel to or pointing away from the plane: never hits.
        return Some(RejectReason::LaserRange {
            range_mm: f64::INFINITY,
        });
    }
    let range = (plane.point - o).dot(&n) / denom;
    let inc = (-denom).clamp(-1.0, 1.0).acos();
    if !(range >= l.range_mm[0] && range <= l.range_mm[1]) {
        return Some(RejectReason::LaserRange { range_mm: range });
    }
    if inc > l.max_incidence_deg.to_radians() {
        return Some(RejectReason::LaserIncidence {
            angle_deg: inc.to_degrees(),
        });
    }
    None
}

/// Points along the arm for `q`: robot base origin, every MDH joint frame origin, the flange
/// and the tool point (mm, base frame), with consecutive duplicates (< 1 mm) removed. The
/// last point is the tool point, the one before it the flange.
pub fn arm_points(model: &KinematicModel, q: &[f64], tool: &Isometry3<f64>) -> Vec<Point3<f64>> {
    let mut pts = vec![Point3::from(model.base_offset().translation.vector)];
    for k in 1..=model.dof() {
        pts.push(Point3::from(model.joint_frame(q, k).translation.vector));
    }
    let fl = model.flange_pose(q);
    let mut out: Vec<Point3<f64>> = Vec::with_capacity(pts.len() + 2);
    for p in pts {
        if out.last().is_none_or(|l| (l - p).norm() > 1.0) {
            out.push(p);
        }
    }
    // The flange and tool are always present (even if they coincide with the wrist).
    out.push(Point3::from(fl.translation.vector));
    out.push(Point3::from((fl * tool).translation.vector));
    out
}

/// Closest distance between segments `p1-q1` and `p2-q2`.
pub fn segment_distance(
    p1: &Point3<f64>,
    q1: &Point3<f64>,
    p2: &Point3<f64>,
    q2: &Point3<f64>,
) -> f64 {
    let d1 = q1 - p1;
    let d2 = q2 - p2;
    let r = p1 - p2;
    let a = d1.dot(&d1);
    let e = d2.dot(&d2);
    let f = d2.dot(&r);
    let (s, t);
    if a <= 1e-12 && e <= 1e-12 {
        return (p1 - p2).norm();
    }
    if a <= 1e-12 {
        s = 0.0;
        t = (f / e).clamp(0.0, 1.0);
    } else {
        let c = d1.dot(&r);
        if e <= 1e-12 {
            t = 0.0;
            s = (-c / a).clamp(0.0, 1.0);
        } else {
            let b = d1.dot(&d2);
            let denom = a * e - b * b;
            let mut s0 = if denom > 1e-12 {
                ((b * f - c * e) / denom).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let mut t0 = (b * s0 + f) / e;
            if t0 < 0.0 {
                t0 = 0.0;
                s0 = (-c / a).clamp(0.0, 1.0);
            } else if t0 > 1.0 {
                t0 = 1.0;
                s0 = ((b - c) / a).clamp(0.0, 1.0);
            }
            s = s0;
            t = t0;
        }
    }
    ((p1 + d1 * s) - (p2 + d2 * t)).norm()
}

/// Capsule self-collision: link segments between consecutive [`arm_points`] (the last one
/// the tool, with the tool radius); pairs that are not neighbours (index difference ≥ 2)
/// must stay apart by the sum of their radii. Returns the first colliding pair (0-based).
pub fn self_collision(pts: &[Point3<f64>], link_r: f64, tool_r: f64) -> Option<(usize, usize)> {
    let n = pts.len().saturating_sub(1);
    let radius = |i: usize| if i + 1 == n { tool_r } else { link_r };
    for i in 0..n {
        for j in (i + 2)..n {
            let d = segment_distance(&pts[i], &pts[i + 1], &pts[j], &pts[j + 1]);
            if d < radius(i) + radius(j) {
                return Some((i, j));
            }
        }
    }
    None
}

/// The table plane of the constraint spec, as the safety wrappers' type.
pub fn table_plane(c: &ConstraintSpec) -> Option<TablePlane> {
    c.table_z_mm.map(|z| TablePlane {
        point: [0.0, 0.0, z],
        normal: [0.0, 0.0, 1.0],
        clearance_mm: c.table_clearance_mm,
    })
}

/// Arm-level checks for one IK branch.
pub fn arm_check(
    c: &ConstraintSpec,
    model: &KinematicModel,
    q: &[f64],
    tool: &Isometry3<f64>,
) -> Option<RejectReason> {
    let margin = c.joint_margin_deg.to_radians();
    for (i, (&x, &(lo, hi))) in q.iter().zip(model.joint_limits().iter()).enumerate() {
        if !(x >= lo + margin && x <= hi - margin) {
            return Some(RejectReason::JointLimit { joint: i + 1 });
        }
    }
    let pts = arm_points(model, q, tool);
    if let Some(t) = table_plane(c) {
        // The robot base origin sits on its own mounting: only the other points count.
        for p in pts.iter().skip(1) {
            let m = t.margin(p);
            if m < 0.0 {
                return Some(RejectReason::Table { margin_mm: m });
            }
        }
    }
    if let Some(env) = &c.envelope {
        if !envelope_ok(env, &pts[pts.len() - 2..]) {
            return Some(RejectReason::Envelope);
        }
    }
    if c.self_collision {
        if let Some((a, b)) = self_collision(&pts, c.link_radius_mm, c.tool_radius_mm) {
            return Some(RejectReason::SelfCollision { a, b });
        }
    }
    None
}

/// Whether all points are inside the envelope.
pub fn envelope_ok(env: &Envelope, pts: &[Point3<f64>]) -> bool {
    pts.iter().all(|p| env.contains(p))
}
