//! Inverse kinematics: every closed-form branch of the nominal geometry family (8 for the UR
//! family, 8 for the VS060 family), then damped-least-squares Newton refinement on the
//! actual (possibly calibrated) model. mm / rad.
//!
//! Branch numbering: `branch = 4·shoulder + 2·elbow + wrist` with `Right = 0, Left = 1`,
//! `Up = 0, Down = 1`, `NoFlip = 0, Flip = 1`.
//! - VS060 family: shoulder `Right` = `q1 = atan2(Wy, Wx)` (wrist centre in front of axis 1),
//!   `Left` = `q1 + π`; elbow `Up` = the `+acos` root of the elbow equation; wrist `NoFlip`
//!   = `q5 ≥ 0`.
//! - UR family (Hawkins 2013): shoulder `Right` = `q1 = ψ + asin(d4/r)`, `Left` =
//!   `ψ + π − asin(d4/r)`; elbow `Up` = `q3 ≥ 0`; wrist `NoFlip` = `q5 ≥ 0`.
use std::f64::consts::{FRAC_PI_2, PI, TAU};
use std::fmt;

use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};

use super::error::IkError;
use super::KinematicModel;

/// Shoulder branch.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Shoulder {
    Right,
    Left,
}
/// Elbow branch.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Elbow {
    Up,
    Down,
}
/// Wrist branch.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Wrist {
    NoFlip,
    Flip,
}

/// Label of an IK branch.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct BranchLabel {
    pub shoulder: Shoulder,
    pub elbow: Elbow,
    pub wrist: Wrist,
}

impl BranchLabel {
    /// From the branch number (0..8).
    pub fn from_index(b: u8) -> Self {
        BranchLabel {
            shoulder: if b & 4 == 0 {
                Shoulder::Right
            } else {
                Shoulder::Left
            },
            elbow: if b & 2 == 0 { Elbow::Up } else { Elbow::Down },
            wrist: if b & 1 == 0 {
                Wrist::NoFlip
            } else {
                Wrist::Flip
            },
        }
    }
    /// The branch number (0..8).
    pub fn index(&self) -> u8 {
        (if self.shoulder == Shoulder::Left {
            4
        } else {
            0
        }) + (if self.elbow == Elbow::Down { 2 } else { 0 })
            + (if self.wrist == Wrist::Flip { 1 } else { 0 })
    }
}

impl fmt::Display for BranchLabel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = match self.shoulder {
            Shoulder::Right => "right",
            Shoulder::Left => "left",
        };
        let e = match self.elbow {
            Elbow::Up => "up",
            Elbow::Down => "down",
        };
        let w = match self.wrist {
            Wrist::NoFlip => "noflip",
            Wrist::Flip => "flip",
        };
        write!(f, "shoulder-{s}/elbow-{e}/wrist-{w}")
    }
}

/// One IK solution.
#[derive(Debug, Clone, PartialEq)]
pub struct IkSolution {
    /// Joint angles (rad), wrapped by ±2π into the limits where possible.
    pub q: Vec<f64>,
    /// Branch number `4·shoulder + 2·elbow + wrist` (see module docs).
    pub branch: u8,
    pub label: BranchLabel,
    /// All joints within the model's limits.
    pub within_limits: bool,
    /// Residual position error of the refined solution (mm).
    pub pos_err_mm: f64,
    /// Residual orientation error of the refined solution (rad).
    pub rot_err_rad: f64,
}

/// Closed-form geometry family, with its nominal constants (mm).
#[derive(Debug, Clone, PartialEq)]
pub enum IkFamily {
    /// DENSO VS060-like: axis 1 vertical through the base origin, shoulder (axis 2, about y)
    /// at height `h`, upper arm `l2` along z, forearm from axis 3 to the wrist centre
    /// `(fx, 0, fz)`, spherical wrist (z, y, z), wrist centre → flange `dw` along z.
    SphericalWrist {
        h: f64,
        l2: f64,
        fx: f64,
        fz: f64,
        dw: f64,
    },
    /// Universal Robots standard DH (`a2, a3 < 0`, α = (π/2, 0, 0, π/2, −π/2, 0)).
    Ur {
        d1: f64,
        a2: f64,
        a3: f64,
        d4: f64,
        d5: f64,
        d6: f64,
    },
}

