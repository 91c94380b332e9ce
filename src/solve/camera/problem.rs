//! The reprojection least-squares problems on the one LM solver ([`crate::solve::lm`]).
//!
//! * [`Layout::Views`]: intrinsics + one board pose per view (`T_v`: board → camera), the
//!   classical intrinsic calibration (`p = T_v · P`).
//! * [`Layout::HandEye`]: intrinsics + the hand-eye `X` (camera in flange) + the target in the
//!   base `B`, with the flange poses `F_v` as inputs: `p = X⁻¹ F_v⁻¹ B · P` — the maximum-
//!   likelihood hand-eye on the raw corner reprojection errors.
//!
//! Optional extra parameters (what the camera diagnosis adds): the board scale `s`
//! (`P → s·P`) and a board bend `(c_x, c_y)`: the sag `z = c_x·((x−x₀)/R)² + c_y·((y−y₀)/R)²`
//! about the board centre (mm at distance `R` from it; a bow about one axis or a bowl).
//! And, eye-in-hand, a map of the flange positions ([`FlangeMap`]): the robot's reported
//! position `p` read as `p + S·(p − c)` with `S` a trace-free 3×3 matrix (eight parameters):
//! the part of the arm's pose error that is linear over the workspace the views sample.
#![allow(clippy::type_complexity)]
use nalgebra::{DMatrix, DVector, Isometry3, Vector3};

use super::geom::{pose_from_slice, project_jac, Intrinsics, PoseJac, N_INTR};
use crate::solve::lm::LsqProblem;

/// One detected corner.
#[derive(Debug, Clone, Copy)]
pub struct Obs {
    /// View index.
    pub view: usize,
    /// Board point as declared (mm, board frame, z = 0).
    pub pt: Vector3<f64>,
    /// Detected pixel.
    pub uv: [f64; 2],
}

/// Which poses are free.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// One board-in-camera pose per view.
    Views(usize),
    /// Hand-eye `X` and target-in-base `B` (flange poses are inputs).
    HandEye,
}

/// Board deformation parameters a fit may free.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BoardModel {
    /// Free the board scale.
    pub scale: bool,
    /// Free the board bend (two parameters).
    pub bend: bool,
    /// Centre `(x₀, y₀)` (mm) and radius `R` (mm) of the bend.
    pub centre: [f64; 3],
}

/// The arm's kinematic parameters seen through the camera (eye-in-hand, [`Layout::HandEye`]
/// only): the flange pose of view `v` is `FK(q_v; θ + δ)` through `model`, `δ` free for the
/// model parameters `params` (indices into [`crate::model::KinematicModel::params`]: joint
/// zeros `phi`, link lengths `a` / `d`, twists `alpha` / `beta`; mm or rad).
pub struct ArmModel<'a> {
    pub model: &'a crate::model::KinematicModel,
    /// Joint angles (rad) per view.
    pub q: &'a [Vec<f64>],
    pub params: Vec<usize>,
}

impl ArmModel<'_> {
    /// The model with the changes `delta` (one per entry of `params`) and its base and tool
    /// groups at identity, so that its measured pose is the flange pose.
    pub fn model_at(&self, delta: &[f64]) -> crate::model::KinematicModel {
        changed_model(self.model, &self.params, delta)
    }
}

/// `model` with `delta[k]` added to parameter `params[k]`, base and tool at identity.
pub fn changed_model(
    model: &crate::model::KinematicModel,
    params: &[usize],
    delta: &[f64],
) -> crate::model::KinematicModel {
    let mut m = model.clone();
    let mut v = m.param_values();
    for (&i, d) in params.iter().zip(delta) {
        v[i] += d;
    }
    m.set_param_values(&v);
    m.set_base(&Isometry3::identity());
    m.set_tool(&Isometry3::identity());
    m
}

