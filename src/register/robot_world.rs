//! Tracker ↔ robot base: the robot-world / hand-eye problem `A_i X = Y B_i` with
//! `A_i = T_base_flange` (robot), `X = T_flange_marker` (marker on the flange),
//! `Y = T_base_tracker` (tracker in the base) and `B_i = T_tracker_marker` (measured).
//!
//! - [`shah`]: Shah (2013), rotations from the top singular pair of `Σ R(A_i⁻¹) ⊗ R(B_i⁻¹)`,
//!   translations by linear least squares.
//! - [`li`]: Li, Wang & Wu (2010), one linear least-squares system in both rotations (as
//!   free 3×3 matrices, then projected) and both translations.
//! - [`tsai_route`]: seed 003's route: Tsai–Lenz `AX = XB` on relative motions of the
//!   inverted robot poses gives `Y`; `X` is then the chordal mean of `A_i⁻¹ Y B_i`.
//! - [`refine`]: joint maximum-likelihood refinement of `(X, Y)` on the one LM solver
//!   ([`RobotWorldProblem`]), weighted by the tracker noise model; covariance of `Y`.
//!
//! [`check`] is the quick on-site registration check: ~20 poses, nominal kinematics, and the
//! change against a previous `Y` at the working volume.
//!
//! The closed forms follow the published equations in the conventions of OpenCV's
//! `calibrateRobotWorldHandEye` (`cTw = B⁻¹`, `gTb = A⁻¹`, outputs `wTb = Y⁻¹`, `cTg = X⁻¹`),
//! so the peer check compares the same numbers.
#![allow(clippy::type_complexity)] // (points, normals, ...) tuples of parallel vectors
use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Matrix6, Point3, SMatrix, Translation3, UnitQuaternion,
    Vector3,
};
use serde::{Deserialize, Serialize};

use super::file::{cov_from_file, cov_to_file, COV_ORDER};
use super::icp::invert_covariance;
use super::paired::{iso_to_rows, perturb, rows_to_iso};
use super::tracker_model::StereoTrackerModel;
use super::{skew, so3_left_jacobian, RegisterError};
use crate::solve::lm::{self, LmOptions, LsqProblem};
use crate::solve::rigid::project_rotation;

/// One robot pose and its tracker measurement.
#[derive(Debug, Clone, PartialEq)]
pub struct RwObs {
    pub id: u64,
    /// `T_base_flange` (mm).
    pub a: Isometry3<f64>,
    /// `T_tracker_marker` (mm).
    pub b: Isometry3<f64>,
}

fn iso(r: &Matrix3<f64>, t: &Vector3<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::from(*t), UnitQuaternion::from_matrix(r))
}

fn rot(i: &Isometry3<f64>) -> Matrix3<f64> {
    i.rotation.to_rotation_matrix().into_inner()
}

fn kron3(a: &Matrix3<f64>, b: &Matrix3<f64>) -> SMatrix<f64, 9, 9> {
    let mut k = SMatrix::<f64, 9, 9>::zeros();
    for r in 0..3 {
        for c in 0..3 {
            k.fixed_view_mut::<3, 3>(3 * r, 3 * c)
                .copy_from(&(b * a[(r, c)]));
        }
    }
    k
}

/// OpenCV-style normalisation: unit determinant with the sign of det, then the nearest
/// rotation.
fn normalize_rotation(m: &Matrix3<f64>) -> Result<Matrix3<f64>, RegisterError> {
    let d = m.determinant();
    if !d.is_finite() || d.abs() <= f32::EPSILON as f64 {
        return Err(RegisterError::Degenerate(
            "robot-world: rotation estimate has a null determinant (too little rotation in the poses)".into(),
        ));
    }
    let s = (d.signum() / d.abs()).cbrt();
    Ok(project_rotation(&(m * s)).into_inner())
}

fn check_obs(obs: &[RwObs], need: usize, what: &str) -> Result<(), RegisterError> {
    if obs.len() < need {
        return Err(RegisterError::Degenerate(format!(
            "{what}: {} poses; need at least {need} with rotations about different axes",
            obs.len()
        )));
    }
    Ok(())
}