fn rz(a: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), a)
}
fn ry(a: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&Vector3::y_axis(), a)
}
fn rx(a: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&Vector3::x_axis(), a)
}
fn tr(x: f64, y: f64, z: f64) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::new(x, y, z), UnitQuaternion::identity())
}
fn rot(q: UnitQuaternion<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::identity(), q)
}
/// Standard DH `Rz(θ)·Tz(d)·Tx(a)·Rx(α)`.
pub fn dh(theta: f64, d: f64, a: f64, alpha: f64) -> Isometry3<f64> {
    rot(rz(theta)) * tr(a, 0.0, d) * rot(rx(alpha))
}
fn wrap(a: f64) -> f64 {
    let mut x = a.rem_euclid(TAU);
    if x > PI {
        x -= TAU;
    }
    x
}

impl IkFamily {
    /// The family's nominal flange pose in the robot base.
    pub fn nominal_fk(&self, q: &[f64; 6]) -> Isometry3<f64> {
        match *self {
            IkFamily::SphericalWrist { h, l2, fx, fz, dw } => {
                rot(rz(q[0]))
                    * tr(0.0, 0.0, h)
                    * rot(ry(q[1]))
                    * tr(0.0, 0.0, l2)
                    * rot(ry(q[2]))
                    * tr(fx, 0.0, fz)
                    * rot(rz(q[3]))
                    * rot(ry(q[4]))
                    * tr(0.0, 0.0, dw)
                    * rot(rz(q[5]))
            }
            IkFamily::Ur {
                d1,
                a2,
                a3,
                d4,
                d5,
                d6,
            } => {
                dh(q[0], d1, 0.0, FRAC_PI_2)
                    * dh(q[1], 0.0, a2, 0.0)
                    * dh(q[2], 0.0, a3, 0.0)
                    * dh(q[3], d4, 0.0, FRAC_PI_2)
                    * dh(q[4], d5, 0.0, -FRAC_PI_2)
                    * dh(q[5], d6, 0.0, 0.0)
            }
        }
    }

    /// The built-in families (VS060, UR5e, UR10e nominal constants).
    pub fn builtin() -> Vec<IkFamily> {
        vec![
            IkFamily::SphericalWrist {
                h: 345.0,
                l2: 305.0,
                fx: -10.0,
                fz: 300.0,
                dw: 70.0,
            },
            IkFamily::Ur {
                d1: 162.5,
                a2: -425.0,
                a3: -392.2,
                d4: 133.3,
                d5: 99.7,
                d6: 99.6,
            },
            IkFamily::Ur {
                d1: 180.7,
                a2: -612.7,
                a3: -571.55,
                d4: 174.15,
                d5: 119.85,
                d6: 116.55,
            },
        ]
    }

    /// The built-in family whose nominal flange pose is within 5 mm and 2° of the model's
    /// on a fixed set of joint vectors (a calibrated robot stays within that).
    pub fn detect(model: &KinematicModel) -> Option<IkFamily> {
        if model.dof() != 6 {
            return None;
        }
        const QS: [[f64; 6]; 6] = [
            [0.0; 6],
            [0.3, -0.5, 0.7, 0.2, -0.9, 1.1],
            [-1.2, 0.8, -0.4, 1.5, 0.6, -2.0],
            [2.0, 0.1, 1.3, -1.0, 1.2, 0.4],
            [-0.7, -1.1, -1.6, 2.5, -0.3, 3.0],
            [1.0, 1.0, 1.0, 1.0, 1.0, 1.0],
        ];
        IkFamily::builtin().into_iter().find(|f| {
            QS.iter().all(|q| {
                let a = f.nominal_fk(q);
                let b = model.flange_pose(q);
                let (dp, dr) = super::pose_distance(&a, &b);
                dp < 5.0 && dr < 2f64.to_radians()
            })
        })
    }

