//! Classical `AX = XB` hand-eye solvers (Tsai–Lenz 1989, Park–Martin 1994, Daniilidis 1999)
//! and a planar-marker pose (homography + LM) for the instrument pose seen in the images: the
//! baselines the RCM method is compared with. The solvers are the camera hand-eye's
//! ([`crate::solve::camera::handeye`]): one implementation of each method in the project.
//!
//! Convention: `a[k] X = X b[k]`. For a camera fixed in the robot base (eye-to-hand) with the
//! instrument pose `Fᵢ` in the base (robot) and `Cᵢ` in the camera (images), `Fᵢ = X Cᵢ`, so
//! `A = Fᵢ Fⱼ⁻¹`, `B = Cᵢ Cⱼ⁻¹` and `X` is the camera in the base.
use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector2,
    Vector3,
};

use super::dual::{mulm, rotvec, Dual, Real, V3};
use super::plucker::Pinhole;
use super::RcmError;
use crate::solve::lm::{self, LsqProblem};

/// An `AX = XB` method.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// Tsai & Lenz 1989 (modified Rodrigues parameters, separable).
    Tsai,
    /// Park & Martin 1994 (log map, separable).
    Park,
    /// Daniilidis 1999 (dual quaternions, simultaneous).
    Daniilidis,
}

impl Method {
    /// All methods.
    pub const ALL: [Method; 3] = [Method::Tsai, Method::Park, Method::Daniilidis];
    /// Name.
    pub fn name(self) -> &'static str {
        match self {
            Method::Tsai => "Tsai",
            Method::Park => "Park",
            Method::Daniilidis => "Daniilidis",
        }
    }
}

/// All motion pairs `(A, B)` of `X Cᵢ = Fᵢ` (every `i < j`).
pub fn motions(
    f: &[Isometry3<f64>],
    c: &[Isometry3<f64>],
) -> (Vec<Isometry3<f64>>, Vec<Isometry3<f64>>) {
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for i in 0..f.len() {
        for j in i + 1..f.len() {
            a.push(f[i] * f[j].inverse());
            b.push(c[i] * c[j].inverse());
        }
    }
    (a, b)
}

/// Solve with `method` through the project's one set of `A X = X B` solvers
/// ([`crate::solve::camera::handeye`], same convention `a[k] X = X b[k]`).
pub fn solve(
    method: Method,
    a: &[Isometry3<f64>],
    b: &[Isometry3<f64>],
) -> Result<Isometry3<f64>, RcmError> {
    use crate::solve::camera::handeye::{self, Method as H};
    if a.len() < 2 {
        return Err(RcmError::TooFew { got: a.len() + 1 });
    }
    let shared = match method {
        Method::Tsai => H::TsaiLenz,
        Method::Park => H::ParkMartin,
        Method::Daniilidis => H::Daniilidis,
    };
    let pairs: Vec<(Isometry3<f64>, Isometry3<f64>)> =
        a.iter().copied().zip(b.iter().copied()).collect();
    handeye::solve(shared, &pairs).ok_or_else(|| {
        RcmError::Degenerate(format!(
            "{}: AX = XB is not determined by these motions (rotations about one axis, or too small)",
            method.name()
        ))
    })
}

/// Pose of a planar marker (points `(x, y, 0)` in the marker frame) from its pixels:
/// homography (DLT, normalised), decomposition, then LM on the reprojection error.
pub fn planar_pose(
    k: &Pinhole,
    model: &[[f64; 2]],
    px: &[[f64; 2]],
) -> Result<Isometry3<f64>, RcmError> {
    if model.len() < 4 || model.len() != px.len() {
        return Err(RcmError::Degenerate(format!(
            "marker pose: need ≥ 4 matching points, got {} / {}",
            model.len(),
            px.len()
        )));
    }
    let mut a = DMatrix::zeros(2 * model.len(), 9);
    for (i, (m, p)) in model.iter().zip(px).enumerate() {
        let r = k.ray(p[0], p[1]);
        let (x, y) = (m[0], m[1]);
        let (u, v) = (r.x, r.y);
        let row1 = [x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y, -u];
        let row2 = [0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y, -v];
        for c in 0..9 {
            a[(2 * i, c)] = row1[c];
            a[(2 * i + 1, c)] = row2[c];
        }
    }
    let e = (a.transpose() * &a).symmetric_eigen();
    let imin = e.eigenvalues.imin();
    let h = e.eigenvectors.column(imin);
    let hm = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let (c1, c2, c3) = (hm.column(0), hm.column(1), hm.column(2));
    let mut s = 2.0 / (c1.norm() + c2.norm());
    if c3.z * s < 0.0 {
        s = -s;
    }
    let r1 = (c1 * s).normalize();
    let r2 = (c2 * s - r1 * r1.dot(&(c2 * s))).normalize();
    let r = Matrix3::from_columns(&[r1, r2, r1.cross(&r2)]);
    let init = Isometry3::from_parts(Translation3::from(c3 * s), UnitQuaternion::from_matrix(&r));
    let p = PnP {
        k: *k,
        model: model.iter().map(|m| Vector2::new(m[0], m[1])).collect(),
        px: px.to_vec(),
        r0: init.rotation.to_rotation_matrix().into_inner(),
        t0: init.translation.vector,
    };
    let rep = lm::minimize(&p, DVector::zeros(6), &lm::LmOptions::default());
    if !rep.termination.converged() {
        return Err(RcmError::Solver(format!(
            "marker pose: {}",
            rep.termination.describe()
        )));
    }
    Ok(p.pose(&rep.x))
}