/// The likely cause of a degenerate robot-world estimate, read from the poses: a flange that
/// barely turns between poses while the marker does (radians read as degrees) or at all (one
/// held orientation); marker rotations that do not follow the flange's up to a fixed mounting
/// ([`crate::plausible::quat::order_mismatch_deg`]: quaternion order, another frame, a marker
/// that moved); rotations about one axis only.
pub fn rotation_cause(obs: &[RwObs]) -> String {
    let Some(first) = obs.first() else {
        return "likely cause: no pose".into();
    };
    let (mut ta, mut tb, mut axes) = (Vec::new(), Vec::new(), Vec::new());
    // The rotation angle between two poses is the same for the flange and the marker.
    for o in &obs[1..] {
        let ra = first.a.rotation.inverse() * o.a.rotation;
        let rb = first.b.rotation.inverse() * o.b.rotation;
        ta.push(ra.angle().to_degrees());
        tb.push(rb.angle().to_degrees());
        if let Some(ax) = ra.axis().filter(|_| ra.angle() > 1f64.to_radians()) {
            axes.push(ax.into_inner());
        }
    }
    let max = |v: &[f64]| v.iter().cloned().fold(0.0, f64::max);
    let (amax, bmax) = (max(&ta), max(&tb));
    if bmax >= 10.0 && amax < 0.2 * bmax {
        return format!(
            "likely cause: the flange turns at most {amax:.2}° between poses while the marker \
             turns up to {bmax:.1}°: the robot's rotations are likely in radians where degrees \
             are expected, or the flange poses are not the robot's"
        );
    }
    if amax < 2.0 {
        return format!(
            "likely cause: the flange turns at most {amax:.2}° between poses; record poses \
             turned by 30° or more about at least two different axes"
        );
    }
    let robot: Vec<UnitQuaternion<f64>> = obs.iter().map(|o| o.a.rotation).collect();
    let file: Vec<[f64; 4]> = obs
        .iter()
        .map(|o| {
            let q = o.b.rotation.into_inner();
            [q.w, q.i, q.j, q.k]
        })
        .collect();
    let (decl, alt) = crate::plausible::quat::order_mismatch_deg(&robot, &file);
    if decl > crate::plausible::quat::ORDER_MISMATCH_DEG {
        return if alt < 0.25 * decl {
            format!(
                "likely cause: the marker's quaternions look like [x, y, z, w] (scalar last): \
                 read as [w, x, y, z] their rotations between poses differ from the flange's by \
                 {decl:.1}° (median), read scalar-last by {alt:.3}°; files use [w, x, y, z]"
            )
        } else {
            format!(
                "likely cause: the marker's rotations between poses do not follow the flange's \
                 (median difference {decl:.1}°): the marker poses are in another frame, belong \
                 to other robot poses, or the marker moved on the flange"
            )
        };
    }
    let mut scatter = Matrix3::zeros();
    for a in &axes {
        scatter += a * a.transpose();
    }
    let eig = scatter.symmetric_eigen();
    let mut ev: Vec<(f64, Vector3<f64>)> = eig
        .eigenvalues
        .iter()
        .zip(eig.eigenvectors.column_iter())
        .map(|(l, v)| (*l, v.into_owned()))
        .collect();
    ev.sort_by(|a, b| b.0.total_cmp(&a.0));
    if !axes.is_empty() && ev[1].0 < 0.02 * ev[0].0 {
        let v = ev[0].1;
        return format!(
            "likely cause: every rotation between poses is about one axis (flange \
             ({:.2}, {:.2}, {:.2})); turn the flange about a second axis by 30° or more",
            v.x, v.y, v.z
        );
    }
    format!(
        "likely cause: the rotations between poses (up to {amax:.1}°) are too small or too \
         alike; add poses turned by 30° or more about different axes"
    )
}

fn with_cause(e: RegisterError, obs: &[RwObs]) -> RegisterError {
    match e {
        RegisterError::Degenerate(m) => {
            RegisterError::Degenerate(format!("{m}; {}", rotation_cause(obs)))
        }
        e => e,
    }
}

/// Shah (2013). Returns `(X, Y)`; a degenerate set of poses is refused with its likely cause
/// ([`rotation_cause`]).
pub fn shah(obs: &[RwObs]) -> Result<(Isometry3<f64>, Isometry3<f64>), RegisterError> {
    shah_closed(obs).map_err(|e| with_cause(e, obs))
}

fn shah_closed(obs: &[RwObs]) -> Result<(Isometry3<f64>, Isometry3<f64>), RegisterError> {
    check_obs(obs, 3, "Shah")?;
    let mut k = SMatrix::<f64, 9, 9>::zeros();
    for o in obs {
        k += kron3(&rot(&o.a.inverse()), &rot(&o.b.inverse()));
    }
    let svd = k.svd(true, true);
    let (u, vt) = (svd.u.unwrap(), svd.v_t.unwrap());
    let i = svd.singular_values.imax();
    // Column-major reshapes of the top singular vectors.
    let mut w = Matrix3::zeros();
    let mut c = Matrix3::zeros();
    for a in 0..3 {
        for b in 0..3 {
            w[(b, a)] = vt[(i, 3 * a + b)];
            c[(b, a)] = u[(3 * a + b, i)];
        }
    }
    let w = normalize_rotation(&w)?; // R of T_tracker_base
    let c = normalize_rotation(&c)?; // R of T_marker_flange
    let n = obs.len();
    let mut am = DMatrix::zeros(3 * n, 6);
    let mut bv = DVector::zeros(3 * n);
    for (i, o) in obs.iter().enumerate() {
        let bi = o.b.inverse();
        let ai = o.a.inverse();
        am.fixed_view_mut::<3, 3>(3 * i, 0).copy_from(&(-rot(&bi)));
        am.fixed_view_mut::<3, 3>(3 * i, 3)
            .copy_from(&Matrix3::identity());
        let rhs = bi.translation.vector - c * ai.translation.vector;
        bv.fixed_rows_mut::<3>(3 * i).copy_from(&rhs);
    }
    let t = lstsq(&am, &bv)?;
    let wtb = Vector3::new(t[0], t[1], t[2]);
    let ctg = Vector3::new(t[3], t[4], t[5]);
    Ok((iso(&c, &ctg).inverse(), iso(&w, &wtb).inverse()))
}