/// A map of the flange positions: the flange at reported position `p` is taken at
/// `p + S·(p − centre)`, `S` trace-free (its eight parameters in [`flange_map_matrix`]'s order;
/// the trace, a uniform scale, is the board's scale and is left to it). The orientations are
/// kept. It is the arm's position error to first order over the workspace the views sample:
/// a scale along some directions, a shear, a small rotation of the positions against the
/// orientations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlangeMap {
    /// The point the map leaves in place (mm, base frame): the training flange positions' mean.
    pub centre: Vector3<f64>,
}

/// Number of parameters of a [`FlangeMap`].
pub const FLANGE_MAP_PARAMS: usize = 8;

/// The trace-free matrix `S` of a [`FlangeMap`] from its parameters
/// `[s_xx, s_xy, s_xz, s_yx, s_yy, s_yz, s_zx, s_zy]` (`s_zz = −s_xx − s_yy`).
pub fn flange_map_matrix(s: &[f64]) -> nalgebra::Matrix3<f64> {
    nalgebra::Matrix3::new(s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7], -s[0] - s[4])
}

/// The parameters' names, in order (file and report).
pub const FLANGE_MAP_NAMES: [&str; FLANGE_MAP_PARAMS] = [
    "s_xx", "s_xy", "s_xz", "s_yx", "s_yy", "s_yz", "s_zx", "s_zy",
];

/// `f` with its position mapped: `p + S·(p − centre)`.
pub fn map_flange(f: &Isometry3<f64>, s: &[f64], centre: &Vector3<f64>) -> Isometry3<f64> {
    shift_flange(f, &flange_map_matrix(s), centre)
}

/// `f` with its position `p` moved to `p + m·(p − centre)`, its orientation kept: the one
/// place a flange map is applied (the fit, the diagnosis' held-out views, and the calibration
/// file's `camera.flange_map` through [`super::calfile::read_through_map`]).
pub fn shift_flange(
    f: &Isometry3<f64>,
    m: &nalgebra::Matrix3<f64>,
    centre: &Vector3<f64>,
) -> Isometry3<f64> {
    let mut g = *f;
    let p = f.translation.vector;
    g.translation.vector = p + m * (p - centre);
    g
}

/// The problem.
pub struct Reproj<'a> {
    pub obs: &'a [Obs],
    /// Flange (or, eye-to-hand, inverse flange) poses per view; [`Layout::HandEye`] only.
    pub flange: &'a [Isometry3<f64>],
    pub layout: Layout,
    /// Which of `[fx, fy, cx, cy, k1, k2, p1, p2, k3]` are free.
    pub intr_free: [bool; N_INTR],
    /// Values of the fixed intrinsics.
    pub intr_fixed: Intrinsics,
    pub board: BoardModel,
    /// Arm parameter changes (free after the board parameters), when given.
    pub arm: Option<ArmModel<'a>>,
    /// A map of the flange positions (its [`FLANGE_MAP_PARAMS`] free after the arm's), when
    /// given ([`Layout::HandEye`] only).
    pub flange_map: Option<FlangeMap>,
}

