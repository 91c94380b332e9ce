//! Beyond seed 002: maximum-likelihood refinement of the camera pose on the segment end points.
//!
//! For pose `i` the robot gives the shaft axis in the base (the instrument frame's origin and
//! z axis). With the camera pose `T_bc` (camera in base) the axis in the camera is known, and
//! so are the two silhouette lines of the cylinder of radius `r` (the tangent planes through
//! the camera centre). The residuals are the signed pixel distances of the four observed end
//! points from their predicted silhouette lines; with Gaussian pixel noise on the end points
//! their least squares is the maximum-likelihood estimate of `T_bc`. Parameters: a rotation
//! vector `w` (in the base, `R = exp(w) R₀`) and the translation `t` (mm).
use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Matrix6, Rotation3, Translation3, UnitQuaternion, Vector3,
};

use super::dual::{cross, cv, dot, mulm, rotvec, scale, sub, unit, Dual, Real, V3};
use super::plucker::{Line, Pinhole};
use super::RcmError;
use crate::solve::lm::{self, LsqProblem};

/// The ML problem.
pub struct MlProblem {
    /// Intrinsics.
    pub k: Pinhole,
    /// Shaft radius (mm).
    pub r: f64,
    /// Instrument axes in the base (from the robot).
    pub axes: Vec<Line>,
    /// Observed segments.
    pub segs: Vec<[[f64; 4]; 2]>,
    /// Which predicted line (`+` → false, `−` → true) the first segment belongs to.
    pub swap: Vec<bool>,
    /// Linearisation point.
    pub r0: Matrix3<f64>,
    /// Linearisation point.
    pub t0: Vector3<f64>,
}

