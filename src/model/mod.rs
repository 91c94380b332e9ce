//! Kinematic model of a serial robot: modified DH (Craig) with the Hayati β parameter for
//! nearly parallel consecutive axes (seed 001: per joint φ, d, a, α, β), plus the robot base
//! pose in the measuring device (tracker) frame and the tool (marker / tip) in the flange.
//!
//! **Units inside: millimetres and radians.** Calibration files use mm and degrees; the
//! conversion happens in [`KinematicModel::to_cal_params`] / [`KinematicModel::apply_cal_params`].
//!
//! Joint *i* (1-based) is the transform from MDH frame *i−1* to MDH frame *i*:
//! `A_i(q_i) = Rx(α_i) · Tx(a_i) · Ry(β_i) · Rz(q_i + φ_i) · Tz(d_i)`
//! (Craig's `α_{i−1}, a_{i−1}` carry the index of the joint that follows them). The flange
//! in the robot base is `base_offset · A_1 ⋯ A_n · F₀ · F` where `base_offset` is a fixed
//! transform (robot base → MDH frame 0, the identity for the presets), `F₀` the fixed
//! residual of the conversion (last MDH frame → flange) and `F` a correction on top of it
//! (parameters `flange_*`, zero and fixed by default). What a tracker measures is
//! `B · flange · T` with `B` the robot base in the tracker frame (`base_*`) and `T` the
//! tool/marker in the flange frame (`tool_*`). Rotations of `B`, `F`, `T` are URDF
//! roll-pitch-yaw: `R = Rz(rz)·Ry(ry)·Rx(rx)`.
//!
//! The derivation of the exact chain → MDH + Hayati conversion is in `src/model/notes/conversion.md`.
use nalgebra::{
    DVector, Isometry3, Matrix3, Matrix3xX, Matrix6xX, Point3, Rotation3, Translation3,
    UnitQuaternion, Vector3,
};
use serde_json::Map;

use crate::dataset::{CalParam, ChainJoint, FixedOrigin, RobotBlock};

pub mod chain;
mod consts;
pub mod error;
mod frames;
pub mod ik;
pub mod point_fk;
pub mod presets;
pub use consts::ModelConsts;
pub use frames::PoseFrames;

pub use chain::{origin_iso, ChainSpecJoint, SerialChain};
pub use error::{IkError, ModelError};
pub use ik::{BranchLabel, Elbow, IkFamily, IkSolution, Shoulder, Wrist};

/// Consecutive axes closer to parallel than this angle use the Hayati β (5°).
pub const PARALLEL_ANGLE_RAD: f64 = 5.0 * std::f64::consts::PI / 180.0;

/// Internal unit of a parameter value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Unit {
    /// Millimetres (files: `mm`).
    Mm,
    /// Radians (files: `deg`).
    Rad,
}

/// Which part of the model a parameter belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ParamGroup {
    /// Joint *i*, 1-based.
    Joint(usize),
    /// Robot base pose in the tracker frame.
    Base,
    /// Marker / tip in the flange frame.
    Tool,
    /// Correction of the last-MDH-frame → flange transform (zero, fixed by default).
    Flange,
}

/// One model parameter (value in internal units: mm or rad).
#[derive(Debug, Clone, PartialEq)]
pub struct Param {
    pub name: String,
    pub unit: Unit,
    pub value: f64,
    pub free: bool,
    pub group: ParamGroup,
}

/// Parameter slots of one joint, in `params()` order.
pub const JOINT_PARAM_NAMES: [&str; 5] = ["phi", "d", "a", "alpha", "beta"];
const J_PHI: usize = 0;
const J_D: usize = 1;
const J_A: usize = 2;
const J_ALPHA: usize = 3;
const J_BETA: usize = 4;
/// Suffixes of a 6-parameter pose group (`base_x`, … `tool_rz`, `flange_rz`).
pub const POSE_PARAM_SUFFIXES: [&str; 6] = ["x", "y", "z", "rx", "ry", "rz"];

/// MDH(Craig) + Hayati kinematic model with base, flange and tool transforms.
#[derive(Debug, Clone, PartialEq)]
pub struct KinematicModel {
    name: String,
    dof: usize,
    params: Vec<Param>,
    /// Fixed: robot base → MDH frame 0.
    base_offset: Isometry3<f64>,
    /// Fixed: last MDH frame → flange, before the `flange_*` parameters (which are a
    /// correction on top of it, zero after conversion). Kept as an isometry so that the
    /// conversion stays exact (no roll-pitch-yaw round trip near gimbal lock).
    flange_fixed: Isometry3<f64>,
    limits: Vec<(f64, f64)>,
    joint_names: Vec<String>,
    /// `hayati[i]`: joint i+1 uses β (its axis is nearly parallel to the previous one).
    hayati: Vec<bool>,
    ik_family: Option<IkFamily>,
}

