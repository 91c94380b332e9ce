//! The cell's geometry as the planner sees it: where the tracker stands (roughly, as the cell
//! file states it), its measurement volume, the largest view angle of the marker and the
//! spheres that block the line of sight. The checks are the tracker visibility model of the
//! cell (volume frustum along the tracker's −z, marker z axis within the view angle of the
//! line of sight, line-of-sight segment clear of every occluder sphere), applied to the
//! nominal tool (marker) pose with a safety margin so the small difference between the
//! nominal and the real arm does not turn a planned pose into a skipped one.
//! Units: file mm / degrees, inside mm / rad.
use nalgebra::{Isometry3, Point3, Vector3};
use serde::{Deserialize, Serialize};

use super::constraints::RejectReason;
use super::spec::FrameSpec;

/// A sphere that blocks the line of sight (robot base frame, mm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Occluder {
    pub center_mm: [f64; 3],
    pub radius_mm: f64,
}

/// Measurement volume: a frustum along the tracker's −z axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VolumeFrustum {
    /// Nearest and farthest depth (mm).
    pub near_mm: f64,
    pub far_mm: f64,
    /// Tangent of the half-angle across x and across y.
    pub tan_x: f64,
    pub tan_y: f64,
}

impl VolumeFrustum {
    /// Whether a point in the tracker frame lies at least `margin` (mm) inside.
    pub fn contains(&self, p: &Point3<f64>, margin: f64) -> bool {
        let depth = -p.z;
        depth >= self.near_mm + margin
            && depth <= self.far_mm - margin
            && p.x.abs() + margin <= depth * self.tan_x
            && p.y.abs() + margin <= depth * self.tan_y
    }
}

/// What the planner knows of the cell (the `cell` table of a plan spec).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CellGeometry {
    /// Tracker pose in the robot base frame (mm, URDF rpy deg).
    pub tracker_pose: FrameSpec,
    /// Measurement volume (none: unbounded).
    #[serde(default)]
    pub volume: Option<VolumeFrustum>,
    /// The marker's z axis must be within this angle of the line of sight (deg).
    #[serde(default)]
    pub max_view_angle_deg: Option<f64>,
    /// Spheres blocking the line of sight.
    #[serde(default)]
    pub occluders: Vec<Occluder>,
    /// Safety margin kept from the volume's faces and the occluders (mm); the view angle
    /// keeps `margin_deg`.
    #[serde(default = "d_margin_mm")]
    pub margin_mm: f64,
    #[serde(default = "d_margin_deg")]
    pub margin_deg: f64,
}

fn d_margin_mm() -> f64 {
    25.0
}
fn d_margin_deg() -> f64 {
    3.0
}

/// Distance from `c` to the segment `a`–`b`.
fn segment_distance(a: &Point3<f64>, b: &Point3<f64>, c: &Point3<f64>) -> f64 {
    let ab = b - a;
    let l2 = ab.norm_squared();
    let s = if l2 > 0.0 {
        ((c - a).dot(&ab) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (a + ab * s - c).norm()
}

impl CellGeometry {
    /// Why the marker at `marker_in_base` (its z axis the marker normal) would not be
    /// measured, or `None`.
    pub fn check(&self, marker_in_base: &Isometry3<f64>) -> Option<RejectReason> {
        let tib = super::frame_iso(&self.tracker_pose);
        let m = Point3::from(marker_in_base.translation.vector);
        let t = Point3::from(tib.translation.vector);
        let blocked = self.occluders.iter().any(|o| {
            segment_distance(&t, &m, &Point3::from(o.center_mm)) < o.radius_mm + self.margin_mm
        });
        if blocked {
            return Some(RejectReason::Occluded);
        }
        let p = tib.inverse_transform_point(&m);
        if let Some(max) = self.max_view_angle_deg {
            let z = marker_in_base.rotation * Vector3::z();
            let to_tracker = (t - m).normalize();
            let ang = z.dot(&to_tracker).clamp(-1.0, 1.0).acos().to_degrees();
            if ang > max - self.margin_deg {
                return Some(RejectReason::TrackerAngle { angle_deg: ang });
            }
        }
        if let Some(v) = &self.volume {
            if !v.contains(&p, self.margin_mm) {
                return Some(RejectReason::TrackerVolume);
            }
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cell() -> CellGeometry {
        CellGeometry {
            tracker_pose: FrameSpec {
                xyz: [2000.0, 0.0, 400.0],
                rpy: [0.0, -90.0, 0.0],
            },
            volume: Some(VolumeFrustum {
                near_mm: 950.0,
                far_mm: 2400.0,
                tan_x: 0.33,
                tan_y: 0.28,
            }),
            max_view_angle_deg: Some(75.0),
            occluders: vec![Occluder {
                center_mm: [1000.0, 0.0, 400.0],
                radius_mm: 50.0,
            }],
            margin_mm: 10.0,
            margin_deg: 2.0,
        }
    }

    /// A marker facing the tracker 1.5 m in front of it is seen; behind the occluder it is
    /// not; turned away it is not; beyond the far face it is not.
    #[test]
    fn visibility_volume_angle_occluder() {
        let c = cell();
        let tib = super::super::frame_iso(&c.tracker_pose);
        // The tracker looks along its -z: with rpy (0,-90,0) its -z is base +x... pick a point
        // on its line of sight at 1500 mm and face the marker back at it.
        let dir = tib.rotation * -Vector3::z();
        let at = |off: Vector3<f64>, depth: f64| {
            let p = tib.translation.vector + dir * depth + off;
            let z = -dir; // marker z axis towards the tracker
            let rot = nalgebra::UnitQuaternion::rotation_between(&Vector3::z(), &z).unwrap();
            Isometry3::from_parts(p.into(), rot)
        };
        let seen = at(Vector3::new(0.0, 300.0, 0.0), 1500.0);
        assert_eq!(c.check(&seen), None);
        let far = at(Vector3::zeros(), 2500.0);
        assert!(matches!(
            c.check(&far),
            Some(RejectReason::TrackerVolume | RejectReason::Occluded)
        ));
        let mut away = seen;
        away.rotation = nalgebra::UnitQuaternion::rotation_between(&Vector3::z(), &dir).unwrap();
        assert!(matches!(
            c.check(&away),
            Some(RejectReason::TrackerAngle { .. })
        ));
        // The occluder sits on the line of sight from the tracker to a marker beyond it.
        let behind = Isometry3::from_parts(
            nalgebra::Translation3::new(-100.0, 0.0, 400.0),
            seen.rotation,
        );
        let d = (tib.translation.vector - Vector3::new(1000.0, 0.0, 400.0)).norm();
        assert!(d > 0.0);
        assert_eq!(c.check(&behind), Some(RejectReason::Occluded));
    }
}
