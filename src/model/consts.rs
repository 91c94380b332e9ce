//! The parts of the forward kinematics that do not depend on the joint angles, formed once
//! per model state (`diagnose` speed): every joint's `Rx(α)`, `Ry(β)` and their product, the
//! fixed frames and the base, flange and tool transforms with the rotations their
//! roll-pitch-yaw axes need. A caller evaluating one model at many poses (the diagnosis'
//! Jacobian, a few thousand poses per model state) computes them once instead of per pose
//! (about 50 of the 60 `sin_cos` of a point's parameter Jacobian). Every product is the same
//! one in the same order as the per-pose code, so every value is bit-identical.
use nalgebra::{Matrix3, Matrix3xX, Point3, Vector3};

use super::{
    pose6, rot_x, rot_y, rot_z, Frame, KinematicModel, ParamGroup, J_A, J_ALPHA, J_BETA, J_D, J_PHI,
};

struct JointConsts {
    phi: f64,
    d: f64,
    a: f64,
    rx: Matrix3<f64>,
    ry: Matrix3<f64>,
    /// `Rx(α)·Ry(β)` (the joint's local rotation before `Rz(q + φ)`).
    rxy: Matrix3<f64>,
}

/// The angle-independent kinematics of one model state (see the module doc).
pub struct ModelConsts {
    joints: Vec<JointConsts>,
    base_offset: Frame,
    flange_fixed: Frame,
    base6: Frame,
    /// `rpy_axes(I, base)`.
    base_axes: [Vector3<f64>; 3],
    /// Flange, tool.
    groups: [GroupConsts; 2],
}

/// A pose group (flange or tool): its values, its frame and the `Rz(rz)`, `Ry(ry)` its
/// roll-pitch-yaw axes need.
struct GroupConsts {
    v: [f64; 6],
    frame: Frame,
    rz: Matrix3<f64>,
    ry: Matrix3<f64>,
}

impl KinematicModel {
    /// The angle-independent kinematics of this model state.
    pub fn consts(&self) -> ModelConsts {
        let p = &self.params;
        let joints = (0..self.dof)
            .map(|i| {
                let o = 5 * i;
                let (al, be) = (p[o + J_ALPHA].value, p[o + J_BETA].value);
                let (rx, ry) = (rot_x(al), rot_y(be));
                JointConsts {
                    phi: p[o + J_PHI].value,
                    d: p[o + J_D].value,
                    a: p[o + J_A].value,
                    rx,
                    ry,
                    rxy: rx * ry,
                }
            })
            .collect();
        let base = self.group_slice(ParamGroup::Base);
        let group = |g: ParamGroup| {
            let v = self.group_slice(g);
            GroupConsts {
                v,
                frame: pose6(&v),
                rz: rot_z(v[5]),
                ry: rot_y(v[4]),
            }
        };
        ModelConsts {
            joints,
            base_offset: Frame::from_iso(&self.base_offset),
            flange_fixed: Frame::from_iso(&self.flange_fixed),
            base6: pose6(&base),
            base_axes: super::rpy_axes(&Matrix3::identity(), &base),
            groups: [group(ParamGroup::Flange), group(ParamGroup::Tool)],
        }
    }

    /// `Rz(q_i + φ_i)` of every joint (missing entries of `q` count as 0).
    fn joint_rz(&self, c: &ModelConsts, q: &[f64]) -> Vec<Matrix3<f64>> {
        c.joints
            .iter()
            .enumerate()
            .map(|(i, j)| rot_z(q.get(i).copied().unwrap_or(0.0) + j.phi))
            .collect()
    }