/// Rotation of a pose group from its three rpy values (rad).
fn rpy_rot(rx: f64, ry: f64, rz: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_euler_angles(rx, ry, rz)
}

/// A frame as rotation matrix + origin (faster than quaternions in the Jacobian pass).
#[derive(Clone, Copy)]
struct Frame {
    r: Matrix3<f64>,
    p: Vector3<f64>,
}

impl Frame {
    fn from_iso(t: &Isometry3<f64>) -> Self {
        Frame {
            r: *t.rotation.to_rotation_matrix().matrix(),
            p: t.translation.vector,
        }
    }
    fn to_iso(self) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(self.p),
            UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(self.r)),
        )
    }
    fn mul(&self, o: &Frame) -> Frame {
        Frame {
            r: self.r * o.r,
            p: self.p + self.r * o.p,
        }
    }
}

#[inline]
fn rot_x(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c)
}
#[inline]
fn rot_y(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c)
}
#[inline]
fn rot_z(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
}

/// `Trans(x,y,z)·Rz·Ry·Rx` from 6 values (mm, rad).
fn pose6(v: &[f64]) -> Frame {
    Frame {
        r: rot_z(v[5]) * rot_y(v[4]) * rot_x(v[3]),
        p: Vector3::new(v[0], v[1], v[2]),
    }
}

/// World axes of the three rpy rotations of a pose group whose parent frame has rotation `rp`:
/// `R = rp·Rz·Ry·Rx`, d/drx about `rp·Rz·Ry·x`, d/dry about `rp·Rz·y`, d/drz about `rp·z`.
fn rpy_axes(rp: &Matrix3<f64>, v: &[f64]) -> [Vector3<f64>; 3] {
    rpy_axes_with(rp, &rot_z(v[5]), &rot_y(v[4]))
}

/// [`rpy_axes`] with `Rz(rz)` and `Ry(ry)` of the group given.
fn rpy_axes_with(rp: &Matrix3<f64>, rz: &Matrix3<f64>, ry: &Matrix3<f64>) -> [Vector3<f64>; 3] {
    let rz = rp * rz;
    let ry = rz * ry;
    [
        ry.column(0).into_owned(),
        rz.column(1).into_owned(),
        rp.column(2).into_owned(),
    ]
}

impl KinematicModel {
    // ------------------------------------------------------------------ construction

    /// Exact conversion of a URDF-style chain (dataset header, mm / degrees) to MDH + Hayati.
    pub fn from_chain(
        chain: &[ChainJoint],
        flange: Option<&FixedOrigin>,
    ) -> Result<Self, ModelError> {
        let sc = SerialChain::from_chain_joints(chain, flange)?;
        Self::from_serial_chain(&sc, "chain")
    }

    /// The header's robot block: its chain when present, otherwise the preset named by `model`.
    pub fn from_robot_block(robot: &RobotBlock) -> Result<Self, ModelError> {
        match &robot.chain {
            Some(c) => {
                let mut m = Self::from_chain(c, robot.flange.as_ref())?;
                m.name = robot.model.clone();
                Ok(m)
            }
            None => Self::preset(&robot.model),
        }
    }

    /// A built-in preset: `denso-vs060`, `ur5e`, `ur10e`.
    pub fn preset(name: &str) -> Result<Self, ModelError> {
        presets::preset(name)
    }

    /// Parse a URDF (metres, radians) and convert its revolute chain (see
    /// [`SerialChain::from_urdf_str`]).
    pub fn from_urdf_str(
        xml: &str,
        base_link: Option<&str>,
        tip_link: Option<&str>,
    ) -> Result<Self, ModelError> {
        let sc = SerialChain::from_urdf_str(xml, base_link, tip_link)?;
        Self::from_serial_chain(&sc, "urdf")
    }