/// Li, Wang & Wu (2010). Returns `(X, Y)`; a degenerate set of poses is refused with its
/// likely cause ([`rotation_cause`]).
pub fn li(obs: &[RwObs]) -> Result<(Isometry3<f64>, Isometry3<f64>), RegisterError> {
    li_closed(obs).map_err(|e| with_cause(e, obs))
}

fn li_closed(obs: &[RwObs]) -> Result<(Isometry3<f64>, Isometry3<f64>), RegisterError> {
    check_obs(obs, 3, "Li")?;
    let n = obs.len();
    let mut am = DMatrix::zeros(12 * n, 24);
    let mut bv = DVector::zeros(12 * n);
    let i3 = Matrix3::identity();
    for (i, o) in obs.iter().enumerate() {
        let bi = o.b.inverse();
        let ai = o.a.inverse();
        let (rb, tb) = (rot(&bi), bi.translation.vector);
        let (ra, ta) = (rot(&ai), ai.translation.vector);
        am.fixed_view_mut::<9, 9>(12 * i, 0)
            .copy_from(&kron3(&rb, &i3));
        am.fixed_view_mut::<9, 9>(12 * i, 9)
            .copy_from(&kron3(&(-i3), &ra.transpose()));
        // kron(I3, taᵀ): 3×9
        for r in 0..3 {
            for k in 0..3 {
                am[(12 * i + 9 + r, 9 + 3 * r + k)] = ta[k];
            }
        }
        am.fixed_view_mut::<3, 3>(12 * i + 9, 18).copy_from(&(-rb));
        am.fixed_view_mut::<3, 3>(12 * i + 9, 21).copy_from(&i3);
        bv.fixed_rows_mut::<3>(12 * i + 9).copy_from(&tb);
    }
    let x = lstsq(&am, &bv)?;
    let w = Matrix3::from_row_slice(&x.as_slice()[0..9]);
    let c = Matrix3::from_row_slice(&x.as_slice()[9..18]);
    let w = normalize_rotation(&w)?;
    let c = normalize_rotation(&c)?;
    let wtb = Vector3::new(x[18], x[19], x[20]);
    let ctg = Vector3::new(x[21], x[22], x[23]);
    Ok((iso(&c, &ctg).inverse(), iso(&w, &wtb).inverse()))
}

fn lstsq(a: &DMatrix<f64>, b: &DVector<f64>) -> Result<DVector<f64>, RegisterError> {
    crate::solve::so3::lstsq_full_rank(a, b).map_err(|rank| {
        RegisterError::Degenerate(format!(
            "robot-world: the poses determine only {rank} of {} unknowns (rotate about at least two different axes)",
            a.ncols()
        ))
    })
}

pub use crate::solve::axxb::OPENCV_TSAI_MIN_MOTION;

/// Tsai & Lenz (1989) `A X = X B` for `X` from absolute poses `hg` (as OpenCV's
/// `gripper2base`) and `hc` (`target2cam`), over all pairs ([`crate::solve::axxb`]).
pub fn tsai_lenz(
    hg: &[Isometry3<f64>],
    hc: &[Isometry3<f64>],
) -> Result<Isometry3<f64>, RegisterError> {
    tsai_lenz_min_motion(hg, hc, 0.0)
}

/// [`tsai_lenz`] over only the pairs whose gripper motion `|2 sin(θ/2)| ≥ min_motion`
/// ([`crate::solve::axxb::tsai_lenz_min_motion`]).
pub fn tsai_lenz_min_motion(
    hg: &[Isometry3<f64>],
    hc: &[Isometry3<f64>],
    min_motion: f64,
) -> Result<Isometry3<f64>, RegisterError> {
    crate::solve::axxb::tsai_lenz_min_motion(hg, hc, min_motion).map_err(|e| match e {
        crate::solve::axxb::AxxbError::Degenerate(m) => RegisterError::Degenerate(m),
    })
}

