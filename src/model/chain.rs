//! The URDF-style serial chain (the `robot.chain` of a dataset header, or a URDF file) and its
//! direct forward kinematics. This is the reference the MDH + Hayati model is checked against.
//!
//! Units: mm and radians inside (the dataset's degrees are converted on construction, URDF
//! metres are multiplied by 1000).
use nalgebra::{Isometry3, Translation3, UnitQuaternion, UnitVector3, Vector3};

use super::error::ModelError;
use crate::dataset::{ChainJoint, FixedOrigin};

/// One revolute joint of a [`SerialChain`].
#[derive(Debug, Clone, PartialEq)]
pub struct ChainSpecJoint {
    pub name: String,
    /// Fixed transform from the previous joint frame (mm).
    pub origin: Isometry3<f64>,
    /// Rotation axis in the joint frame.
    pub axis: UnitVector3<f64>,
    /// Limits (rad), when known.
    pub limits: Option<(f64, f64)>,
}

/// A serial chain of revolute joints, URDF convention, mm / rad.
#[derive(Debug, Clone, PartialEq)]
pub struct SerialChain {
    pub joints: Vec<ChainSpecJoint>,
    /// Fixed transform from the last joint frame to the flange (mm).
    pub flange: Isometry3<f64>,
}

/// `Translation(xyz) * Rz(yaw) * Ry(pitch) * Rx(roll)` (URDF origin), xyz mm, rpy rad.
pub fn origin_iso(xyz: [f64; 3], rpy: [f64; 3]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(xyz[0], xyz[1], xyz[2]),
        UnitQuaternion::from_euler_angles(rpy[0], rpy[1], rpy[2]),
    )
}

fn finite3(v: &[f64; 3]) -> bool {
    v.iter().all(|x| x.is_finite())
}

