//! Forward kinematics of one pose, computed once: every MDH frame, the flange and the tool
//! of a model at one joint vector, for callers that need several of them at the same pose
//! (the diagnosis' gravity torques and link deflections ask for the frame of their joint
//! and of each mass point, which [`KinematicModel::joint_frame`] would walk the chain for
//! each time). The frames are the same prefix products in the same order as
//! [`KinematicModel::joint_frame`], [`KinematicModel::flange_pose`] and
//! [`KinematicModel::tool_pose_in_base`], so every value is bit-identical to theirs.
use nalgebra::{Isometry3, Rotation3, Vector3};

use super::{pose6, Frame, KinematicModel, ParamGroup};

/// Frames of one model at one joint vector (see the module doc).
#[derive(Debug, Clone)]
pub struct PoseFrames {
    /// MDH frame `k` (0 = frame 0 … `dof`) in the robot base.
    joints: Vec<Isometry3<f64>>,
    /// Flange origin in the robot base (mm).
    flange: Vector3<f64>,
    /// Tool (marker / tip) origin in the robot base (mm).
    tool: Vector3<f64>,
    /// Rotation tracker ← robot base (`base_*`).
    base_rotation: Rotation3<f64>,
}

impl KinematicModel {
    /// Every frame of the model at `q` (missing entries of `q` count as 0), walked once.
    pub fn pose_frames(&self, q: &[f64]) -> PoseFrames {
        let mut t = Frame::from_iso(&self.base_offset);
        let mut joints = Vec::with_capacity(self.dof + 1);
        joints.push(t.to_iso());
        for i in 0..self.dof {
            t = t.mul(&self.joint_local(i, q.get(i).copied().unwrap_or(0.0)));
            joints.push(t.to_iso());
        }
        let flange = t
            .mul(&Frame::from_iso(&self.flange_fixed))
            .mul(&pose6(&self.group_slice(ParamGroup::Flange)));
        let tool = flange.mul(&pose6(&self.group_slice(ParamGroup::Tool)));
        PoseFrames {
            joints,
            flange: flange.p,
            tool: tool.p,
            base_rotation: self.base().rotation.to_rotation_matrix(),
        }
    }
}

impl PoseFrames {
    /// MDH frame `k` (clamped to the last joint frame), as [`KinematicModel::joint_frame`].
    pub fn joint_frame(&self, k: usize) -> &Isometry3<f64> {
        &self.joints[k.min(self.joints.len() - 1)]
    }
    /// Flange origin in the robot base, as [`KinematicModel::flange_pose`]'s translation.
    pub fn flange_origin(&self) -> Vector3<f64> {
        self.flange
    }
    /// Tool origin in the robot base, as [`KinematicModel::tool_pose_in_base`]'s translation.
    pub fn tool_origin(&self) -> Vector3<f64> {
        self.tool
    }
    /// `model.base().rotation.to_rotation_matrix()`.
    pub fn base_rotation(&self) -> &Rotation3<f64> {
        &self.base_rotation
    }
}

/// The bit-identity tests' cases: every preset with each parameter moved off its nominal
/// value, and 20 joint vectors of it spread over ±2.5 rad.
#[cfg(test)]
pub(super) fn test_cases() -> Vec<(&'static str, KinematicModel, Vec<Vec<f64>>)> {
    ["denso-vs060", "ur5e", "ur10e"]
        .into_iter()
        .map(|name| {
            let mut model = KinematicModel::preset(name).unwrap();
            let n = model.dof();
            let mut v = model.param_values();
            for (i, x) in v.iter_mut().enumerate() {
                *x += 1e-3 * ((i * 7 % 11) as f64 - 5.0);
            }
            model.set_param_values(&v);
            let qs = (0..20)
                .map(|s| {
                    (0..n)
                        .map(|i| (0.37 * (s * n + i) as f64).sin() * 2.5)
                        .collect()
                })
                .collect();
            (name, model, qs)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every frame equals the one-at-a-time forward kinematics bit for bit.
    #[test]
    fn pose_frames_are_bit_identical_to_the_one_at_a_time_kinematics() {
        let mut checked = 0;
        for (name, model, qs) in test_cases() {
            let n = model.dof();
            for q in &qs {
                let f = model.pose_frames(q);
                for k in 0..=n + 1 {
                    assert_eq!(
                        *f.joint_frame(k),
                        model.joint_frame(q, k),
                        "{name} frame {k}"
                    );
                }
                assert_eq!(f.flange_origin(), model.flange_pose(q).translation.vector);
                assert_eq!(
                    f.tool_origin(),
                    model.tool_pose_in_base(q).translation.vector
                );
                assert_eq!(
                    *f.base_rotation(),
                    model.base().rotation.to_rotation_matrix()
                );
                checked += 1;
            }
        }
        assert_eq!(checked, 60);
    }
}