impl Reproj<'_> {
    fn n_intr(&self) -> usize {
        self.intr_free.iter().filter(|f| **f).count()
    }
    fn n_poses(&self) -> usize {
        match self.layout {
            Layout::Views(n) => n,
            Layout::HandEye => 2,
        }
    }
    /// Full intrinsics from the parameter vector.
    pub fn intrinsics(&self, x: &DVector<f64>) -> Intrinsics {
        let mut v = self.intr_fixed.to_vec();
        let mut k = 0;
        for (i, f) in self.intr_free.iter().enumerate() {
            if *f {
                v[i] = x[k];
                k += 1;
            }
        }
        Intrinsics::from_slice(&v)
    }
    /// Offset of pose block `b` in the parameter vector.
    pub fn pose_offset(&self, b: usize) -> usize {
        self.n_intr() + 6 * b
    }
    /// Offset of the board parameters (scale, then bend).
    pub fn board_offset(&self) -> usize {
        self.n_intr() + 6 * self.n_poses()
    }
    /// Pose block `b`.
    pub fn pose(&self, x: &DVector<f64>, b: usize) -> Isometry3<f64> {
        let o = self.pose_offset(b);
        pose_from_slice(&x.as_slice()[o..o + 6])
    }
    /// Offset of the arm parameter changes.
    pub fn arm_offset(&self) -> usize {
        self.board_offset() + self.board.scale as usize + 2 * self.board.bend as usize
    }
    /// Offset of the flange map's parameters.
    pub fn map_offset(&self) -> usize {
        self.arm_offset() + self.arm.as_ref().map_or(0, |a| a.params.len())
    }
    /// The flange map's parameters at `x` (empty without a map).
    pub fn map_params(&self, x: &DVector<f64>) -> Vec<f64> {
        let o = self.map_offset();
        let n = if self.flange_map.is_some() {
            FLANGE_MAP_PARAMS
        } else {
            0
        };
        (0..n).map(|k| x[o + k]).collect()
    }
    /// Arm parameter changes (mm / rad) at `x`, one per entry of [`ArmModel::params`].
    pub fn arm_deltas(&self, x: &DVector<f64>) -> Vec<f64> {
        let o = self.arm_offset();
        let n = self.arm.as_ref().map_or(0, |a| a.params.len());
        (0..n).map(|k| x[o + k]).collect()
    }
    /// `(scale, [bend x, bend y])` at `x`.
    pub fn board_params(&self, x: &DVector<f64>) -> (f64, [f64; 2]) {
        let mut o = self.board_offset();
        let s = if self.board.scale {
            o += 1;
            x[o - 1]
        } else {
            1.0
        };
        let c = if self.board.bend {
            [x[o], x[o + 1]]
        } else {
            [0.0; 2]
        };
        (s, c)
    }
    /// Initial parameter vector.
    pub fn pack(
        &self,
        k: &Intrinsics,
        poses: &[Isometry3<f64>],
        scale: f64,
        bend: [f64; 2],
    ) -> DVector<f64> {
        let kv = k.to_vec();
        let mut v: Vec<f64> = (0..N_INTR)
            .filter(|i| self.intr_free[*i])
            .map(|i| kv[i])
            .collect();
        for p in poses {
            v.extend(super::geom::pose_to_vec(p));
        }
        if self.board.scale {
            v.push(scale);
        }
        if self.board.bend {
            v.extend(bend);
        }
        if let Some(a) = &self.arm {
            v.extend(std::iter::repeat_n(0.0, a.params.len()));
        }
        if self.flange_map.is_some() {
            v.extend([0.0; FLANGE_MAP_PARAMS]);
        }
        DVector::from_vec(v)
    }

    /// Residuals (px) and, when `jac`, the Jacobian.
    fn eval(&self, x: &DVector<f64>, jac: bool) -> (DVector<f64>, DMatrix<f64>) {
        let n = self.n_params();
        let m = 2 * self.obs.len();
        let mut r = DVector::zeros(m);
        let mut j = if jac {
            DMatrix::zeros(m, n)
        } else {
            DMatrix::zeros(0, 0)
        };
        let k = self.intrinsics(x);
        let (s, c) = self.board_params(x);
        let [x0, y0, rr] = self.board.centre;
        let free_idx: Vec<usize> = (0..N_INTR).filter(|i| self.intr_free[*i]).collect();
        let xs = x.as_slice();
        let bo = self.board_offset();
        // Flange poses and their parameter Jacobians (base frame; rows 0..3 position, 3..6
        // small-angle rotation) per view when the arm parameters are free.
        let ao = self.arm_offset();
        let arm_frames: Option<Vec<(Isometry3<f64>, nalgebra::Matrix6xX<f64>)>> =
            self.arm.as_ref().map(|a| {
                let m = a.model_at(&self.arm_deltas(x));
                a.q.iter()
                    .map(|q| {
                        let (pose, jf) = m.pose_param_jacobian(q);
                        let mut js = nalgebra::Matrix6xX::zeros(a.params.len());
                        for (k, &pi) in a.params.iter().enumerate() {
                            js.set_column(k, &jf.column(pi));
                        }
                        (pose, js)
                    })
                    .collect()
            });
        // The flange map: `S` and the columns' basis matrices.
        let mo = self.map_offset();
        let map = self.flange_map.map(|m| {
            let sv = self.map_params(x);
            let basis: Vec<nalgebra::Matrix3<f64>> = (0..FLANGE_MAP_PARAMS)
                .map(|k| {
                    let mut e = [0.0; FLANGE_MAP_PARAMS];
                    e[k] = 1.0;
                    flange_map_matrix(&e)
                })
                .collect();
            (m.centre, flange_map_matrix(&sv), basis)
        });
        // Every pose block's rotation, left Jacobian and (quaternion-route) rotation matrix,
        // once per evaluation rather than once per corner (the same arithmetic).
        let blocks_pre: Vec<(PoseJac, nalgebra::Matrix3<f64>)> = (0..self.n_poses())
            .map(|b| {
                let o = self.pose_offset(b);
                let v = &xs[o..o + 6];
                let rq = *pose_from_slice(v).rotation.to_rotation_matrix().matrix();
                (PoseJac::new(v), rq)
            })
            .collect();
        for (i, o) in self.obs.iter().enumerate() {
            let mut d_arm: Vec<Vector3<f64>> = vec![];
            let mut d_map: Vec<Vector3<f64>> = vec![];
            // Board point with scale and bend.
            let (qx, qy) = if self.board.bend || c != [0.0; 2] {
                (((o.pt.x - x0) / rr).powi(2), ((o.pt.y - y0) / rr).powi(2))
            } else {
                (0.0, 0.0)
            };
            let p = Vector3::new(s * o.pt.x, s * o.pt.y, c[0] * qx + c[1] * qy);
            let dp_ds = Vector3::new(o.pt.x, o.pt.y, 0.0);
            // Camera-frame point and its derivatives w.r.t. pose blocks and the board point.
            let (pc, blocks, dpc_dp): (
                Vector3<f64>,
                Vec<(usize, nalgebra::SMatrix<f64, 3, 6>)>,
                nalgebra::Matrix3<f64>,
            ) = match self.layout {
                Layout::Views(_) => {
                    let off = self.pose_offset(o.view);
                    let (pj, rq) = &blocks_pre[o.view];
                    let (y, jp) = pj.transform_jac(&p);
                    (y, vec![(off, jp)], *rq)
                }
                Layout::HandEye => {
                    let (ox, ob) = (self.pose_offset(0), self.pose_offset(1));
                    let ((pjx, rqx), (pjb, rqb)) = (&blocks_pre[0], &blocks_pre[1]);
                    let (y1, jb) = pjb.transform_jac(&p);
                    let f0 = match &arm_frames {
                        Some(af) => &af[o.view].0,
                        None => &self.flange[o.view],
                    };
                    // The mapped flange: position p + S (p − c), orientation kept.
                    let mapped;
                    let f = match &map {
                        Some((c, sm, _)) => {
                            mapped = shift_flange(f0, sm, c);
                            &mapped
                        }
                        None => f0,
                    };
                    let y2 = f.inverse_transform_vector(&(y1 - f.translation.vector));
                    let (y3, jx) = pjx.inv_transform_jac(&y2);
                    let rf = f.rotation.to_rotation_matrix();
                    let chain = rqx.transpose() * rf.matrix().transpose();
                    // The map scales a change of the reported position by (I + S).
                    let i_s = map
                        .as_ref()
                        .map_or(nalgebra::Matrix3::identity(), |(_, sm, _)| {
                            nalgebra::Matrix3::identity() + sm
                        });
                    if let Some(af) = &arm_frames {
                        // δF: position δp, rotation δθ (base frame): F⁻¹y changes by
                        // −F_R⁻¹ (δθ × (y − p) + δp), p the (mapped) flange position.
                        let js = &af[o.view].1;
                        let rel = y1 - f.translation.vector;
                        d_arm = js
                            .column_iter()
                            .map(|c| {
                                let dp = i_s * Vector3::new(c[0], c[1], c[2]);
                                let dw = Vector3::new(c[3], c[4], c[5]);
                                -(chain * (dw.cross(&rel) + dp))
                            })
                            .collect();
                    }
                    if let Some((c, _, basis)) = &map {
                        // δp = E_k (p₀ − c) for parameter k.
                        let rel0 = f0.translation.vector - c;
                        d_map = basis.iter().map(|e| -(chain * (e * rel0))).collect();
                    }
                    (y3, vec![(ox, jx), (ob, chain * jb)], chain * rqb)
                }
            };
            let Some((uv, jp, ji)) = project_jac(&k, &pc) else {
                // Behind the camera: a large constant residual, no gradient.
                r[2 * i] = 1e4;
                r[2 * i + 1] = 1e4;
                continue;
            };
            r[2 * i] = uv[0] - o.uv[0];
            r[2 * i + 1] = uv[1] - o.uv[1];
            if !jac {
                continue;
            }
            for (col, &fi) in free_idx.iter().enumerate() {
                j[(2 * i, col)] = ji[(0, fi)];
                j[(2 * i + 1, col)] = ji[(1, fi)];
            }
            for (off, jb) in &blocks {
                let d = jp * jb;
                for c6 in 0..6 {
                    j[(2 * i, off + c6)] = d[(0, c6)];
                    j[(2 * i + 1, off + c6)] = d[(1, c6)];
                }
            }
            let mut bo2 = bo;
            if self.board.scale {
                let d = jp * (dpc_dp * dp_ds);
                j[(2 * i, bo2)] = d[0];
                j[(2 * i + 1, bo2)] = d[1];
                bo2 += 1;
            }
            if self.board.bend {
                let d = jp * dpc_dp.column(2);
                for (col, q) in [qx, qy].into_iter().enumerate() {
                    j[(2 * i, bo2 + col)] = d[0] * q;
                    j[(2 * i + 1, bo2 + col)] = d[1] * q;
                }
            }
            for (k, dpc) in d_arm.iter().enumerate() {
                let d = jp * dpc;
                j[(2 * i, ao + k)] = d[0];
                j[(2 * i + 1, ao + k)] = d[1];
            }
            for (k, dpc) in d_map.iter().enumerate() {
                let d = jp * dpc;
                j[(2 * i, mo + k)] = d[0];
                j[(2 * i + 1, mo + k)] = d[1];
            }
        }
        (r, j)
    }
}

