//! The true robot: a URDF-style serial chain with its own forward kinematics.
//!
//! Convention (URDF, lengths in mm, angles in rad inside this module): for joint *i* the fixed
//! transform from the previous joint frame (the base for joint 1) is `Trans(origin_xyz) ·
//! Rot(origin_rpy)` with URDF fixed-axis roll-pitch-yaw (`Rz(y)·Ry(p)·Rx(r)`), followed by a
//! rotation of θ_i about `axis`. `flange` is the fixed transform from the last joint frame to the
//! mounting flange. This code shares nothing with the root crate's MDH/Hayati model on purpose.

use nalgebra::{Isometry3, Point3, Translation3, Unit, UnitQuaternion, Vector3};
use rand::Rng;
use serde::{Deserialize, Serialize};

/// URDF roll-pitch-yaw (rad) to a rotation: `Rz(yaw) · Ry(pitch) · Rx(roll)`.
pub fn rpy_rotation(rpy: &Vector3<f64>) -> UnitQuaternion<f64> {
    let rx = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), rpy.x);
    let ry = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), rpy.y);
    let rz = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), rpy.z);
    rz * ry * rx
}

/// A fixed transform from xyz (mm) and URDF rpy (rad).
pub fn fixed_transform(xyz: &Vector3<f64>, rpy: &Vector3<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::from(*xyz), rpy_rotation(rpy))
}

/// A fixed transform from xyz (mm) and URDF rpy (deg) given as arrays.
pub fn fixed_transform_deg(xyz_mm: [f64; 3], rpy_deg: [f64; 3]) -> Isometry3<f64> {
    fixed_transform(
        &Vector3::from(xyz_mm),
        &Vector3::from(rpy_deg).map(f64::to_radians),
    )
}

/// One revolute joint of a URDF-style chain (mm, rad).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UrdfJoint {
    /// Joint name.
    pub name: String,
    /// Fixed translation from the previous frame (mm).
    pub origin_xyz_mm: Vector3<f64>,
    /// Fixed URDF roll-pitch-yaw (rad).
    pub origin_rpy_rad: Vector3<f64>,
    /// Rotation axis in the joint frame (unit).
    pub axis: Unit<Vector3<f64>>,
    /// Joint limits (rad).
    pub limits_rad: (f64, f64),
}

/// A URDF-style serial chain of revolute joints plus a fixed flange transform (mm, rad).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UrdfChain {
    /// Robot model name (`denso-vs060`, `ur5e`, `ur10e`, …).
    pub model: String,
    /// The joints, base to tip.
    pub joints: Vec<UrdfJoint>,
    /// Flange translation in the last joint frame (mm).
    pub flange_xyz_mm: Vector3<f64>,
    /// Flange URDF rpy in the last joint frame (rad).
    pub flange_rpy_rad: Vector3<f64>,
}

/// Per-joint frames of one forward-kinematics evaluation (all in the robot base frame).
#[derive(Debug, Clone)]
pub struct ChainFrames {
    /// Frame of joint *i* after its rotation (index 0 = joint 1).
    pub joints: Vec<Isometry3<f64>>,
    /// The flange.
    pub flange: Isometry3<f64>,
}

impl ChainFrames {
    /// Origin of joint `i` (0-based) in the base frame (mm).
    pub fn joint_origin(&self, i: usize) -> Point3<f64> {
        Point3::from(self.joints[i].translation.vector)
    }
    /// Joint axis `i` (0-based) in the base frame, given the chain.
    pub fn joint_axis(&self, chain: &UrdfChain, i: usize) -> Vector3<f64> {
        self.joints[i].rotation * chain.joints[i].axis.into_inner()
    }
}

/// An extra rotation applied right after a joint's own rotation (link/bearing tilt), as a
/// rotation vector in the joint frame (rad).
pub type JointTilt = Vector3<f64>;

impl UrdfChain {
    /// Number of joints.
    pub fn dof(&self) -> usize {
        self.joints.len()
    }

    /// Built-in nominal chains: `denso-vs060`, `ur5e`, `ur10e`.
    pub fn preset(name: &str) -> Option<Self> {
        match name {
            "denso-vs060" => Some(Self::vs060()),
            "ur5e" => Some(Self::from_ur_dh(
                "ur5e",
                [162.5, 0.0, 0.0, 133.3, 99.7, 99.6],
                [0.0, -425.0, -392.2, 0.0, 0.0, 0.0],
            )),
            "ur10e" => Some(Self::from_ur_dh(
                "ur10e",
                [180.7, 0.0, 0.0, 174.15, 119.85, 116.55],
                [0.0, -612.7, -571.55, 0.0, 0.0, 0.0],
            )),
            _ => None,
        }
    }