/// The navigation chain's route: Tsai–Lenz on `(A_i⁻¹, B_i)` gives `Y = T_base_tracker`; `X`
/// is the mean of `A_i⁻¹ Y B_i`. Returns `(X, Y)`.
pub fn tsai_route(obs: &[RwObs]) -> Result<(Isometry3<f64>, Isometry3<f64>), RegisterError> {
    tsai_route_min_motion(obs, 0.0)
}

/// [`tsai_route`] with [`tsai_lenz_min_motion`]'s pair filter.
pub fn tsai_route_min_motion(
    obs: &[RwObs],
    min_motion: f64,
) -> Result<(Isometry3<f64>, Isometry3<f64>), RegisterError> {
    let hg: Vec<_> = obs.iter().map(|o| o.a.inverse()).collect();
    let hc: Vec<_> = obs.iter().map(|o| o.b).collect();
    let y = tsai_lenz_min_motion(&hg, &hc, min_motion).map_err(|e| with_cause(e, obs))?;
    let xs: Vec<_> = obs.iter().map(|o| o.a.inverse() * y * o.b).collect();
    Ok((crate::solve::rigid::mean_isometry(&xs), y))
}

/// Joint refinement problem. Parameters: left perturbations of `Z = Y⁻¹ = T_tracker_base`
/// (0..6) and of `X` (6..12). Residuals per pose: whitened position of the predicted marker
/// `Z A_i X` minus the measured one (tracker frame) and the chordal rotation difference
/// `vec(R_Z R_A R_X − R_B) / (√2 σ_rot)` (a small rotation `δ` moves the chordal entries by
/// `‖[δ]× R‖_F² = 2|δ|²`, so this weight gives each pose the information of its angle).
pub struct RobotWorldProblem<'a> {
    pub obs: &'a [RwObs],
    pub z0: Isometry3<f64>,
    pub x0: Isometry3<f64>,
    /// Whitening of each position residual (`Σ^{-1/2}`).
    pub w: Vec<Matrix3<f64>>,
    /// Orientation noise per axis (rad).
    pub sigma_rot: f64,
}

impl RobotWorldProblem<'_> {
    fn unpack(&self, v: &DVector<f64>) -> (Isometry3<f64>, Isometry3<f64>) {
        (
            perturb(&self.z0, &v.as_slice()[0..6]),
            perturb(&self.x0, &v.as_slice()[6..12]),
        )
    }
}

impl LsqProblem for RobotWorldProblem<'_> {
    fn n_params(&self) -> usize {
        12
    }
    fn residuals(&self, v: &DVector<f64>) -> DVector<f64> {
        self.residuals_jacobian(v).0
    }
    fn residuals_jacobian(&self, v: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
        let (z, x) = self.unpack(v);
        let wz = Vector3::new(v[0], v[1], v[2]);
        let wx = Vector3::new(v[6], v[7], v[8]);
        let (jlz, jlx) = (so3_left_jacobian(&wz), so3_left_jacobian(&wx));
        let n = self.obs.len();
        let mut r = DVector::zeros(12 * n);
        let mut j = DMatrix::zeros(12 * n, 12);
        let (rz, rx) = (rot(&z), rot(&x));
        for (i, o) in self.obs.iter().enumerate() {
            let ra = rot(&o.a);
            let pa = ra * x.translation.vector + o.a.translation.vector; // marker in base
            let pred = rz * pa + z.translation.vector;
            let w = self.w[i];
            let base = 12 * i;
            r.fixed_rows_mut::<3>(base)
                .copy_from(&(w * (pred - o.b.translation.vector)));
            j.fixed_view_mut::<3, 3>(base, 0)
                .copy_from(&(w * (-skew(&(rz * pa)) * jlz)));
            j.fixed_view_mut::<3, 3>(base, 3).copy_from(&w);
            j.fixed_view_mut::<3, 3>(base, 9).copy_from(&(w * rz * ra));
            let m = rz * ra * rx;
            let sr = self.sigma_rot * std::f64::consts::SQRT_2;
            let d = (m - rot(&o.b)) / sr;
            for c in 0..3 {
                for rr in 0..3 {
                    r[base + 3 + 3 * c + rr] = d[(rr, c)];
                }
            }
            for k in 0..3 {
                let gz = skew(&jlz.column(k).into_owned()) * m / sr;
                let gx = rz * ra * skew(&jlx.column(k).into_owned()) * rx / sr;
                for c in 0..3 {
                    for rr in 0..3 {
                        j[(base + 3 + 3 * c + rr, k)] = gz[(rr, c)];
                        j[(base + 3 + 3 * c + rr, 6 + k)] = gx[(rr, c)];
                    }
                }
            }
        }
        (r, j)
    }
}