    /// All closed-form branches for a flange pose: `(branch, q)`. Branches whose equations
    /// have no real root are left out.
    pub fn closed_form(&self, t: &Isometry3<f64>) -> Vec<(u8, [f64; 6])> {
        let r = t.rotation.to_rotation_matrix().into_inner();
        let p = t.translation.vector;
        let mut out = Vec::with_capacity(8);
        match *self {
            IkFamily::SphericalWrist { h, l2, fx, fz, dw } => {
                let w = p - r.column(2) * dw;
                let a0 = if w.x.hypot(w.y) < 1e-9 {
                    0.0
                } else {
                    w.y.atan2(w.x)
                };
                let rho = fx.hypot(fz);
                let psi = fx.atan2(fz);
                for (sh, q1) in [(0u8, a0), (1u8, a0 + PI)] {
                    let (s1, c1) = q1.sin_cos();
                    let x = c1 * w.x + s1 * w.y;
                    let z = w.z - h;
                    let k = (x * x + z * z - l2 * l2 - fx * fx - fz * fz) / (2.0 * l2);
                    let c = k / rho;
                    if !c.is_finite() || c.abs() > 1.0 + SEED_MARGIN {
                        continue;
                    }
                    let ac = c.clamp(-1.0, 1.0).acos();
                    for (el, sgn) in [(0u8, 1.0), (1u8, -1.0)] {
                        let q3 = sgn * ac - psi;
                        let (s3, c3) = q3.sin_cos();
                        let ux = fx * c3 + fz * s3;
                        let uz = l2 - fx * s3 + fz * c3;
                        let q2 = (uz * x - ux * z).atan2(ux * x + uz * z);
                        let r03 = (rz(q1) * ry(q2 + q3)).to_rotation_matrix().into_inner();
                        let m = r03.transpose() * r;
                        for (wr, q456) in zyz(&m) {
                            out.push((
                                4 * sh + 2 * el + wr,
                                [q1, q2, q3, q456[0], q456[1], q456[2]].map(wrap),
                            ));
                        }
                    }
                }
            }
            IkFamily::Ur {
                d1,
                a2,
                a3,
                d4,
                d5,
                d6,
            } => {
                let p05 = p - r.column(2) * d6;
                let rxy = p05.x.hypot(p05.y);
                if rxy < d4.abs() * (1.0 - 2.0 * SEED_MARGIN) || rxy < 1e-12 {
                    return out;
                }
                let psi = p05.y.atan2(p05.x);
                let asn = (d4 / rxy).clamp(-1.0, 1.0).asin();
                for (sh, q1) in [(0u8, psi + asn), (1u8, psi + PI - asn)] {
                    let (s1, c1) = q1.sin_cos();
                    let c5 = (s1 * r[(0, 2)] - c1 * r[(1, 2)]).clamp(-1.0, 1.0);
                    for (wr, sgn5) in [(0u8, 1.0), (1u8, -1.0)] {
                        let q5 = sgn5 * c5.acos();
                        let s5 = q5.sin();
                        let q6 = if s5.abs() < 1e-10 {
                            0.0
                        } else {
                            ((-s1 * r[(0, 1)] + c1 * r[(1, 1)]) / s5)
                                .atan2((s1 * r[(0, 0)] - c1 * r[(1, 0)]) / s5)
                        };
                        let t01 = dh(q1, d1, 0.0, FRAC_PI_2);
                        let t45 = dh(q5, d5, 0.0, -FRAC_PI_2);
                        let t56 = dh(q6, d6, 0.0, 0.0);
                        let t14 = t01.inverse() * t * t56.inverse() * t45.inverse();
                        let x = t14.translation.vector.x;
                        let y = t14.translation.vector.y;
                        let c3 = (x * x + y * y - a2 * a2 - a3 * a3) / (2.0 * a2 * a3);
                        if !c3.is_finite() || c3.abs() > 1.0 + SEED_MARGIN {
                            continue;
                        }
                        let ac = c3.clamp(-1.0, 1.0).acos();
                        for (el, sgn3) in [(0u8, 1.0), (1u8, -1.0)] {
                            let q3 = sgn3 * ac;
                            let q2 = y.atan2(x) - (a3 * q3.sin()).atan2(a2 + a3 * q3.cos());
                            let m = t14.rotation.to_rotation_matrix().into_inner()
                                * rx(-FRAC_PI_2).to_rotation_matrix().into_inner();
                            let q234 = m[(1, 0)].atan2(m[(0, 0)]);
                            let q4 = q234 - q2 - q3;
                            out.push((4 * sh + 2 * el + wr, [q1, q2, q3, q4, q5, q6].map(wrap)));
                        }
                    }
                }
            }
        }
        out.sort_by_key(|b| b.0);
        out
    }
}