    /// Exact conversion of a [`SerialChain`] (mm / rad) to MDH + Hayati.
    pub fn from_serial_chain(sc: &SerialChain, name: &str) -> Result<Self, ModelError> {
        let n = sc.dof();
        if n == 0 {
            return Err(ModelError::EmptyChain);
        }
        // Joint axis lines at q = 0 in the robot base; line 0 is the base z axis.
        let mut pts = vec![Vector3::zeros(); n + 1];
        let mut dirs = vec![Vector3::z(); n + 1];
        let mut c = Isometry3::identity();
        let mut chain_frames = Vec::with_capacity(n);
        for (i, j) in sc.joints.iter().enumerate() {
            c *= j.origin;
            pts[i + 1] = c.translation.vector;
            dirs[i + 1] = c.rotation * j.axis.into_inner();
            chain_frames.push(c);
        }
        let sin_par = PARALLEL_ANGLE_RAD.sin();
        let mut hayati = vec![false; n + 1]; // index = joint number (1-based), [0] unused
        let mut hit = vec![Vector3::zeros(); n + 1];
        let mut frames: Vec<Frame> = Vec::with_capacity(n + 1);
        let mut jp = vec![[0.0f64; 5]; n + 1]; // [phi, d, a, alpha, beta] per joint (1-based)

        // Computes α_i, β_i of joint i from frame i-1 (already set) and axis i.
        let alpha_beta = |f: &Frame, z: &Vector3<f64>, hay: bool| -> (f64, f64) {
            let dir = f.r.transpose() * z;
            let beta = if hay {
                dir.x.clamp(-1.0, 1.0).asin()
            } else {
                0.0
            };
            let alpha = (-dir.y).atan2(dir.z);
            (alpha, beta)
        };
        let perp = |x: Vector3<f64>, z: &Vector3<f64>| -> Option<Vector3<f64>> {
            let v = x - z * x.dot(z);
            let nv = v.norm();
            (nv > 1e-12).then(|| v / nv)
        };
        for i in 0..=n {
            let zi = dirs[i];
            // Default x: the one that makes φ_i = 0 (for i ≥ 1), or base x for frame 0.
            let x_default = if i == 0 {
                perp(Vector3::x(), &zi).unwrap_or_else(|| perp(Vector3::y(), &zi).unwrap())
            } else {
                let f = &frames[i - 1];
                let (al, be) = alpha_beta(f, &zi, hayati[i]);
                let xd = f.r * rot_x(al) * rot_y(be) * Vector3::x();
                perp(xd, &zi).unwrap_or_else(|| {
                    perp(Vector3::x(), &zi).unwrap_or_else(|| perp(Vector3::y(), &zi).unwrap())
                })
            };
            let (origin, x) = if i == n {
                (hit[n], x_default)
            } else {
                let zj = dirs[i + 1];
                let pj = pts[i + 1];
                let cross = zi.cross(&zj);
                let s = cross.norm();
                let (o, q) = if s < sin_par {
                    // Hayati: origin where x_{i-1} hits axis i (d_i = 0); x_i towards the
                    // point where the plane ⟂ z_i through the origin cuts axis i+1.
                    hayati[i + 1] = true;
                    let o = if i == 0 { Vector3::zeros() } else { hit[i] };
                    let t = (o - pj).dot(&zi) / zj.dot(&zi);
                    (o, pj + zj * t)
                } else {
                    // Common normal between the two lines.
                    let w0 = pts[i] - pj;
                    let b = zi.dot(&zj);
                    let d = zi.dot(&w0);
                    let e = zj.dot(&w0);
                    let den = 1.0 - b * b;
                    let sp = (b * e - d) / den;
                    let tq = (e - b * d) / den;
                    (pts[i] + zi * sp, pj + zj * tq)
                };
                let v = q - o;
                let x = if s >= sin_par {
                    // the common normal is exactly ±(z_i × z_{i+1}): take its direction from
                    // the cross product (precise even when the normal is short), the sign
                    // and length from v.
                    let c = perp(cross / s, &zi).unwrap_or(x_default);
                    if v.dot(&c) < 0.0 {
                        -c
                    } else {
                        c
                    }
                } else if v.norm() > 1e-9 {
                    perp(v, &zi).unwrap_or(x_default)
                } else {
                    x_default
                };
                // the point of axis i+1 on the x_i line (= q up to rounding)
                hit[i + 1] = o + x * v.dot(&x);
                (o, x)
            };
            let y = zi.cross(&x);
            let r = Matrix3::from_columns(&[x, y, zi]);
            if i >= 1 {
                let f = &frames[i - 1];
                let (al, be) = alpha_beta(f, &zi, hayati[i]);
                let a = (hit[i] - f.p).dot(&f.r.column(0));
                let xp = f.r * rot_x(al) * rot_y(be) * Vector3::x();
                let xi = r.column(0).into_owned();
                let phi = xp.cross(&xi).dot(&zi).atan2(xp.dot(&xi));
                let d = (origin - hit[i]).dot(&zi);
                jp[i] = [phi, d, a, al, be];
            }
            frames.push(Frame { r, p: origin });
        }
        let base_offset = frames[0].to_iso();
        let mut params = Vec::with_capacity(5 * n + 18);
        for i in 1..=n {
            for (k, nm) in JOINT_PARAM_NAMES.iter().enumerate() {
                let unit = if k == J_D || k == J_A {
                    Unit::Mm
                } else {
                    Unit::Rad
                };
                let free = match k {
                    J_BETA => hayati[i],
                    // d_i is replaced by β_{i+1} when axes i, i+1 are nearly parallel
                    J_D => !(i < n && hayati[i + 1]),
                    _ => true,
                };
                params.push(Param {
                    name: format!("{nm}{i}"),
                    unit,
                    value: jp[i][k],
                    free,
                    group: ParamGroup::Joint(i),
                });
            }
        }
        for (g, prefix) in [
            (ParamGroup::Base, "base"),
            (ParamGroup::Tool, "tool"),
            (ParamGroup::Flange, "flange"),
        ] {
            for (k, sfx) in POSE_PARAM_SUFFIXES.iter().enumerate() {
                let free = match g {
                    ParamGroup::Base => true,
                    ParamGroup::Tool => k < 3,
                    _ => false,
                };
                params.push(Param {
                    name: format!("{prefix}_{sfx}"),
                    unit: if k < 3 { Unit::Mm } else { Unit::Rad },
                    value: 0.0,
                    free,
                    group: g,
                });
            }
        }
        let limits = sc
            .joints
            .iter()
            .map(|j| {
                j.limits
                    .unwrap_or((-std::f64::consts::TAU, std::f64::consts::TAU))
            })
            .collect();
        let mut m = KinematicModel {
            name: name.to_string(),
            dof: n,
            params,
            base_offset,
            flange_fixed: Isometry3::identity(),
            limits,
            joint_names: sc.joints.iter().map(|j| j.name.clone()).collect(),
            hayati: hayati[1..].to_vec(),
            ik_family: None,
        };
        // Flange residual so that the model equals the chain exactly at q = 0 (and hence
        // everywhere, the joint axes being the same lines).
        let m0 = m.last_frame(&vec![0.0; n]).to_iso();
        let chain0 = chain_frames[n - 1] * sc.flange;
        m.flange_fixed = m0.inverse() * chain0;
        m.ik_family = IkFamily::detect(&m);
        Ok(m)
    }