/// Refinement options.
#[derive(Debug, Clone, Copy)]
pub struct RefineOptions {
    /// Tracker noise model (position weights); without one, isotropic `sigma_pos_mm`.
    pub tracker_model: Option<StereoTrackerModel>,
    /// Position noise per axis (mm) when no model is given; also added to the robot side.
    pub sigma_pos_mm: f64,
    /// Orientation noise per axis (deg).
    pub sigma_rot_deg: f64,
}

impl Default for RefineOptions {
    fn default() -> Self {
        RefineOptions {
            tracker_model: None,
            sigma_pos_mm: 0.1,
            sigma_rot_deg: 0.05,
        }
    }
}

/// Refined `(X, Y)` with the covariance of `Y` (left perturbation of `T_base_tracker`,
/// rad / mm) and of `X`, and residual statistics.
#[derive(Debug, Clone)]
pub struct RobotWorld {
    pub x: Isometry3<f64>,
    pub y: Isometry3<f64>,
    pub cov_y: Matrix6<f64>,
    pub cov_x: Matrix6<f64>,
    pub rms_pos_mm: f64,
    pub rms_rot_deg: f64,
    /// Per-pose position residual (mm).
    pub pos_residuals_mm: Vec<f64>,
    /// Reduced χ² of the whitened residuals (≈ 1 when the noise model is right).
    pub chi2_reduced: f64,
}

/// Joint LM refinement of `(X, Y)` from a closed-form start.
pub fn refine(
    obs: &[RwObs],
    start: (Isometry3<f64>, Isometry3<f64>),
    o: &RefineOptions,
) -> Result<RobotWorld, RegisterError> {
    check_obs(obs, 3, "robot-world refinement")?;
    if let Some(m) = &o.tracker_model {
        m.validate()?;
    }
    if !(o.sigma_pos_mm > 0.0 && o.sigma_rot_deg > 0.0) {
        return Err(RegisterError::Invalid(
            "robot-world: position and rotation sigmas must be > 0".into(),
        ));
    }
    let w: Vec<Matrix3<f64>> = obs
        .iter()
        .map(|ob| {
            let p = Point3::from(ob.b.translation.vector);
            let c = o
                .tracker_model
                .map(|m| m.covariance(&p))
                .unwrap_or_else(Matrix3::zeros)
                + Matrix3::identity() * o.sigma_pos_mm.powi(2);
            c.try_inverse()
                .and_then(|i| i.cholesky())
                .map(|ch| ch.l().transpose())
                .unwrap_or_else(|| Matrix3::identity() / o.sigma_pos_mm)
        })
        .collect();
    let (x0, y0) = start;
    let prob = RobotWorldProblem {
        obs,
        z0: y0.inverse(),
        x0,
        w,
        sigma_rot: o.sigma_rot_deg.to_radians(),
    };
    let rep = lm::minimize(&prob, DVector::zeros(12), &LmOptions::default());
    if !rep.termination.converged() {
        return Err(RegisterError::Solver(format!(
            "robot-world refinement: {}",
            rep.termination.describe()
        )));
    }
    let (z, x) = prob.unpack(&rep.x);
    let (r, j) = prob.residuals_jacobian(&rep.x);
    let jtj = j.transpose() * &j;
    let cov = jtj
        .try_inverse()
        .ok_or_else(|| RegisterError::Degenerate("robot-world covariance singular".into()))?;
    let dof = (r.len() as f64 - 12.0).max(1.0);
    let chi2 = r.norm_squared() / dof;
    // Without a noise model the residual scale is estimated.
    let scale = if o.tracker_model.is_some() { 1.0 } else { chi2 };
    let cov_z = Matrix6::from_fn(|a, b| cov[(a, b)] * scale);
    let cov_x = Matrix6::from_fn(|a, b| cov[(6 + a, 6 + b)] * scale);
    let y = z.inverse();
    let cov_y = invert_covariance(&z, &cov_z);
    let mut pos = Vec::new();
    let mut rot2 = 0.0;
    for ob in obs {
        let pred = z * ob.a * x;
        pos.push((pred.translation.vector - ob.b.translation.vector).norm());
        rot2 += pred.rotation.angle_to(&ob.b.rotation).powi(2);
    }
    let n = obs.len() as f64;
    Ok(RobotWorld {
        x,
        y,
        cov_y,
        cov_x,
        rms_pos_mm: (pos.iter().map(|p| p * p).sum::<f64>() / n).sqrt(),
        rms_rot_deg: (rot2 / n).sqrt().to_degrees(),
        pos_residuals_mm: pos,
        chi2_reduced: chi2,
    })
}

/// Format tag of the tracker ↔ robot file.
pub use crate::schema::ROBOT_WORLD_FORMAT;