impl SerialChain {
    /// From the dataset header's chain (mm, degrees).
    pub fn from_chain_joints(
        chain: &[ChainJoint],
        flange: Option<&FixedOrigin>,
    ) -> Result<Self, ModelError> {
        if chain.is_empty() {
            return Err(ModelError::EmptyChain);
        }
        let mut joints = Vec::with_capacity(chain.len());
        for j in chain {
            let bad = |reason: &str| ModelError::InvalidJoint {
                joint: j.name.clone(),
                reason: reason.to_string(),
            };
            if !finite3(&j.origin_xyz) || !finite3(&j.origin_rpy) || !finite3(&j.axis) {
                return Err(bad("origin or axis is not finite"));
            }
            let axis = Vector3::from(j.axis);
            if axis.norm() < 1e-9 {
                return Err(bad("axis has zero length"));
            }
            let limits = match j.limits {
                Some([lo, hi]) => {
                    if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
                        return Err(bad("limits must be finite with lower <= upper"));
                    }
                    Some((lo.to_radians(), hi.to_radians()))
                }
                None => None,
            };
            let rpy = j.origin_rpy.map(f64::to_radians);
            joints.push(ChainSpecJoint {
                name: j.name.clone(),
                origin: origin_iso(j.origin_xyz, rpy),
                axis: UnitVector3::new_normalize(axis),
                limits,
            });
        }
        let flange = match flange {
            Some(f) => {
                if !finite3(&f.origin_xyz) || !finite3(&f.origin_rpy) {
                    return Err(ModelError::InvalidJoint {
                        joint: "flange".into(),
                        reason: "origin is not finite".into(),
                    });
                }
                origin_iso(f.origin_xyz, f.origin_rpy.map(f64::to_radians))
            }
            None => Isometry3::identity(),
        };
        Ok(SerialChain { joints, flange })
    }

    /// Number of joints.
    pub fn dof(&self) -> usize {
        self.joints.len()
    }

    /// Flange pose in the robot base (mm), q in rad; missing entries of `q` count as 0.
    pub fn fk(&self, q: &[f64]) -> Isometry3<f64> {
        let mut t = Isometry3::identity();
        for (i, j) in self.joints.iter().enumerate() {
            let qi = q.get(i).copied().unwrap_or(0.0);
            t = t * j.origin * UnitQuaternion::from_axis_angle(&j.axis, qi);
        }
        t * self.flange
    }

    /// Parse a URDF and extract the revolute chain from `base_link` (default: the root link)
    /// to `tip_link` (default: the end of the longest joint path). Fixed joints are merged
    /// into the next joint's origin (or into the flange after the last movable joint).
    /// URDF metres become mm.
    pub fn from_urdf_str(
        xml: &str,
        base_link: Option<&str>,
        tip_link: Option<&str>,
    ) -> Result<Self, ModelError> {
        let robot = urdf_rs::read_from_string(xml).map_err(|e| ModelError::Urdf {
            message: e.to_string(),
        })?;
        let links: Vec<&str> = robot.links.iter().map(|l| l.name.as_str()).collect();
        let exists = |l: &str| {
            links.contains(&l)
                || robot
                    .joints
                    .iter()
                    .any(|j| j.parent.link == l || j.child.link == l)
        };
        let base = match base_link {
            Some(b) => {
                if !exists(b) {
                    return Err(ModelError::UrdfLinkNotFound { link: b.into() });
                }
                b.to_string()
            }
            None => {
                // root: a parent link that is nobody's child
                let root = robot
                    .joints
                    .iter()
                    .map(|j| j.parent.link.as_str())
                    .find(|p| !robot.joints.iter().any(|j| j.child.link == *p));
                match root {
                    Some(r) => r.to_string(),
                    None => return Err(ModelError::EmptyChain),
                }
            }
        };
        if let Some(t) = tip_link {
            if !exists(t) {
                return Err(ModelError::UrdfLinkNotFound { link: t.into() });
            }
        }
        // Depth-first walk over joints from `base`: find the path to the tip (or the longest
        // path by number of movable joints).
        fn walk<'a>(
            robot: &'a urdf_rs::Robot,
            link: &str,
            tip: Option<&str>,
            path: &mut Vec<&'a urdf_rs::Joint>,
            best: &mut Option<Vec<&'a urdf_rs::Joint>>,
            depth: usize,
        ) {
            if depth > 10_000 {
                return;
            }
            let movable = |p: &[&urdf_rs::Joint]| {
                p.iter()
                    .filter(|j| !matches!(j.joint_type, urdf_rs::JointType::Fixed))
                    .count()
            };
            match tip {
                Some(t) if t == link => {
                    *best = Some(path.clone());
                    return;
                }
                None => {
                    // most movable joints; on a tie the longer path (trailing fixed
                    // joints are the flange)
                    let better = match best {
                        None => true,
                        Some(b) => (movable(path), path.len()) > (movable(b), b.len()),
                    };
                    if better {
                        *best = Some(path.clone());
                    }
                }
                _ => {}
            }
            for j in robot.joints.iter().filter(|j| j.parent.link == link) {
                if path.iter().any(|p| std::ptr::eq(*p, j)) {
                    continue; // cycle guard
                }
                path.push(j);
                walk(robot, &j.child.link, tip, path, best, depth + 1);
                path.pop();
                if tip.is_some() && best.is_some() {
                    return;
                }
            }
        }
        let mut best = None;
        walk(&robot, &base, tip_link, &mut Vec::new(), &mut best, 0);
        let path = best.ok_or_else(|| ModelError::UrdfNoPath {
            base: base.clone(),
            tip: tip_link.unwrap_or("<leaf>").to_string(),
        })?;
        // Drop trailing fixed joints past the last movable one only if no tip was given?
        // No: trailing fixed joints are the flange (merged below).
        let mut joints = Vec::new();
        let mut pending = Isometry3::identity();
        for j in path {
            let xyz = [
                j.origin.xyz.0[0] * 1000.0,
                j.origin.xyz.0[1] * 1000.0,
                j.origin.xyz.0[2] * 1000.0,
            ];
            let rpy = j.origin.rpy.0;
            if !finite3(&xyz) || !finite3(&rpy) {
                return Err(ModelError::InvalidJoint {
                    joint: j.name.clone(),
                    reason: "origin is not finite".into(),
                });
            }
            let origin = origin_iso(xyz, rpy);
            match j.joint_type {
                urdf_rs::JointType::Fixed => pending *= origin,
                urdf_rs::JointType::Revolute | urdf_rs::JointType::Continuous => {
                    let axis = Vector3::from(j.axis.xyz.0);
                    if !finite3(&j.axis.xyz.0) || axis.norm() < 1e-9 {
                        return Err(ModelError::InvalidJoint {
                            joint: j.name.clone(),
                            reason: "axis has zero length or is not finite".into(),
                        });
                    }
                    let limits = if matches!(j.joint_type, urdf_rs::JointType::Revolute)
                        && j.limit.lower.is_finite()
                        && j.limit.upper.is_finite()
                        && j.limit.lower < j.limit.upper
                    {
                        Some((j.limit.lower, j.limit.upper))
                    } else {
                        None
                    };
                    joints.push(ChainSpecJoint {
                        name: j.name.clone(),
                        origin: pending * origin,
                        axis: UnitVector3::new_normalize(axis),
                        limits,
                    });
                    pending = Isometry3::identity();
                }
                ref other => {
                    return Err(ModelError::UnsupportedJoint {
                        joint: j.name.clone(),
                        kind: format!("{other:?}").to_lowercase(),
                    })
                }
            }
        }
        if joints.is_empty() {
            return Err(ModelError::EmptyChain);
        }
        Ok(SerialChain {
            joints,
            flange: pending,
        })
    }
}