    // ------------------------------------------------------------------ accessors

    /// Model name (preset name or the header's `model`).
    pub fn name(&self) -> &str {
        &self.name
    }
    /// Set the model name.
    pub fn set_name(&mut self, name: &str) {
        self.name = name.to_string();
    }
    /// Number of joints.
    pub fn dof(&self) -> usize {
        self.dof
    }
    /// Joint limits (rad).
    pub fn joint_limits(&self) -> Vec<(f64, f64)> {
        self.limits.clone()
    }
    /// Replace the joint limits (rad).
    pub fn set_joint_limits(&mut self, limits: &[(f64, f64)]) -> Result<(), ModelError> {
        if limits.len() != self.dof {
            return Err(ModelError::LengthMismatch {
                expected: self.dof,
                got: limits.len(),
            });
        }
        self.limits = limits.to_vec();
        Ok(())
    }
    /// Joint names from the chain.
    pub fn joint_names(&self) -> &[String] {
        &self.joint_names
    }
    /// Whether joint i (1-based) uses the Hayati β.
    pub fn uses_beta(&self, joint: usize) -> bool {
        joint >= 1 && self.hayati.get(joint - 1).copied().unwrap_or(false)
    }
    /// Fixed transform robot base → MDH frame 0.
    pub fn base_offset(&self) -> &Isometry3<f64> {
        &self.base_offset
    }
    /// The closed-form IK family detected for this geometry, if any.
    pub fn ik_family(&self) -> Option<&IkFamily> {
        self.ik_family.as_ref()
    }
    /// Override the closed-form IK family (None disables closed-form IK).
    pub fn set_ik_family(&mut self, f: Option<IkFamily>) {
        self.ik_family = f;
    }