/// One closed-form estimate in the file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClosedForm {
    pub method: String,
    #[serde(rename = "T_base_tracker")]
    pub t_base_tracker: Vec<f64>,
    #[serde(rename = "T_flange_marker")]
    pub t_flange_marker: Vec<f64>,
}

/// `robot_world.json` (`robocal-robot-world/1`): mm, degrees; covariances as in
/// `registration.json` (left perturbation, deg / mm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotWorldFile {
    pub format: String,
    #[serde(rename = "T_base_tracker")]
    pub t_base_tracker: super::file::TransformWithCov,
    #[serde(rename = "T_flange_marker")]
    pub t_flange_marker: super::file::TransformWithCov,
    pub n_poses: usize,
    pub rms_pos_mm: f64,
    pub rms_rot_deg: f64,
    pub chi2_reduced: f64,
    pub closed_forms: Vec<ClosedForm>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tracker_model: Option<StereoTrackerModel>,
}

impl RobotWorldFile {
    /// The file of a refined solution and its closed-form starts.
    pub fn new(
        rw: &RobotWorld,
        n: usize,
        closed: &[(&str, (Isometry3<f64>, Isometry3<f64>))],
        model: Option<StereoTrackerModel>,
    ) -> Self {
        let twc = |t: &Isometry3<f64>, c: &Matrix6<f64>| super::file::TransformWithCov {
            matrix: iso_to_rows(t).to_vec(),
            covariance: Some(cov_to_file(c)),
            covariance_order: Some(COV_ORDER.replace("tracker frame", "left frame")),
            covariance_ct: None,
            covariance_tracker: None,
        };
        RobotWorldFile {
            format: ROBOT_WORLD_FORMAT.into(),
            t_base_tracker: twc(&rw.y, &rw.cov_y),
            t_flange_marker: twc(&rw.x, &rw.cov_x),
            n_poses: n,
            rms_pos_mm: rw.rms_pos_mm,
            rms_rot_deg: rw.rms_rot_deg,
            chi2_reduced: rw.chi2_reduced,
            closed_forms: closed
                .iter()
                .map(|(m, (x, y))| ClosedForm {
                    method: m.to_string(),
                    t_base_tracker: iso_to_rows(y).to_vec(),
                    t_flange_marker: iso_to_rows(x).to_vec(),
                })
                .collect(),
            tracker_model: model,
        }
    }

    /// `Y = T_base_tracker` and its covariance (rad, mm).
    pub fn y(&self) -> Result<(Isometry3<f64>, Matrix6<f64>), RegisterError> {
        let t = rows_to_iso(&self.t_base_tracker.matrix, "T_base_tracker.matrix")?;
        let c = match &self.t_base_tracker.covariance {
            Some(v) => cov_from_file(v, "T_base_tracker.covariance")?,
            None => Matrix6::zeros(),
        };
        Ok((t, c))
    }

    /// Reads and checks a file.
    pub fn load(path: &std::path::Path) -> Result<Self, RegisterError> {
        let text = crate::fsio::read_to_string(path).map_err(|e| super::io_err(path, e))?;
        let f: RobotWorldFile = serde_json::from_str(&text).map_err(|e| RegisterError::Input {
            file: path.display().to_string(),
            line: e.line(),
            msg: crate::schema::kind::with_other_kind(
                format_args!("{e} (expected a `{ROBOT_WORLD_FORMAT}` file)"),
                &text,
                ROBOT_WORLD_FORMAT,
            ),
        })?;
        if f.format != ROBOT_WORLD_FORMAT {
            return Err(RegisterError::Input {
                file: path.display().to_string(),
                line: 1,
                msg: format!(
                    "field `format`: `{}` is not `{ROBOT_WORLD_FORMAT}`",
                    f.format
                ),
            });
        }
        f.y().map_err(|e| RegisterError::Input {
            file: path.display().to_string(),
            line: 0,
            msg: e.to_string(),
        })?;
        Ok(f)
    }

    /// Writes the file.
    pub fn save(&self, path: &std::path::Path) -> Result<(), RegisterError> {
        let s = serde_json::to_string_pretty(self)
            .map_err(|e| RegisterError::Invalid(format!("serialising: {e}")))?;
        crate::fsio::write(path, s + "\n").map_err(|e| super::io_err(path, e))
    }
}

/// Result of the on-site registration check against a previous `Y`.
#[derive(Debug, Clone)]
pub struct CheckResult {
    /// Rotation change (deg).
    pub rot_change_deg: f64,
    /// Largest displacement (mm) of the poses' marker positions (base frame) mapped by the
    /// old vs the new `Y`.
    pub max_shift_mm: f64,
    /// The shift in units of the new estimate's 95 % uncertainty at those points.
    pub shift_sigma: f64,
    pub pass: bool,
}