impl LsqProblem for Reproj<'_> {
    fn n_params(&self) -> usize {
        self.map_offset()
            + if self.flange_map.is_some() {
                FLANGE_MAP_PARAMS
            } else {
                0
            }
    }
    fn residuals(&self, x: &DVector<f64>) -> DVector<f64> {
        self.eval(x, false).0
    }
    fn residuals_jacobian(&self, x: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
        self.eval(x, true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::lm::numeric_jacobian;
    use nalgebra::{Translation3, UnitQuaternion};

    fn setup() -> (Vec<Obs>, Vec<Isometry3<f64>>, Intrinsics) {
        let k = Intrinsics {
            fx: 900.0,
            fy: 902.0,
            cx: 320.0,
            cy: 240.0,
            dist: [-0.05, 0.02, 0.001, -0.001, 0.003],
        };
        let mut obs = vec![];
        let mut fl = vec![];
        for v in 0..3 {
            fl.push(Isometry3::from_parts(
                Translation3::new(-400.0 + 10.0 * v as f64, -150.0, 550.0),
                UnitQuaternion::from_scaled_axis(Vector3::new(3.1, 0.1 * v as f64, 0.2)),
            ));
            for i in 0..4 {
                for jj in 0..3 {
                    obs.push(Obs {
                        view: v,
                        pt: Vector3::new(30.0 * (i + 1) as f64, 30.0 * (jj + 1) as f64, 0.0),
                        uv: [300.0 + i as f64, 200.0 + jj as f64],
                    });
                }
            }
        }
        (obs, fl, k)
    }

    #[test]
    fn jacobians_match_finite_differences() {
        let (obs, fl, k) = setup();
        let board = BoardModel {
            scale: true,
            bend: true,
            centre: [75.0, 60.0, 90.0],
        };
        let x_he = Isometry3::from_parts(
            Translation3::new(0.0, 50.0, 40.0),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.01, -0.02, 0.03)),
        );
        let b = Isometry3::from_parts(
            Translation3::new(-500.0, -200.0, 0.0),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.02, 0.01, 0.5)),
        );
        for layout in [Layout::HandEye, Layout::Views(3)] {
            let p = Reproj {
                obs: &obs,
                flange: &fl,
                layout,
                intr_free: [true; N_INTR],
                intr_fixed: k,
                board,
                arm: None,
                flange_map: None,
            };
            let poses: Vec<Isometry3<f64>> = match layout {
                Layout::HandEye => vec![x_he, b],
                Layout::Views(n) => (0..n).map(|v| (fl[v] * x_he).inverse() * b).collect(),
            };
            let x0 = p.pack(&k, &poses, 1.002, [0.3, -0.2]);
            let (_, ja) = p.residuals_jacobian(&x0);
            let jn = numeric_jacobian(|x| p.residuals(x), &x0, 1e-6);
            for c in 0..ja.ncols() {
                let e = (ja.column(c) - jn.column(c)).norm() / (1.0 + jn.column(c).norm());
                assert!(e < 1e-5, "{layout:?} column {c}: {e}");
            }
        }
        // Arm parameters through the UR5e model (flange from q, not from the inputs): joint
        // zeros, link lengths and twists.
        let model = crate::model::KinematicModel::preset("ur5e").unwrap();
        let params: Vec<usize> = [
            "phi2", "phi3", "phi4", "phi5", "a3", "d4", "alpha5", "beta3",
        ]
        .iter()
        .map(|n| model.param_index(n).unwrap())
        .collect();
        let np = params.len();
        let qs: Vec<Vec<f64>> = (0..3)
            .map(|v| vec![0.1 * v as f64, -1.3, 1.4, -1.6 + 0.2 * v as f64, -1.5, 0.3])
            .collect();
        let p = Reproj {
            obs: &obs,
            flange: &fl,
            layout: Layout::HandEye,
            intr_free: [true; N_INTR],
            intr_fixed: k,
            board,
            arm: Some(ArmModel {
                model: &model,
                q: &qs,
                params,
            }),
            // With the flange map on top: its own columns and its effect on the arm's.
            flange_map: Some(FlangeMap {
                centre: Vector3::new(-390.0, -140.0, 540.0),
            }),
        };
        let mut x0 = p.pack(&k, &[x_he, b], 1.002, [0.3, -0.2]);
        let ao = p.arm_offset();
        for kk in 0..np {
            x0[ao + kk] = 0.001 * (kk as f64 + 1.0);
        }
        let mo = p.map_offset();
        assert_eq!(p.n_params(), mo + FLANGE_MAP_PARAMS);
        for kk in 0..FLANGE_MAP_PARAMS {
            x0[mo + kk] = 0.004 * (kk as f64 - 3.5);
        }
        let (_, ja) = p.residuals_jacobian(&x0);
        let jn = numeric_jacobian(|x| p.residuals(x), &x0, 1e-7);
        for c in 0..ja.ncols() {
            let e = (ja.column(c) - jn.column(c)).norm() / (1.0 + jn.column(c).norm());
            assert!(e < 1e-5, "arm column {c}: {e}");
        }
    }
}