fn rows(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    [
        [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
        [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
        [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
    ]
}

/// Predicted silhouette lines (pixel homogeneous, `[a, b, c]` with `a u + b v + c = 0`) of the
/// cylinder of radius `r` around the camera-frame axis `(p, d)`.
pub fn silhouettes<T: Real>(k: &Pinhole, r: f64, p: V3<T>, d: V3<T>) -> [[T; 3]; 2] {
    let d = unit(d);
    let m = cross(p, d);
    let rho = dot(m, m).sqrt();
    let mh = scale(T::c(1.0) / rho, m);
    let q = cross(d, mh);
    let s = T::c(r) / rho;
    let c = (T::c(1.0) - s * s).sqrt();
    let line = |sg: f64| {
        let n = [
            c * mh[0] + T::c(sg) * s * q[0],
            c * mh[1] + T::c(sg) * s * q[1],
            c * mh[2] + T::c(sg) * s * q[2],
        ];
        let a = n[0] / T::c(k.fx);
        let b = n[1] / T::c(k.fy);
        [a, b, n[2] - T::c(k.cx) * a - T::c(k.cy) * b]
    };
    [line(1.0), line(-1.0)]
}

fn dist<T: Real>(l: &[T; 3], u: f64, v: f64) -> T {
    (l[0] * T::c(u) + l[1] * T::c(v) + l[2]) / (l[0] * l[0] + l[1] * l[1]).sqrt()
}

impl MlProblem {
    /// Builds the problem at the camera pose `init` and fixes which observed segment is which
    /// predicted silhouette (the closer assignment at `init`).
    pub fn new(
        k: Pinhole,
        r: f64,
        axes: Vec<Line>,
        segs: Vec<[[f64; 4]; 2]>,
        init: &Isometry3<f64>,
    ) -> MlProblem {
        let mut p = MlProblem {
            k,
            r,
            swap: vec![false; axes.len()],
            axes,
            segs,
            r0: init.rotation.to_rotation_matrix().into_inner(),
            t0: init.translation.vector,
        };
        let z = [0.0; 6];
        for i in 0..p.axes.len() {
            let a: f64 = p.pose_res(i, &z, false).iter().map(|x| x * x).sum();
            let b: f64 = p.pose_res(i, &z, true).iter().map(|x| x * x).sum();
            p.swap[i] = b < a;
        }
        p
    }

    fn pose_res<T: Real>(&self, i: usize, x: &[T; 6], swap: bool) -> [T; 4] {
        let w = [-x[0], -x[1], -x[2]];
        let t0: V3<T> = cv(self.t0.into());
        let t = [t0[0] + x[3], t0[1] + x[4], t0[2] + x[5]];
        let rt = rows(&self.r0.transpose());
        let ax = &self.axes[i];
        let o: V3<T> = cv(ax.foot().into());
        let pc = mulm(&rt, rotvec(w, sub(o, t)));
        let dc = mulm(&rt, rotvec(w, cv(ax.d.into())));
        let sil = silhouettes(&self.k, self.r, pc, dc);
        let (la, lb) = if swap {
            (&sil[1], &sil[0])
        } else {
            (&sil[0], &sil[1])
        };
        let s = &self.segs[i];
        [
            dist(la, s[0][0], s[0][1]),
            dist(la, s[0][2], s[0][3]),
            dist(lb, s[1][0], s[1][1]),
            dist(lb, s[1][2], s[1][3]),
        ]
    }

    /// The camera pose (camera in base) at parameters `x`.
    pub fn pose(&self, x: &DVector<f64>) -> Isometry3<f64> {
        let r = Rotation3::new(Vector3::new(x[0], x[1], x[2])).into_inner() * self.r0;
        Isometry3::from_parts(
            Translation3::from(self.t0 + Vector3::new(x[3], x[4], x[5])),
            UnitQuaternion::from_matrix(&r),
        )
    }
}

impl LsqProblem for MlProblem {
    fn n_params(&self) -> usize {
        6
    }
    fn residuals(&self, x: &DVector<f64>) -> DVector<f64> {
        let xs = [x[0], x[1], x[2], x[3], x[4], x[5]];
        let mut r = Vec::with_capacity(4 * self.axes.len());
        for i in 0..self.axes.len() {
            r.extend_from_slice(&self.pose_res(i, &xs, self.swap[i]));
        }
        DVector::from_vec(r)
    }
    fn residuals_jacobian(&self, x: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
        let xd: [Dual<6>; 6] = std::array::from_fn(|a| Dual::var(x[a], a));
        let n = self.axes.len();
        let mut r = DVector::zeros(4 * n);
        let mut j = DMatrix::zeros(4 * n, 6);
        for i in 0..n {
            for (row, v) in self.pose_res(i, &xd, self.swap[i]).iter().enumerate() {
                r[4 * i + row] = v.a;
                for a in 0..6 {
                    j[(4 * i + row, a)] = v.b[a];
                }
            }
        }
        (r, j)
    }
}

/// Result of the ML refinement.
#[derive(Debug, Clone)]
pub struct MlFit {
    /// Camera in base.
    pub pose: Isometry3<f64>,
    /// Covariance of `(w [rad], t [mm])` (σ² from the residual).
    pub cov: Matrix6<f64>,
    /// RMS end-point distance (px).
    pub rms_px: f64,
    /// Solver termination.
    pub termination: lm::Termination,
    /// Residuals (px), 4 per pose.
    pub residuals: Vec<f64>,
}

/// Refine the camera pose from `init` (two LM rounds: the second re-decides which segment is
/// which silhouette at the first's result).
pub fn refine(
    k: Pinhole,
    r: f64,
    axes: &[Line],
    segs: &[[[f64; 4]; 2]],
    init: &Isometry3<f64>,
) -> Result<MlFit, RcmError> {
    let mut pose = *init;
    let mut last = None;
    for _ in 0..2 {
        let p = MlProblem::new(k, r, axes.to_vec(), segs.to_vec(), &pose);
        let rep = lm::minimize(&p, DVector::zeros(6), &lm::LmOptions::default());
        if !rep.termination.converged() {
            return Err(RcmError::Solver(format!(
                "ML refinement: {}",
                rep.termination.describe()
            )));
        }
        pose = p.pose(&rep.x);
        last = Some(rep);
    }
    let rep = last.expect("two rounds");
    let n = rep.residuals.len();
    let dof = n.saturating_sub(6).max(1);
    let s2 = rep.residuals.norm_squared() / dof as f64;
    let jtj = rep.jacobian.transpose() * &rep.jacobian;
    let inv = jtj.clone().try_inverse().ok_or_else(|| {
        RcmError::Degenerate(
            "the camera pose is not determined by the silhouettes (singular normal matrix)".into(),
        )
    })?;
    let cov = Matrix6::from_iterator((inv * s2).iter().copied());
    Ok(MlFit {
        pose,
        cov,
        rms_px: (rep.residuals.norm_squared() / n.max(1) as f64).sqrt(),
        termination: rep.termination,
        residuals: rep.residuals.iter().copied().collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ml_jacobian_matches_finite_differences() {
        let k = Pinhole {
            fx: 800.0,
            fy: 780.0,
            cx: 320.0,
            cy: 250.0,
        };
        let cam = Isometry3::new(
            Vector3::new(100.0, -50.0, 300.0),
            Vector3::new(2.5, 0.3, -0.2),
        );
        let rcm = Vector3::new(120.0, -40.0, 150.0);
        let mut axes = Vec::new();
        let mut segs = Vec::new();
        for i in 0..5 {
            let a = i as f64;
            let d = Vector3::new(0.2 * a.cos(), 0.2 * a.sin(), -1.0);
            axes.push(Line::through(&rcm, &d));
            segs.push([
                [300.0 + a, 200.0, 350.0, 260.0 + a],
                [320.0, 190.0 - a, 370.0, 255.0],
            ]);
        }
        let p = MlProblem::new(k, 4.0, axes, segs, &cam);
        let x = DVector::from_vec(vec![0.01, -0.02, 0.015, 1.0, -2.0, 0.5]);
        let (r, j) = p.residuals_jacobian(&x);
        assert!((r - p.residuals(&x)).norm() < 1e-9);
        let jn = lm::numeric_jacobian(|x| p.residuals(x), &x, 1e-6);
        let err = (&j - &jn).abs().max();
        assert!(
            err < 1e-5 * (1.0 + jn.abs().max()),
            "max |J - J_fd| = {err}"
        );
    }
}