/// Compares a new `Y` (with covariance) with a previous one at the marker positions of
/// the check poses; passes when the largest shift ≤ `tol_mm`.
pub fn check(rw: &RobotWorld, prev_y: &Isometry3<f64>, obs: &[RwObs], tol_mm: f64) -> CheckResult {
    let mut max_shift: f64 = 0.0;
    let mut max_sig: f64 = 0.0;
    for o in obs {
        let p_trk = Point3::from(o.b.translation.vector);
        let d = (rw.y * p_trk - prev_y * p_trk).norm();
        let j = super::paired::point_jacobian(&rw.y, &p_trk);
        let c = j * rw.cov_y * j.transpose();
        let s = c.trace().sqrt().max(1e-12);
        max_shift = max_shift.max(d);
        max_sig = max_sig.max(d / s);
    }
    CheckResult {
        rot_change_deg: rw.y.rotation.angle_to(&prev_y.rotation).to_degrees(),
        max_shift_mm: max_shift,
        shift_sigma: max_sig,
        pass: max_shift <= tol_mm,
    }
}

/// Observations from a dataset: `A_i` from the record's `flange` pose when present, else
/// the nominal forward kinematics of `q` (header robot); `B_i` from the marker `p` + `quat`.
/// Records without a visible marker with orientation are skipped (returned with reasons).
pub fn observations_from_dataset(
    ds: &crate::dataset::Dataset,
) -> Result<(Vec<RwObs>, Vec<(u64, String)>), RegisterError> {
    let model = crate::model::KinematicModel::from_robot_block(&ds.header.robot).ok();
    let mut out = Vec::new();
    let mut skipped = Vec::new();
    let fin = |v: &[f64]| v.iter().all(|x| x.is_finite());
    for r in ds.poses() {
        let a = if let Some(f) = &r.flange {
            match crate::plausible::quat::pose(&f.p, &f.quat) {
                Ok(a) => a,
                Err(e) => {
                    skipped.push((r.id, format!("flange: {e}")));
                    continue;
                }
            }
        } else if let (Some(q), Some(m)) = (&r.q, &model) {
            if q.len() != m.dof() || !fin(q) {
                skipped.push((r.id, "bad `q`".into()));
                continue;
            }
            let qr: Vec<f64> = q.iter().map(|d| d.to_radians()).collect();
            m.flange_pose(&qr)
        } else {
            skipped.push((r.id, "neither `flange` nor usable `q` + robot model".into()));
            continue;
        };
        let Some(mk) = r.marker.as_ref().filter(|m| m.visible) else {
            skipped.push((r.id, "marker not visible".into()));
            continue;
        };
        let (Some(p), Some(qm)) = (mk.p, mk.quat) else {
            skipped.push((r.id, "marker without `p` and `quat`".into()));
            continue;
        };
        let b = match crate::plausible::quat::pose(&p, &qm) {
            Ok(b) => b,
            Err(e) => {
                skipped.push((r.id, format!("marker: {e}")));
                continue;
            }
        };
        out.push(RwObs { id: r.id, a, b });
    }
    Ok((out, skipped))
}