    /// Names of the presets.
    pub const PRESETS: [&'static str; 3] = ["denso-vs060", "ur5e", "ur10e"];

    fn vs060() -> Self {
        let data: [([f64; 3], [f64; 3], [f64; 2]); 6] = [
            ([0.0, 0.0, 181.5], [0.0, 0.0, 1.0], [-170.0, 170.0]),
            ([0.0, 0.0, 163.5], [0.0, 1.0, 0.0], [-120.0, 120.0]),
            ([0.0, 0.0, 305.0], [0.0, 1.0, 0.0], [-125.0, 155.0]),
            ([-10.0, 0.0, 164.5], [0.0, 0.0, 1.0], [-270.0, 270.0]),
            ([0.0, 0.0, 135.5], [0.0, 1.0, 0.0], [-120.0, 120.0]),
            ([0.0, 0.0, 70.0], [0.0, 0.0, 1.0], [-360.0, 360.0]),
        ];
        let joints = data
            .iter()
            .enumerate()
            .map(|(i, (xyz, axis, lim))| UrdfJoint {
                name: format!("joint_{}", i + 1),
                origin_xyz_mm: Vector3::from(*xyz),
                origin_rpy_rad: Vector3::zeros(),
                axis: Unit::new_normalize(Vector3::from(*axis)),
                limits_rad: (lim[0].to_radians(), lim[1].to_radians()),
            })
            .collect();
        Self {
            model: "denso-vs060".into(),
            joints,
            flange_xyz_mm: Vector3::zeros(),
            flange_rpy_rad: Vector3::zeros(),
        }
    }

    /// UR's standard DH table (`d`, `a` in mm; α = [90°, 0, 0, 90°, −90°, 0]) expressed as a URDF
    /// chain: joint *i*'s origin is `Trans_x(a_{i-1}) · Rot_x(α_{i-1}) · Trans_z(d_i)`.
    fn from_ur_dh(model: &str, d: [f64; 6], a: [f64; 6]) -> Self {
        use std::f64::consts::FRAC_PI_2;
        let alpha = [FRAC_PI_2, 0.0, 0.0, FRAC_PI_2, -FRAC_PI_2, 0.0];
        let lim = 360f64.to_radians();
        let joints = (0..6)
            .map(|i| {
                let (a_prev, al_prev) = if i == 0 {
                    (0.0, 0.0)
                } else {
                    (a[i - 1], alpha[i - 1])
                };
                UrdfJoint {
                    name: format!("joint_{}", i + 1),
                    origin_xyz_mm: Vector3::new(
                        a_prev,
                        -al_prev.sin() * d[i],
                        al_prev.cos() * d[i],
                    ),
                    origin_rpy_rad: Vector3::new(al_prev, 0.0, 0.0),
                    axis: Vector3::z_axis(),
                    limits_rad: (-lim, lim),
                }
            })
            .collect();
        Self {
            model: model.into(),
            joints,
            flange_xyz_mm: Vector3::new(a[5], 0.0, 0.0),
            flange_rpy_rad: Vector3::new(alpha[5], 0.0, 0.0),
        }
    }

    /// Fixed origin transform of joint `i` (0-based), with link lengths scaled by `growth`.
    fn origin(&self, i: usize, growth: f64) -> Isometry3<f64> {
        let j = &self.joints[i];
        fixed_transform(&(j.origin_xyz_mm * growth), &j.origin_rpy_rad)
    }

    /// Flange pose in the base frame for joint angles `theta` (rad).
    pub fn fk(&self, theta: &[f64]) -> Isometry3<f64> {
        self.frames(theta, 1.0, None).flange
    }

    /// Every joint frame and the flange, with link translations scaled by `growth` (thermal
    /// expansion, 1.0 = none) and optional per-joint tilts applied after each joint rotation.
    pub fn frames(&self, theta: &[f64], growth: f64, tilts: Option<&[JointTilt]>) -> ChainFrames {
        let mut t = Isometry3::identity();
        let mut joints = Vec::with_capacity(self.joints.len());
        for (i, j) in self.joints.iter().enumerate() {
            let th = theta.get(i).copied().unwrap_or(0.0);
            t *= self.origin(i, growth);
            t *= UnitQuaternion::from_axis_angle(&j.axis, th);
            if let Some(tl) = tilts.and_then(|v| v.get(i)) {
                t *= UnitQuaternion::from_scaled_axis(*tl);
            }
            joints.push(t);
        }
        let flange = t * fixed_transform(&(self.flange_xyz_mm * growth), &self.flange_rpy_rad);
        ChainFrames { joints, flange }
    }

    /// A copy with seeded random geometric errors: each origin translation component moves by
    /// ±U(origin_mm), each rpy component by ±U(origin_deg) (U = uniform in `[lo, hi]`, random sign).
    pub fn perturbed<R: Rng>(
        &self,
        rng: &mut R,
        origin_mm: [f64; 2],
        origin_deg: [f64; 2],
    ) -> Self {
        let mut c = self.clone();
        for j in &mut c.joints {
            for k in 0..3 {
                j.origin_xyz_mm[k] += signed_uniform(rng, origin_mm);
            }
            for k in 0..3 {
                j.origin_rpy_rad[k] += signed_uniform(rng, origin_deg).to_radians();
            }
        }
        c
    }
}

/// A random value with magnitude uniform in `[range[0], range[1]]` and a random sign.
pub fn signed_uniform<R: Rng>(rng: &mut R, range: [f64; 2]) -> f64 {
    let (lo, hi) = (range[0].min(range[1]), range[0].max(range[1]));
    let m = if hi > lo {
        rng.random_range(lo..=hi)
    } else {
        lo
    };
    if rng.random_bool(0.5) {
        m
    } else {
        -m
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ur5e_q0_matches_published_dh() {
        let c = UrdfChain::preset("ur5e").unwrap();
        let f = c.fk(&[0.0; 6]);
        let p = f.translation.vector;
        assert!(
            (p - Vector3::new(-817.2, -232.9, 62.8)).norm() < 1e-9,
            "{p}"
        );
        let q = f.rotation;
        let want = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::FRAC_PI_2);
        assert!(q.angle_to(&want) < 1e-12);
    }

    #[test]
    fn rpy_is_fixed_axis_xyz() {
        let r = rpy_rotation(&Vector3::new(0.1, 0.2, 0.3));
        let m = r.to_rotation_matrix();
        // URDF: R = Rz(y) Ry(p) Rx(r); check one element: R[2][0] = -sin(p).
        assert!((m[(2, 0)] + 0.2f64.sin()).abs() < 1e-15);
    }
}