/// Relative margin by which a closed-form equation may miss a real root and still give a
/// (clamped) seed: a calibrated robot can reach slightly beyond the nominal workspace; the
/// Newton refinement on the actual model decides.
pub const SEED_MARGIN: f64 = 0.05;

/// ZYZ Euler angles of `m = Rz(a)·Ry(b)·Rz(c)`: (no-flip with b ≥ 0, flip with b ≤ 0).
fn zyz(m: &Matrix3<f64>) -> [(u8, [f64; 3]); 2] {
    let sb = m[(0, 2)].hypot(m[(1, 2)]);
    let b = sb.atan2(m[(2, 2)]);
    let (a, c) = if sb < 1e-12 {
        // b = 0 (or π): only a ± c is defined; put it all on c.
        (0.0, m[(1, 0)].atan2(m[(0, 0)]) * m[(2, 2)].signum())
    } else {
        (m[(1, 2)].atan2(m[(0, 2)]), m[(2, 1)].atan2(-m[(2, 0)]))
    };
    [(0, [a, b, c]), (1, [a + PI, -b, c + PI])]
}

/// Damped least-squares Newton on the model's flange pose. Returns (q, pos_err, rot_err).
pub fn refine(
    model: &KinematicModel,
    target: &Isometry3<f64>,
    q0: &[f64],
    max_iter: usize,
) -> (Vec<f64>, f64, f64) {
    let n = model.dof();
    let mut q = q0.to_vec();
    // rotation error weighted by a length so both parts count alike
    const L: f64 = 300.0;
    let err = |q: &[f64]| {
        let f = model.flange_pose(q);
        let dp = target.translation.vector - f.translation.vector;
        let dr = (target.rotation * f.rotation.inverse()).scaled_axis();
        (dp, dr)
    };
    let (mut dp, mut dr) = err(&q);
    let mut cost = dp.norm_squared() + (L * L) * dr.norm_squared();
    let mut lambda = 1e-3;
    for _ in 0..max_iter {
        if dp.norm() < 1e-9 && dr.norm() < 1e-12 {
            break;
        }
        let j = model.joint_jacobian(&q);
        let mut jw = DMatrix::<f64>::zeros(6, n);
        let mut e = DVector::<f64>::zeros(6);
        for c in 0..n {
            for k in 0..3 {
                jw[(k, c)] = j[(k, c)];
                jw[(3 + k, c)] = L * j[(3 + k, c)];
            }
        }
        for k in 0..3 {
            e[k] = dp[k];
            e[3 + k] = L * dr[k];
        }
        let mut improved = false;
        for _ in 0..12 {
            let a = &jw * jw.transpose() + DMatrix::<f64>::identity(6, 6) * lambda;
            let Some(chol) = a.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let dq = jw.transpose() * chol.solve(&e);
            let qn: Vec<f64> = q.iter().zip(dq.iter()).map(|(a, b)| a + b).collect();
            let (dpn, drn) = err(&qn);
            let cn = dpn.norm_squared() + (L * L) * drn.norm_squared();
            if cn.is_finite() && cn <= cost {
                q = qn;
                dp = dpn;
                dr = drn;
                cost = cn;
                lambda = (lambda * 0.1).max(1e-12);
                improved = true;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    (q, dp.norm(), dr.norm())
}

/// Move a nominal closed-form seed towards the model's solution on the same branch: with
/// `Δ = nominal(q) · model(q)⁻¹` the nominal geometry reaches `Δ · target` where the model
/// reaches `target`, so re-solving the closed form for the shifted target keeps the branch
/// while absorbing the calibration (a few fixed-point steps; the Newton step polishes).
fn shift_seed(
    model: &KinematicModel,
    fam: &IkFamily,
    target: &Isometry3<f64>,
    branch: u8,
    mut q: [f64; 6],
) -> [f64; 6] {
    for _ in 0..6 {
        let delta = fam.nominal_fk(&q) * model.flange_pose(&q).inverse();
        let shifted = delta * target;
        let Some((_, qn)) = fam
            .closed_form(&shifted)
            .into_iter()
            .find(|(b, _)| *b == branch)
        else {
            break;
        };
        // continuity with the previous iterate (wrapping may move by 2π)
        let qn = std::array::from_fn(|i| q[i] + wrap(qn[i] - q[i]));
        let step = qn
            .iter()
            .zip(q.iter())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        q = qn;
        if step < 1e-12 {
            break;
        }
    }
    q
}

/// Wrap each joint by multiples of 2π into its limits where possible (preferring the value
/// closest to the original). Returns whether all joints ended within limits.
pub fn wrap_into_limits(q: &mut [f64], limits: &[(f64, f64)]) -> bool {
    let mut all = true;
    for (x, &(lo, hi)) in q.iter_mut().zip(limits.iter()) {
        let w = wrap(*x);
        let mut best: Option<f64> = None;
        for k in -3..=3 {
            let c = w + k as f64 * TAU;
            if c >= lo - 1e-12 && c <= hi + 1e-12 {
                let better = match best {
                    None => true,
                    Some(b) => (c - *x).abs() < (b - *x).abs(),
                };
                if better {
                    best = Some(c);
                }
            }
        }
        match best {
            Some(b) => *x = b.clamp(lo, hi),
            None => {
                *x = w;
                all = false;
            }
        }
    }
    all
}

/// Position tolerance of a returned solution (mm).
pub const IK_POS_TOL_MM: f64 = 1e-7;
/// Orientation tolerance of a returned solution (rad).
pub const IK_ROT_TOL_RAD: f64 = 1e-9;

/// All branches: closed form on the nominal family, Newton refinement on `model`.
pub fn solve(model: &KinematicModel, target: &Isometry3<f64>) -> Result<Vec<IkSolution>, IkError> {
    let t = target.translation.vector;
    if !(t.iter().all(|x| x.is_finite()) && target.rotation.coords.iter().all(|x| x.is_finite())) {
        return Err(IkError::NonFiniteTarget);
    }
    let fam = model
        .ik_family()
        .ok_or(IkError::NoClosedForm { dof: model.dof() })?;
    let seeds = fam.closed_form(target);
    let unreachable = |reason: &str| IkError::Unreachable {
        x_mm: t.x,
        y_mm: t.y,
        z_mm: t.z,
        reason: reason.to_string(),
    };
    if seeds.is_empty() {
        return Err(unreachable("no closed-form branch has a real solution"));
    }
    let limits = model.joint_limits();
    let mut sols = Vec::with_capacity(seeds.len());
    let (mut best_p, mut best_r) = (f64::INFINITY, f64::INFINITY);
    for (branch, q0) in seeds {
        let q0 = shift_seed(model, fam, target, branch, q0);
        let (mut q, ep, er) = refine(model, target, &q0, 100);
        if ep < best_p {
            best_p = ep;
            best_r = er;
        }
        if !(ep <= IK_POS_TOL_MM && er <= IK_ROT_TOL_RAD) || q.iter().any(|x| !x.is_finite()) {
            continue;
        }
        let within = wrap_into_limits(&mut q, &limits);
        sols.push(IkSolution {
            q,
            branch,
            label: BranchLabel::from_index(branch),
            within_limits: within,
            pos_err_mm: ep,
            rot_err_rad: er,
        });
    }
    if sols.is_empty() {
        if best_p > 1.0 {
            return Err(unreachable(
                "refinement on the model leaves > 1 mm on every branch",
            ));
        }
        return Err(IkError::NotConverged {
            pos_err_mm: best_p,
            rot_err_deg: best_r.to_degrees(),
        });
    }
    Ok(sols)
}