/// Why poses were skipped, most common first (`N × reason`), with the likely cause of the
/// most common one ("0 usable poses" names the cause, not the symptom).
pub fn skip_summary(skipped: &[(u64, String)]) -> String {
    let mut counts: Vec<(&str, usize)> = vec![];
    for (_, w) in skipped {
        match counts.iter_mut().find(|(k, _)| *k == w.as_str()) {
            Some((_, n)) => *n += 1,
            None => counts.push((w.as_str(), 1)),
        }
    }
    counts.sort_by_key(|c| std::cmp::Reverse(c.1));
    let Some((top, _)) = counts.first() else {
        return "no pose records".into();
    };
    let cause = if top.contains("not visible") {
        "the tracker did not see the marker (the wrong tool, or the marker outside the tracker's \
         volume)"
    } else if top.contains("without `p` and `quat`") {
        "the records carry marker positions only: robot-world needs each marker's orientation \
         (`marker.quat`)"
    } else if top.contains("neither `flange`") || top.contains("bad `q`") {
        "no robot pose: the records need a `flange` block, or `q` in degrees with a robot model \
         robocal knows"
    } else if top.contains("quaternion") || top.contains("not finite") {
        "corrupt values in the file"
    } else {
        "see the reasons"
    };
    let list: Vec<String> = counts
        .iter()
        .take(3)
        .map(|(k, n)| format!("{n} × {k}"))
        .collect();
    format!("skipped {}; likely cause: {cause}", list.join(", "))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    pub(crate) fn synth(
        n: usize,
        noise: f64,
        seed: u64,
    ) -> (Vec<RwObs>, Isometry3<f64>, Isometry3<f64>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let x = Isometry3::new(
            Vector3::new(20.0, -10.0, 80.0),
            Vector3::new(0.1, 0.3, -0.2),
        );
        let y = Isometry3::new(
            Vector3::new(1500.0, 200.0, 400.0),
            Vector3::new(0.2, -1.4, 0.3),
        );
        let obs = (0..n)
            .map(|i| {
                let a = Isometry3::new(
                    Vector3::new(
                        rng.random_range(300.0..600.0),
                        rng.random_range(-200.0..200.0),
                        rng.random_range(200.0..500.0),
                    ),
                    Vector3::new(
                        rng.random_range(-0.6..0.6),
                        rng.random_range(-0.6..0.6) + 3.0,
                        rng.random_range(-0.6..0.6),
                    ),
                );
                let mut b = y.inverse() * a * x;
                let e = Vector3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                );
                b.translation.vector += e * noise;
                b.rotation = UnitQuaternion::from_scaled_axis(e * noise * 1e-3) * b.rotation;
                RwObs { id: i as u64, a, b }
            })
            .collect();
        (obs, x, y)
    }

    /// A degenerate set of poses names its likely cause, not "too little
    /// rotation": rotations about one axis, quaternions in the wrong order, radians.
    #[test]
    fn degenerate_poses_name_their_likely_cause() {
        let (obs, x, y) = synth(12, 0.0, 3);
        // One axis: every flange orientation about the base z axis.
        let one: Vec<RwObs> = obs
            .iter()
            .enumerate()
            .map(|(i, o)| {
                let mut a = o.a;
                a.rotation = UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3 * i as f64);
                RwObs {
                    id: o.id,
                    a,
                    b: y.inverse() * a * x,
                }
            })
            .collect();
        let c = rotation_cause(&one);
        assert!(c.contains("about one axis"), "{c}");
        let err = li(&one).unwrap_err().to_string();
        assert!(
            err.contains("likely cause") && err.contains("one axis"),
            "{err}"
        );
        // The marker's quaternions read scalar-first as scalar-last.
        let swapped: Vec<RwObs> = obs
            .iter()
            .map(|o| {
                let q = o.b.rotation.into_inner().coords;
                let mut b = o.b;
                b.rotation = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
                    q[0], q[1], q[2], q[3],
                ));
                RwObs { b, ..o.clone() }
            })
            .collect();
        let c = rotation_cause(&swapped);
        assert!(c.contains("[x, y, z, w]"), "{c}");
        // Flange rotations in radians read as degrees: the flange barely turns.
        let rad: Vec<RwObs> = obs
            .iter()
            .map(|o| {
                let mut a = o.a;
                a.rotation = UnitQuaternion::from_scaled_axis(
                    o.a.rotation.scaled_axis() * std::f64::consts::PI / 180.0,
                );
                RwObs { a, ..o.clone() }
            })
            .collect();
        let c = rotation_cause(&rad);
        assert!(c.contains("radians"), "{c}");
        // Good poses: only the generic advice (never called on them by the solvers).
        assert!(shah(&obs).is_ok());
    }

    #[test]
    fn closed_forms_recover_exact_data() {
        let (obs, x, y) = synth(15, 0.0, 1);
        type Solver = fn(&[RwObs]) -> Result<(Isometry3<f64>, Isometry3<f64>), RegisterError>;
        let solvers: [(&str, Solver); 3] = [("shah", shah), ("li", li), ("tsai", tsai_route)];
        for (name, f) in solvers {
            let (xe, ye) = f(&obs).unwrap();
            assert!(
                (ye.translation.vector - y.translation.vector).norm() < 1e-6,
                "{name} Y"
            );
            assert!(ye.rotation.angle_to(&y.rotation) < 1e-9, "{name} Y rot");
            assert!(
                (xe.translation.vector - x.translation.vector).norm() < 1e-6,
                "{name} X"
            );
        }
    }

    #[test]
    fn refinement_jacobian_matches_fd_and_improves_noisy_start() {
        let (obs, x, y) = synth(20, 0.3, 2);
        let prob = RobotWorldProblem {
            obs: &obs,
            z0: y.inverse(),
            x0: x,
            w: vec![Matrix3::identity() * 3.0; obs.len()],
            sigma_rot: 0.001,
        };
        let v = DVector::from_iterator(12, (0..12).map(|k| 0.01 * (k as f64 - 5.0)));
        let (_, ja) = prob.residuals_jacobian(&v);
        let jn = lm::numeric_jacobian(|v| prob.residuals(v), &v, 1e-6);
        let rel = (&ja - &jn).norm() / ja.norm();
        assert!(rel < 1e-6, "{rel}");
        let start = shah(&obs).unwrap();
        let rw = refine(&obs, start, &RefineOptions::default()).unwrap();
        assert!((rw.y.translation.vector - y.translation.vector).norm() < 2.0);
        assert!(rw.rms_pos_mm < 0.6, "{}", rw.rms_pos_mm);
    }
}