    /// [`KinematicModel::measured_point`] from the constants and the joints' `Rz`.
    fn measured_point_with(&self, c: &ModelConsts, rz: &[Matrix3<f64>]) -> Point3<f64> {
        let mut t = c.base_offset;
        for (j, rz) in c.joints.iter().zip(rz) {
            let r = j.rxy * rz;
            t = t.mul(&Frame {
                p: Vector3::new(j.a, 0.0, 0.0) + r.column(2) * j.d,
                r,
            });
        }
        let f = c.base6.mul(&t.mul(&c.flange_fixed).mul(&c.groups[0].frame));
        let tool = &c.groups[1].v;
        Point3::from(f.p + f.r * Vector3::new(tool[0], tool[1], tool[2]))
    }

    /// [`KinematicModel::point_param_jacobian_into`] with the constants `c` of this model
    /// state (the same values).
    pub fn point_param_jacobian_with(
        &self,
        c: &ModelConsts,
        q: &[f64],
        out: &mut Matrix3xX<f64>,
    ) -> Option<Point3<f64>> {
        if out.ncols() != self.params.len() {
            return None;
        }
        let rz = self.joint_rz(c, q);
        let p = self.measured_point_with(c, &rz).coords;
        self.param_walk_with(c, &rz, |k, axis, cen, rot| {
            let col = if rot { axis.cross(&(p - cen)) } else { axis };
            out.fixed_view_mut::<3, 1>(0, k).copy_from(&col);
        });
        Some(Point3::from(p))
    }

    /// [`KinematicModel::param_walk`] at the angles whose joint rotations are `rz`.
    fn param_walk_with<F: FnMut(usize, Vector3<f64>, Vector3<f64>, bool)>(
        &self,
        c: &ModelConsts,
        rz: &[Matrix3<f64>],
        mut f: F,
    ) -> Frame {
        let b = c.base6;
        let ob = self.off_base();
        let eye = Matrix3::identity();
        for (k, ax) in c.base_axes.iter().enumerate() {
            f(ob + k, eye.column(k).into_owned(), b.p, false);
            f(ob + 3 + k, *ax, b.p, true);
        }
        let mut t = b.mul(&c.base_offset);
        for (i, (j, rz)) in c.joints.iter().zip(rz).enumerate() {
            let o = 5 * i;
            let x = t.r.column(0).into_owned();
            f(o + J_ALPHA, x, t.p, true);
            let r1 = t.r * j.rx;
            let p1 = t.p + x * j.a;
            f(o + J_A, x, t.p, false);
            f(o + J_BETA, r1.column(1).into_owned(), p1, true);
            let r2 = r1 * j.ry;
            let z = r2.column(2).into_owned();
            f(o + J_PHI, z, p1, true);
            f(o + J_D, z, p1, false);
            t = Frame {
                r: r2 * rz,
                p: p1 + z * j.d,
            };
        }
        t = t.mul(&c.flange_fixed);
        for (g, off) in c.groups.iter().zip([self.off_flange(), self.off_tool()]) {
            let ax = super::rpy_axes_with(&t.r, &g.rz, &g.ry);
            for k in 0..3 {
                f(off + k, t.r.column(k).into_owned(), t.p, false);
            }
            t = t.mul(&g.frame);
            for (k, a) in ax.iter().enumerate() {
                f(off + 3 + k, *a, t.p, true);
            }
        }
        t
    }
}

#[cfg(test)]
mod tests {
    /// The Jacobian and point from the constants equal the per-pose ones bit for bit.
    #[test]
    fn constants_give_the_same_jacobian_bit_for_bit() {
        use super::*;
        let mut checked = 0;
        for (name, model, qs) in super::super::frames::test_cases() {
            let c = model.consts();
            for q in &qs {
                let (p0, j0) = model.point_param_jacobian(q);
                let mut j1 = Matrix3xX::zeros(model.params().len());
                let p1 = model.point_param_jacobian_with(&c, q, &mut j1).unwrap();
                assert_eq!(p1, p0, "{name}");
                assert_eq!(p1, model.measured_point(q), "{name}");
                assert_eq!(j1, j0, "{name}");
                checked += 1;
            }
        }
        assert_eq!(checked, 60);
    }
}