struct PnP {
    k: Pinhole,
    model: Vec<Vector2<f64>>,
    px: Vec<[f64; 2]>,
    r0: Matrix3<f64>,
    t0: Vector3<f64>,
}

impl PnP {
    fn pose(&self, x: &DVector<f64>) -> Isometry3<f64> {
        let r = Rotation3::new(Vector3::new(x[0], x[1], x[2])).into_inner() * self.r0;
        Isometry3::from_parts(
            Translation3::from(self.t0 + Vector3::new(x[3], x[4], x[5])),
            UnitQuaternion::from_matrix(&r),
        )
    }
    fn res<T: Real>(&self, x: &[T; 6]) -> Vec<T> {
        let r0 = [
            [self.r0[(0, 0)], self.r0[(0, 1)], self.r0[(0, 2)]],
            [self.r0[(1, 0)], self.r0[(1, 1)], self.r0[(1, 2)]],
            [self.r0[(2, 0)], self.r0[(2, 1)], self.r0[(2, 2)]],
        ];
        let mut out = Vec::with_capacity(2 * self.model.len());
        for (m, p) in self.model.iter().zip(&self.px) {
            let q: V3<T> = mulm(&r0, [T::c(m.x), T::c(m.y), T::c(0.0)]);
            let q = rotvec([x[0], x[1], x[2]], q);
            let c = [
                q[0] + T::c(self.t0.x) + x[3],
                q[1] + T::c(self.t0.y) + x[4],
                q[2] + T::c(self.t0.z) + x[5],
            ];
            out.push(T::c(self.k.fx) * c[0] / c[2] + T::c(self.k.cx - p[0]));
            out.push(T::c(self.k.fy) * c[1] / c[2] + T::c(self.k.cy - p[1]));
        }
        out
    }
}

impl LsqProblem for PnP {
    fn n_params(&self) -> usize {
        6
    }
    fn residuals(&self, x: &DVector<f64>) -> DVector<f64> {
        DVector::from_vec(self.res(&[x[0], x[1], x[2], x[3], x[4], x[5]]))
    }
    fn residuals_jacobian(&self, x: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
        let xd: [Dual<6>; 6] = std::array::from_fn(|a| Dual::var(x[a], a));
        let r = self.res(&xd);
        let mut j = DMatrix::zeros(r.len(), 6);
        for (i, v) in r.iter().enumerate() {
            for a in 0..6 {
                j[(i, a)] = v.b[a];
            }
        }
        (DVector::from_iterator(r.len(), r.iter().map(|v| v.a)), j)
    }
}

/// Marker points mapped into a pose (used by tests and by callers that carry a marker frame).
pub fn marker_in(pose: &Isometry3<f64>, m: &[f64; 2]) -> Point3<f64> {
    pose * Point3::new(m[0], m[1], 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn rand_iso(rng: &mut ChaCha8Rng, ang: f64, t: f64) -> Isometry3<f64> {
        Isometry3::new(
            Vector3::new(
                rng.random_range(-t..t),
                rng.random_range(-t..t),
                rng.random_range(-t..t),
            ),
            Vector3::new(
                rng.random_range(-ang..ang),
                rng.random_range(-ang..ang),
                rng.random_range(-ang..ang),
            ),
        )
    }

    #[test]
    fn all_methods_recover_x_exactly() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let x = rand_iso(&mut rng, 2.0, 300.0);
        let c: Vec<Isometry3<f64>> = (0..6).map(|_| rand_iso(&mut rng, 1.0, 100.0)).collect();
        let f: Vec<Isometry3<f64>> = c.iter().map(|ci| x * ci).collect();
        let (a, b) = motions(&f, &c);
        for m in Method::ALL {
            let e = solve(m, &a, &b).unwrap();
            let dt = (e.translation.vector - x.translation.vector).norm();
            let dr = e.rotation.angle_to(&x.rotation);
            assert!(dt < 1e-6 && dr < 1e-9, "{}: {dt} mm, {dr} rad", m.name());
        }
    }

    #[test]
    fn planar_pose_recovers_the_marker() {
        let k = Pinhole {
            fx: 700.0,
            fy: 710.0,
            cx: 320.0,
            cy: 240.0,
        };
        let truth = Isometry3::new(Vector3::new(5.0, -8.0, 90.0), Vector3::new(0.3, -0.4, 0.2));
        let model: Vec<[f64; 2]> = (0..9)
            .map(|i| [4.0 * (i % 3) as f64, 4.0 * (i / 3) as f64])
            .collect();
        let px: Vec<[f64; 2]> = model
            .iter()
            .map(|m| k.project(&marker_in(&truth, m).coords))
            .collect();
        let e = planar_pose(&k, &model, &px).unwrap();
        assert!((e.translation.vector - truth.translation.vector).norm() < 1e-6);
        assert!(e.rotation.angle_to(&truth.rotation) < 1e-8);
        let p = PnP {
            k,
            model: model.iter().map(|m| Vector2::new(m[0], m[1])).collect(),
            px,
            r0: e.rotation.to_rotation_matrix().into_inner(),
            t0: e.translation.vector,
        };
        let x = DVector::from_vec(vec![0.01, 0.02, -0.01, 0.5, 0.3, -1.0]);
        let (_, j) = p.residuals_jacobian(&x);
        let jn = lm::numeric_jacobian(|x| p.residuals(x), &x, 1e-6);
        assert!((&j - &jn).abs().max() < 1e-4, "{}", (&j - &jn).abs().max());
    }
}
