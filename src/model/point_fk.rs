//! The marker point of many poses at one parameter vector (speed: the bootstrap's
//! exactness check evaluates 200 poses for each of 10,000 subsets).
//!
//! [`KinematicModel::measured_point`] rebuilds every rotation of the chain from its angles
//! (24 `sin_cos` per pose). Here everything that depends on the parameters alone is done
//! once ([`KinematicModel::point_fk`]): `Rx(α)·Ry(β)` and the joint origin of each joint, the
//! base, and the marker point in the last MDH frame; the pose's joint angles enter through
//! their precomputed sines and cosines ([`JointTrig`]) and `θ = q + φ` by the angle-sum
//! identities. The point is then accumulated from the marker back to the base as a vector,
//! `v ← pᵢ + Rx(αᵢ)Ry(βᵢ)Rz(θᵢ)·v`, with no matrix product. Same result as
//! `measured_point` to rounding (tested below).
use nalgebra::{Matrix3, Point3, Vector3};

use super::{
    pose6, rot_x, rot_y, Frame, KinematicModel, ParamGroup, J_A, J_ALPHA, J_BETA, J_D, J_PHI,
};

/// `(sin q, cos q)` of every joint of one pose (missing entries count as 0, as in
/// [`KinematicModel::measured_point`]).
pub type JointTrig = Vec<(f64, f64)>;

/// The sines and cosines of `q` for a model with `dof` joints.
pub fn joint_trig(q: &[f64], dof: usize) -> JointTrig {
    (0..dof)
        .map(|i| q.get(i).copied().unwrap_or(0.0).sin_cos())
        .collect()
}

#[derive(Debug, Clone)]
struct JointConst {
    /// `Rx(α)·Ry(β)`.
    rxy: Matrix3<f64>,
    /// Joint frame origin in the previous frame: `(a, 0, 0) + Rx(α)Ry(β)·(0, 0, d)`.
    p: Vector3<f64>,
    sin_phi: f64,
    cos_phi: f64,
}

/// Marker-point forward kinematics at fixed parameters (see the module docs).
#[derive(Debug, Clone)]
pub struct PointFk {
    /// Base and base offset: rotation and origin of MDH frame 0 in the tracker frame.
    start_r: Matrix3<f64>,
    start_p: Vector3<f64>,
    joints: Vec<JointConst>,
    /// Marker origin in the last MDH frame.
    tool_in_last: Vector3<f64>,
}

impl KinematicModel {
    /// The parameter-dependent part of [`Self::measured_point`], computed once.
    pub fn point_fk(&self) -> PointFk {
        let start =
            pose6(&self.group_slice(ParamGroup::Base)).mul(&Frame::from_iso(&self.base_offset));
        let joints = (0..self.dof)
            .map(|i| {
                let v = |k: usize| self.params[5 * i + k].value;
                let rxy = rot_x(v(J_ALPHA)) * rot_y(v(J_BETA));
                let (sin_phi, cos_phi) = v(J_PHI).sin_cos();
                JointConst {
                    p: Vector3::new(v(J_A), 0.0, 0.0) + rxy.column(2) * v(J_D),
                    rxy,
                    sin_phi,
                    cos_phi,
                }
            })
            .collect();
        let tail =
            Frame::from_iso(&self.flange_fixed).mul(&pose6(&self.group_slice(ParamGroup::Flange)));
        let t = self.group_slice(ParamGroup::Tool);
        PointFk {
            start_r: start.r,
            start_p: start.p,
            joints,
            tool_in_last: tail.p + tail.r * Vector3::new(t[0], t[1], t[2]),
        }
    }
}

impl PointFk {
    /// Marker origin in the tracker frame for the pose whose joint sines and cosines are
    /// `trig` (from [`joint_trig`] with the model's `dof`).
    pub fn point(&self, trig: &[(f64, f64)]) -> Point3<f64> {
        let mut v = self.tool_in_last;
        for (j, &(sq, cq)) in self.joints.iter().zip(trig).rev() {
            // θ = q + φ
            let s = sq * j.cos_phi + cq * j.sin_phi;
            let c = cq * j.cos_phi - sq * j.sin_phi;
            let rz_v = Vector3::new(c * v.x - s * v.y, s * v.x + c * v.y, v.z);
            v = j.p + j.rxy * rz_v;
        }
        Point3::from(self.start_p + self.start_r * v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn point_fk_equals_measured_point() {
        let mut m = KinematicModel::preset("denso-vs060").unwrap();
        // Every parameter off its nominal value, so no term can hide behind a zero.
        let mut vals = m.param_values();
        for (k, v) in vals.iter_mut().enumerate() {
            *v += 1e-3 * (k as f64 + 1.0).sin() * if k % 2 == 0 { 1.0 } else { 50.0 };
        }
        m.set_param_values(&vals);
        let fk = m.point_fk();
        for s in 0..50 {
            let q: Vec<f64> = (0..m.dof())
                .map(|i| ((s * 7 + i * 3) as f64 * 0.37).sin() * 2.5)
                .collect();
            let a = m.measured_point(&q);
            let b = fk.point(&joint_trig(&q, m.dof()));
            assert!((a - b).norm() < 1e-9, "{a} vs {b}");
        }
        // A short q counts its missing joints as 0, as measured_point does.
        let q = [0.3, -0.2];
        let d = m.measured_point(&q) - fk.point(&joint_trig(&q, m.dof()));
        assert!(d.norm() < 1e-9);
    }
}