    /// All parameters in the fixed order: joints 1..n × (φ, d, a, α, β), then
    /// `base_x..base_rz`, `tool_x..tool_rz`, `flange_x..flange_rz`.
    pub fn params(&self) -> &[Param] {
        &self.params
    }
    /// Parameter values (mm / rad) in `params()` order.
    pub fn param_values(&self) -> DVector<f64> {
        DVector::from_iterator(self.params.len(), self.params.iter().map(|p| p.value))
    }
    /// Set all parameter values (mm / rad, `params()` order). A vector of the wrong length
    /// sets only the common prefix (use [`Self::try_set_param_values`] to get an error).
    pub fn set_param_values(&mut self, v: &DVector<f64>) {
        for (p, x) in self.params.iter_mut().zip(v.iter()) {
            p.value = *x;
        }
    }
    /// Like [`Self::set_param_values`] but checks length and finiteness.
    pub fn try_set_param_values(&mut self, v: &DVector<f64>) -> Result<(), ModelError> {
        if v.len() != self.params.len() {
            return Err(ModelError::LengthMismatch {
                expected: self.params.len(),
                got: v.len(),
            });
        }
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            return Err(ModelError::NonFinite {
                name: self.params[i].name.clone(),
            });
        }
        self.set_param_values(v);
        Ok(())
    }
    /// Values of the free parameters only (in `params()` order).
    pub fn free_values(&self) -> DVector<f64> {
        DVector::from_iterator(
            self.free_count(),
            self.params.iter().filter(|p| p.free).map(|p| p.value),
        )
    }
    /// Set the free parameters (in `params()` order) from a vector of `free_count()` values.
    pub fn set_free_values(&mut self, v: &DVector<f64>) {
        for (p, x) in self.params.iter_mut().filter(|p| p.free).zip(v.iter()) {
            p.value = *x;
        }
    }
    /// Indices (into `params()`) of the free parameters.
    pub fn free_indices(&self) -> Vec<usize> {
        (0..self.params.len())
            .filter(|&i| self.params[i].free)
            .collect()
    }
    /// Number of free parameters.
    pub fn free_count(&self) -> usize {
        self.params.iter().filter(|p| p.free).count()
    }
    /// Mark a parameter free or fixed.
    pub fn set_free(&mut self, name: &str, free: bool) -> Result<(), ModelError> {
        let i = self
            .param_index(name)
            .ok_or_else(|| ModelError::UnknownParam {
                name: name.to_string(),
            })?;
        self.params[i].free = free;
        Ok(())
    }
    /// Every parameter's name and free flag (in `params()` order), to put back with
    /// [`Self::set_free_flags`] after a fit that frees another subset.
    pub fn free_flags(&self) -> Vec<(String, bool)> {
        self.params
            .iter()
            .map(|p| (p.name.clone(), p.free))
            .collect()
    }
    /// Mark each named parameter free or fixed (the list [`Self::free_flags`] returns).
    pub fn set_free_flags(&mut self, flags: &[(String, bool)]) -> Result<(), ModelError> {
        for (n, f) in flags {
            self.set_free(n, *f)?;
        }
        Ok(())
    }
    /// Index of a parameter by name.
    pub fn param_index(&self, name: &str) -> Option<usize> {
        self.params.iter().position(|p| p.name == name)
    }
    /// Value (mm / rad) of a parameter by name.
    pub fn param(&self, name: &str) -> Option<f64> {
        self.param_index(name).map(|i| self.params[i].value)
    }
    /// Set one parameter value (mm / rad).
    pub fn set_param(&mut self, name: &str, value: f64) -> Result<(), ModelError> {
        if !value.is_finite() {
            return Err(ModelError::NonFinite { name: name.into() });
        }
        let i = self
            .param_index(name)
            .ok_or_else(|| ModelError::UnknownParam {
                name: name.to_string(),
            })?;
        self.params[i].value = value;
        Ok(())
    }

    /// Fix the parameters that a point measurement with free base (6) and tool position (3)
    /// cannot separate: all of joint 1 (absorbed by the base), `phi{n}` and `d{n}` (absorbed
    /// by the tool position). Leaves a set whose identification Jacobian is generically of
    /// full rank for a 6R arm observed at well-spread poses.
    pub fn fix_point_redundancies(&mut self) {
        let n = self.dof;
        for p in &mut self.params {
            match p.group {
                ParamGroup::Joint(1) => p.free = false,
                ParamGroup::Joint(j)
                    if j == n && (p.name.starts_with("phi") || p.name.starts_with("d")) =>
                {
                    p.free = false
                }
                _ => {}
            }
        }
    }

    fn off_base(&self) -> usize {
        5 * self.dof
    }
    fn off_tool(&self) -> usize {
        5 * self.dof + 6
    }
    fn off_flange(&self) -> usize {
        5 * self.dof + 12
    }
    fn group_slice(&self, g: ParamGroup) -> [f64; 6] {
        let o = match g {
            ParamGroup::Base => self.off_base(),
            ParamGroup::Tool => self.off_tool(),
            _ => self.off_flange(),
        };
        let mut v = [0.0; 6];
        for (k, x) in v.iter_mut().enumerate() {
            *x = self.params[o + k].value;
        }
        v
    }
    /// Set a pose group (`Base`, `Tool`, `Flange`) from an isometry.
    pub fn set_pose_group(&mut self, g: ParamGroup, iso: &Isometry3<f64>) {
        let o = match g {
            ParamGroup::Base => self.off_base(),
            ParamGroup::Tool => self.off_tool(),
            ParamGroup::Flange => self.off_flange(),
            ParamGroup::Joint(_) => return,
        };
        let (rx, ry, rz) = iso.rotation.euler_angles();
        let t = iso.translation.vector;
        for (k, x) in [t.x, t.y, t.z, rx, ry, rz].into_iter().enumerate() {
            self.params[o + k].value = x;
        }
    }
    /// A pose group as an isometry.
    pub fn pose_group(&self, g: ParamGroup) -> Isometry3<f64> {
        let v = self.group_slice(g);
        Isometry3::from_parts(
            Translation3::new(v[0], v[1], v[2]),
            rpy_rot(v[3], v[4], v[5]),
        )
    }
    /// Robot base pose in the tracker frame (`base_*`).
    pub fn base(&self) -> Isometry3<f64> {
        self.pose_group(ParamGroup::Base)
    }
    /// Tool (marker / tip) pose in the flange frame (`tool_*`).
    pub fn tool(&self) -> Isometry3<f64> {
        self.pose_group(ParamGroup::Tool)
    }
    /// Set the robot base pose in the tracker frame.
    pub fn set_base(&mut self, iso: &Isometry3<f64>) {
        self.set_pose_group(ParamGroup::Base, iso);
    }
    /// Set the tool pose in the flange frame.
    pub fn set_tool(&mut self, iso: &Isometry3<f64>) {
        self.set_pose_group(ParamGroup::Tool, iso);
    }

    // ------------------------------------------------------------------ forward kinematics

    #[inline]
    fn joint_local(&self, i: usize, q: f64) -> Frame {
        let o = 5 * i;
        let p = &self.params;
        let (phi, d, a, al, be) = (
            p[o + J_PHI].value,
            p[o + J_D].value,
            p[o + J_A].value,
            p[o + J_ALPHA].value,
            p[o + J_BETA].value,
        );
        let r = rot_x(al) * rot_y(be) * rot_z(q + phi);
        Frame {
            p: Vector3::new(a, 0.0, 0.0) + r.column(2) * d,
            r,
        }
    }

    /// Last MDH frame (before the flange transform) in the robot base.
    fn last_frame(&self, q: &[f64]) -> Frame {
        let mut t = Frame::from_iso(&self.base_offset);
        for i in 0..self.dof {
            t = t.mul(&self.joint_local(i, q.get(i).copied().unwrap_or(0.0)));
        }
        t
    }

    fn flange_frame(&self, q: &[f64]) -> Frame {
        self.last_frame(q)
            .mul(&Frame::from_iso(&self.flange_fixed))
            .mul(&pose6(&self.group_slice(ParamGroup::Flange)))
    }

    /// Full last-MDH-frame → flange transform: the fixed conversion residual followed by
    /// the `flange_*` correction.
    pub fn flange_transform(&self) -> Isometry3<f64> {
        self.flange_fixed * self.pose_group(ParamGroup::Flange)
    }

    /// MDH frame `k` (0 = frame 0, `dof` = last joint frame) in the robot base.
    pub fn joint_frame(&self, q: &[f64], k: usize) -> Isometry3<f64> {
        let mut t = Frame::from_iso(&self.base_offset);
        for i in 0..k.min(self.dof) {
            t = t.mul(&self.joint_local(i, q.get(i).copied().unwrap_or(0.0)));
        }
        t.to_iso()
    }

    /// Flange pose in the robot base (mm), q in rad. Missing entries of `q` count as 0.
    pub fn flange_pose(&self, q: &[f64]) -> Isometry3<f64> {
        self.flange_frame(q).to_iso()
    }
    /// Tool (marker / tip) pose in the robot base: flange · tool.
    pub fn tool_pose_in_base(&self, q: &[f64]) -> Isometry3<f64> {
        self.flange_frame(q)
            .mul(&pose6(&self.group_slice(ParamGroup::Tool)))
            .to_iso()
    }
    /// Marker / tip origin in the tracker frame: base · flange · tool · 0.
    pub fn measured_point(&self, q: &[f64]) -> Point3<f64> {
        let f = pose6(&self.group_slice(ParamGroup::Base)).mul(&self.flange_frame(q));
        let t = self.group_slice(ParamGroup::Tool);
        Point3::from(f.p + f.r * Vector3::new(t[0], t[1], t[2]))
    }
    /// Full marker pose in the tracker frame.
    pub fn measured_pose(&self, q: &[f64]) -> Isometry3<f64> {
        pose6(&self.group_slice(ParamGroup::Base))
            .mul(&self.flange_frame(q))
            .mul(&pose6(&self.group_slice(ParamGroup::Tool)))
            .to_iso()
    }

    /// Geometric Jacobian of the flange: rows (v; ω) in the robot base frame, v the flange
    /// origin velocity (mm/rad), ω the angular velocity; one column per joint.
    pub fn joint_jacobian(&self, q: &[f64]) -> Matrix6xX<f64> {
        let n = self.dof;
        let mut axes = Vec::with_capacity(n);
        let mut t = Frame::from_iso(&self.base_offset);
        for i in 0..n {
            let l = self.joint_local(i, q.get(i).copied().unwrap_or(0.0));
            let next = t.mul(&l);
            // joint axis: z of the new frame through its origin
            axes.push((next.r.column(2).into_owned(), next.p));
            t = next;
        }
        let pf = t
            .mul(&Frame::from_iso(&self.flange_fixed))
            .mul(&pose6(&self.group_slice(ParamGroup::Flange)))
            .p;
        let mut j = Matrix6xX::zeros(n);
        for (i, (z, o)) in axes.iter().enumerate() {
            let v = z.cross(&(pf - o));
            j.fixed_view_mut::<3, 1>(0, i).copy_from(&v);
            j.fixed_view_mut::<3, 1>(3, i).copy_from(z);
        }
        j
    }

    // ------------------------------------------------------------------ parameter Jacobians

    /// Walk the chain in the tracker frame, calling `f(param_index, axis, center, rotational)`
    /// for every parameter; returns the final marker frame. Rotational parameters rotate
    /// about `axis` through `center`; translational ones translate along `axis`.
    fn param_walk<F: FnMut(usize, Vector3<f64>, Vector3<f64>, bool)>(
        &self,
        q: &[f64],
        mut f: F,
    ) -> Frame {
        let n = self.dof;
        let bv = self.group_slice(ParamGroup::Base);
        let b = pose6(&bv);
        let ob = self.off_base();
        let eye = Matrix3::identity();
        let bax = rpy_axes(&eye, &bv);
        for (k, ax) in bax.iter().enumerate() {
            f(ob + k, eye.column(k).into_owned(), b.p, false);
            f(ob + 3 + k, *ax, b.p, true);
        }
        let mut t = b.mul(&Frame::from_iso(&self.base_offset));
        for i in 0..n {
            let o = 5 * i;
            let p = &self.params;
            let (phi, d, a, al, be) = (
                p[o + J_PHI].value,
                p[o + J_D].value,
                p[o + J_A].value,
                p[o + J_ALPHA].value,
                p[o + J_BETA].value,
            );
            let qi = q.get(i).copied().unwrap_or(0.0);
            let x = t.r.column(0).into_owned();
            f(o + J_ALPHA, x, t.p, true);
            let r1 = t.r * rot_x(al);
            let p1 = t.p + x * a;
            f(o + J_A, x, t.p, false);
            f(o + J_BETA, r1.column(1).into_owned(), p1, true);
            let r2 = r1 * rot_y(be);
            let z = r2.column(2).into_owned();
            f(o + J_PHI, z, p1, true);
            f(o + J_D, z, p1, false);
            t = Frame {
                r: r2 * rot_z(qi + phi),
                p: p1 + z * d,
            };
        }
        t = t.mul(&Frame::from_iso(&self.flange_fixed));
        for (g, off) in [
            (ParamGroup::Flange, self.off_flange()),
            (ParamGroup::Tool, self.off_tool()),
        ] {
            let v = self.group_slice(g);
            let ax = rpy_axes(&t.r, &v);
            for k in 0..3 {
                f(off + k, t.r.column(k).into_owned(), t.p, false);
            }
            t = t.mul(&pose6(&v));
            for (k, a) in ax.iter().enumerate() {
                f(off + 3 + k, *a, t.p, true);
            }
        }
        t
    }

    /// Marker origin in the tracker frame and its derivative w.r.t. every parameter
    /// (3 × `params().len()`, `params()` order, mm per mm or mm per rad). One analytic pass.
    pub fn point_param_jacobian(&self, q: &[f64]) -> (Point3<f64>, Matrix3xX<f64>) {
        let m = self.params.len();
        let mut jac = Matrix3xX::zeros(m);
        self.point_param_jacobian_into(q, &mut jac)
            .map(|p| (p, jac))
            .unwrap_or_else(|| (self.measured_point(q), Matrix3xX::zeros(m)))
    }

    /// As [`Self::point_param_jacobian`], writing into a caller-owned 3 × `params().len()`
    /// matrix (no allocation). Returns `None` if `out` has the wrong number of columns.
    pub fn point_param_jacobian_into(
        &self,
        q: &[f64],
        out: &mut Matrix3xX<f64>,
    ) -> Option<Point3<f64>> {
        if out.ncols() != self.params.len() {
            return None;
        }
        let p = self.measured_point(q).coords;
        self.param_walk(q, |k, axis, c, rot| {
            let col = if rot { axis.cross(&(p - c)) } else { axis };
            out.fixed_view_mut::<3, 1>(0, k).copy_from(&col);
        });
        Some(Point3::from(p))
    }

    /// Marker pose in the tracker frame and its derivative w.r.t. every parameter:
    /// rows 0..3 position (mm), rows 3..6 the small-angle rotation (rad) in the tracker frame
    /// (`δR ≈ [δθ]× R`).
    pub fn pose_param_jacobian(&self, q: &[f64]) -> (Isometry3<f64>, Matrix6xX<f64>) {
        let m = self.params.len();
        let mut jac = Matrix6xX::zeros(m);
        let pose = self.measured_pose(q);
        let p = pose.translation.vector;
        self.param_walk(q, |k, axis, c, rot| {
            if rot {
                let v = axis.cross(&(p - c));
                jac.fixed_view_mut::<3, 1>(0, k).copy_from(&v);
                jac.fixed_view_mut::<3, 1>(3, k).copy_from(&axis);
            } else {
                jac.fixed_view_mut::<3, 1>(0, k).copy_from(&axis);
            }
        });
        (pose, jac)
    }

    // ------------------------------------------------------------------ calibration files

    /// Parameters in file units (mm, deg).
    pub fn to_cal_params(&self) -> Vec<CalParam> {
        self.params
            .iter()
            .map(|p| CalParam {
                name: p.name.clone(),
                value: match p.unit {
                    Unit::Mm => p.value,
                    Unit::Rad => p.value.to_degrees(),
                },
                std: None,
                unit: match p.unit {
                    Unit::Mm => "mm".into(),
                    Unit::Rad => "deg".into(),
                },
                free: p.free,
                extra: Map::new(),
            })
            .collect()
    }

    /// Apply parameters read from a calibration file (mm / deg; `rad` and `m` accepted).
    /// Every name must exist; nothing is changed if any entry is invalid.
    pub fn apply_cal_params(&mut self, cal: &[CalParam]) -> Result<(), ModelError> {
        let mut updates = Vec::with_capacity(cal.len());
        for c in cal {
            let i = self
                .param_index(&c.name)
                .ok_or_else(|| ModelError::UnknownParam {
                    name: c.name.clone(),
                })?;
            if !c.value.is_finite() {
                return Err(ModelError::NonFinite {
                    name: c.name.clone(),
                });
            }
            let u = c.unit.trim().to_ascii_lowercase();
            let v = match (self.params[i].unit, u.as_str()) {
                (Unit::Mm, "mm") => c.value,
                (Unit::Mm, "m") => c.value * 1000.0,
                (Unit::Rad, "deg" | "degree" | "degrees") => c.value.to_radians(),
                (Unit::Rad, "rad" | "radian" | "radians") => c.value,
                (unit, _) => {
                    return Err(ModelError::BadUnit {
                        name: c.name.clone(),
                        unit: c.unit.clone(),
                        expected: match unit {
                            Unit::Mm => "mm".into(),
                            Unit::Rad => "deg".into(),
                        },
                    })
                }
            };
            updates.push((i, v, c.free));
        }
        for (i, v, free) in updates {
            self.params[i].value = v;
            self.params[i].free = free;
        }
        Ok(())
    }

    /// All inverse-kinematics branches of a flange pose in the robot base (see [`ik`]).
    pub fn ik(&self, flange_in_base: &Isometry3<f64>) -> Result<Vec<IkSolution>, IkError> {
        ik::solve(self, flange_in_base)
    }

    /// All IK branches that put the tool (marker / tip, `tool_*`) at `tool_in_base`.
    pub fn ik_for_tool(&self, tool_in_base: &Isometry3<f64>) -> Result<Vec<IkSolution>, IkError> {
        ik::solve(self, &(tool_in_base * self.tool().inverse()))
    }

    /// Damped-least-squares IK from a seed (any geometry, no closed form needed): the
    /// solution nearest the seed's basin, within 1e-7 mm / 1e-9 rad, or a typed error.
    pub fn ik_from_seed(
        &self,
        flange_in_base: &Isometry3<f64>,
        q0: &[f64],
    ) -> Result<Vec<f64>, IkError> {
        let t = flange_in_base.translation.vector;
        if !(t.iter().all(|x| x.is_finite())
            && flange_in_base.rotation.coords.iter().all(|x| x.is_finite())
            && q0.iter().all(|x| x.is_finite()))
        {
            return Err(IkError::NonFiniteTarget);
        }
        let mut q0 = q0.to_vec();
        q0.resize(self.dof, 0.0);
        let (q, ep, er) = ik::refine(self, flange_in_base, &q0, 200);
        if ep <= ik::IK_POS_TOL_MM && er <= ik::IK_ROT_TOL_RAD {
            Ok(q)
        } else if ep > 1e-3 {
            Err(IkError::Unreachable {
                x_mm: t.x,
                y_mm: t.y,
                z_mm: t.z,
                reason: format!("refinement from the seed stalls {ep:.3e} mm away"),
            })
        } else {
            Err(IkError::NotConverged {
                pos_err_mm: ep,
                rot_err_deg: er.to_degrees(),
            })
        }
    }
}

/// Position distance (mm) and rotation angle (rad) between two poses.
pub fn pose_distance(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    (
        (a.translation.vector - b.translation.vector).norm(),
        a.rotation.angle_to(&b.rotation),
    )
}
