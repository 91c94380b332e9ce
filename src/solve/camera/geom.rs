//! Camera geometry kit: SO(3) exponential / logarithm and its left Jacobian, poses as
//! 6-vectors (rotation vector rad, translation mm), the OpenCV pinhole + Brown–Conrady
//! projection (k1, k2, p1, p2, k3) and the analytic derivatives the solvers need.
use nalgebra::{
    DMatrix, Isometry3, Matrix2x3, Matrix3, Point3, SMatrix, Translation3, UnitQuaternion, Vector3,
};

/// Number of intrinsic parameters: fx, fy, cx, cy, k1, k2, p1, p2, k3.
pub const N_INTR: usize = 9;

/// Camera intrinsics (px) and OpenCV distortion `[k1, k2, p1, p2, k3]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub dist: [f64; 5],
}

impl Intrinsics {
    /// As the parameter vector `[fx, fy, cx, cy, k1, k2, p1, p2, k3]`.
    pub fn to_vec(&self) -> [f64; N_INTR] {
        let d = self.dist;
        [
            self.fx, self.fy, self.cx, self.cy, d[0], d[1], d[2], d[3], d[4],
        ]
    }
    /// From the parameter vector of [`Self::to_vec`].
    pub fn from_slice(v: &[f64]) -> Self {
        Intrinsics {
            fx: v[0],
            fy: v[1],
            cx: v[2],
            cy: v[3],
            dist: [v[4], v[5], v[6], v[7], v[8]],
        }
    }
}

pub use crate::solve::so3::{exp_so3, left_jacobian, log_so3, skew};

/// A pose as `[ωx, ωy, ωz, tx, ty, tz]` (rotation vector rad, translation mm).
pub fn pose_to_vec(p: &Isometry3<f64>) -> [f64; 6] {
    let w = p.rotation.scaled_axis();
    let t = p.translation.vector;
    [w.x, w.y, w.z, t.x, t.y, t.z]
}

/// Right Jacobian of the rotation vector: `exp(w + dw) ≈ exp(w) · exp(J_r(w) dw)`, so a
/// covariance `C` of the rotation-vector parameters `w` ([`pose_to_vec`]) is, as small rotations
/// about the rotated frame's own axes, `J_r C J_rᵀ`. At a rotation of 90–180° the two differ by
/// far more than rounding (components mixed and scaled by up to 2/π).
pub fn right_jacobian(w: &Vector3<f64>) -> Matrix3<f64> {
    let t = w.norm();
    let k = w.cross_matrix();
    if t < 1e-8 {
        return Matrix3::identity() - 0.5 * k;
    }
    Matrix3::identity() - (1.0 - t.cos()) / (t * t) * k + (t - t.sin()) / (t * t * t) * (k * k)
}

/// A covariance `cov` (any size, rad / mm) of parameters whose rotation vectors start at the
/// indices `blocks` (each with its value `w`), restated as small rotations about each pose's own
/// axes (left and right multiplied by [`right_jacobian`] on those blocks).
pub fn cov_rotations_local(cov: &DMatrix<f64>, blocks: &[(usize, Vector3<f64>)]) -> DMatrix<f64> {
    let n = cov.nrows();
    let mut t = DMatrix::<f64>::identity(n, n);
    for (o, w) in blocks {
        if o + 3 <= n {
            t.view_mut((*o, *o), (3, 3)).copy_from(&right_jacobian(w));
        }
    }
    &t * cov * t.transpose()
}

/// The pose of a 6-vector of [`pose_to_vec`].
pub fn pose_from_slice(v: &[f64]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(v[3], v[4], v[5]),
        UnitQuaternion::from_scaled_axis(Vector3::new(v[0], v[1], v[2])),
    )
}

/// `y = R(ω) p + t` and `∂y/∂[ω, t]` (3×6).
pub fn transform_jac(v: &[f64], p: &Vector3<f64>) -> (Vector3<f64>, SMatrix<f64, 3, 6>) {
    PoseJac::new(v).transform_jac(p)
}

/// `y = R(ω)ᵀ (p − t)` (the inverse pose applied to `p`) and `∂y/∂[ω, t]` (3×6).
pub fn inv_transform_jac(v: &[f64], p: &Vector3<f64>) -> (Vector3<f64>, SMatrix<f64, 3, 6>) {
    PoseJac::new(v).inv_transform_jac(p)
}

/// A pose 6-vector's rotation, left Jacobian and translation, computed once per pose for the
/// derivatives of many points ([`transform_jac`] / [`inv_transform_jac`] recompute them per
/// call; the arithmetic is the same, so the results are bit-identical).
pub struct PoseJac {
    rot: nalgebra::Rotation3<f64>,
    l: Matrix3<f64>,
    t: Vector3<f64>,
}

impl PoseJac {
    pub fn new(v: &[f64]) -> Self {
        let w = Vector3::new(v[0], v[1], v[2]);
        PoseJac {
            rot: exp_so3(&w),
            l: left_jacobian(&w),
            t: Vector3::new(v[3], v[4], v[5]),
        }
    }

    /// As [`transform_jac`].
    pub fn transform_jac(&self, p: &Vector3<f64>) -> (Vector3<f64>, SMatrix<f64, 3, 6>) {
        let rp = self.rot * p;
        let y = rp + self.t;
        let mut j = SMatrix::<f64, 3, 6>::zeros();
        j.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(-skew(&rp) * self.l));
        j.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&Matrix3::identity());
        (y, j)
    }

    /// As [`inv_transform_jac`].
    pub fn inv_transform_jac(&self, p: &Vector3<f64>) -> (Vector3<f64>, SMatrix<f64, 3, 6>) {
        let rt = self.rot.transpose();
        let d = p - self.t;
        let y = rt * d;
        let mut j = SMatrix::<f64, 3, 6>::zeros();
        j.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(rt.matrix() * skew(&d) * self.l));
        j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-*rt.matrix()));
        (y, j)
    }
}

/// Project a camera-frame point (mm) to pixels; `None` behind the camera.
/// The same arithmetic as [`project_jac`] without the derivatives (the numeric-derivative
/// fits call it millions of times).
pub fn project(k: &Intrinsics, p: &Vector3<f64>) -> Option<[f64; 2]> {
    if p.z <= 1e-9 || !p.iter().all(|c| c.is_finite()) {
        return None;
    }
    let d = distort(k, p.x / p.z, p.y / p.z);
    Some([k.fx * d.xd + k.cx, k.fy * d.yd + k.cy])
}

/// Brown–Conrady distortion of the normalised point `(x, y)` and the powers of its radius.
struct Distorted {
    r2: f64,
    r4: f64,
    r6: f64,
    rad: f64,
    xd: f64,
    yd: f64,
}

#[inline(always)]
fn distort(k: &Intrinsics, x: f64, y: f64) -> Distorted {
    let [k1, k2, p1, p2, k3] = k.dist;
    let r2 = x * x + y * y;
    let r4 = r2 * r2;
    let r6 = r4 * r2;
    let rad = 1.0 + k1 * r2 + k2 * r4 + k3 * r6;
    let xd = x * rad + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
    let yd = y * rad + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
    Distorted {
        r2,
        r4,
        r6,
        rad,
        xd,
        yd,
    }
}

/// Pixel of camera-frame point `p`, its derivative with respect to `p` (2×3) and to the
/// intrinsics `[fx, fy, cx, cy, k1, k2, p1, p2, k3]` (2×9).
pub fn project_jac(
    k: &Intrinsics,
    p: &Vector3<f64>,
) -> Option<([f64; 2], Matrix2x3<f64>, SMatrix<f64, 2, N_INTR>)> {
    if p.z <= 1e-9 || !p.iter().all(|c| c.is_finite()) {
        return None;
    }
    let [k1, k2, p1, p2, k3] = k.dist;
    let (x, y) = (p.x / p.z, p.y / p.z);
    let Distorted {
        r2,
        r4,
        r6,
        rad,
        xd,
        yd,
    } = distort(k, x, y);
    let uv = [k.fx * xd + k.cx, k.fy * yd + k.cy];
    let dr = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r4;
    let dxd_dx = rad + 2.0 * x * x * dr + 2.0 * p1 * y + 6.0 * p2 * x;
    let dxd_dy = 2.0 * x * y * dr + 2.0 * p1 * x + 2.0 * p2 * y;
    let dyd_dx = 2.0 * x * y * dr + 2.0 * p1 * x + 2.0 * p2 * y;
    let dyd_dy = rad + 2.0 * y * y * dr + 6.0 * p1 * y + 2.0 * p2 * x;
    let iz = 1.0 / p.z;
    // ∂(x, y)/∂p
    let dn = Matrix2x3::new(iz, 0.0, -x * iz, 0.0, iz, -y * iz);
    let dd = nalgebra::Matrix2::new(k.fx * dxd_dx, k.fx * dxd_dy, k.fy * dyd_dx, k.fy * dyd_dy);
    let jp = dd * dn;
    let mut ji = SMatrix::<f64, 2, N_INTR>::zeros();
    ji[(0, 0)] = xd;
    ji[(1, 1)] = yd;
    ji[(0, 2)] = 1.0;
    ji[(1, 3)] = 1.0;
    let dxk = [x * r2, x * r4, 2.0 * x * y, r2 + 2.0 * x * x, x * r6];
    let dyk = [y * r2, y * r4, r2 + 2.0 * y * y, 2.0 * x * y, y * r6];
    for c in 0..5 {
        ji[(0, 4 + c)] = k.fx * dxk[c];
        ji[(1, 4 + c)] = k.fy * dyk[c];
    }
    Some((uv, jp, ji))
}

/// The camera-frame ray through pixel `(u, v)` at unit depth, undistorting by fixed-point
/// iteration (the inverse of [`project`] to ~1e-12 for moderate distortion).
pub fn unproject(k: &Intrinsics, u: f64, v: f64) -> Vector3<f64> {
    let [k1, k2, p1, p2, k3] = k.dist;
    let (xd, yd) = ((u - k.cx) / k.fx, (v - k.cy) / k.fy);
    let (mut x, mut y) = (xd, yd);
    for _ in 0..50 {
        let r2 = x * x + y * y;
        let rad = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
        let dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
        let dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
        x = (xd - dx) / rad;
        y = (yd - dy) / rad;
    }
    Vector3::new(x, y, 1.0)
}

/// Rotation angle (deg) of `a⁻¹ b` and translation distance (mm) between two poses.
pub fn pose_error(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    let d = a.inverse() * b;
    (
        (a.translation.vector - b.translation.vector).norm(),
        d.rotation.angle().to_degrees(),
    )
}

/// Average of poses: chordal-L2 mean rotation (quaternion eigenvector) and mean translation.
pub fn mean_pose(poses: &[Isometry3<f64>]) -> Isometry3<f64> {
    let mut m = nalgebra::Matrix4::<f64>::zeros();
    let mut t = Vector3::zeros();
    for p in poses {
        let q = p.rotation.coords; // (x, y, z, w)
        m += q * q.transpose();
        t += p.translation.vector;
    }
    let eig = m.symmetric_eigen();
    let (imax, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .fold((0, f64::MIN), |a, (i, &v)| if v > a.1 { (i, v) } else { a });
    let q = eig.eigenvectors.column(imax).into_owned();
    let rot = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[3], q[0], q[1], q[2]));
    Isometry3::from_parts(Translation3::from(t / poses.len().max(1) as f64), rot)
}

/// Board point of inner corner `(i, j)` (mm): `((i+1)·s, (j+1)·s, 0)` in the board frame
/// whose origin is the outer corner of the dark square `(0, 0)`.
pub fn board_point(i: usize, j: usize, square_mm: f64) -> Point3<f64> {
    Point3::new((i + 1) as f64 * square_mm, (j + 1) as f64 * square_mm, 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::lm::numeric_jacobian;
    use nalgebra::DVector;

    /// `exp(w)⁻¹ exp(w + h e_i) ≈ exp(h J_r e_i)`, at small and at 170° rotations; and the local
    /// covariance of a rotation-vector covariance differs from it at large angles.
    #[test]
    fn right_jacobian_matches_finite_differences() {
        for w in [
            Vector3::new(1e-10, 0.0, 0.0),
            Vector3::new(0.3, -0.2, 0.1),
            Vector3::new(0.4, 2.1, -1.6) * (170f64.to_radians() / 2.6856),
        ] {
            let jr = right_jacobian(&w);
            let r0 = UnitQuaternion::from_scaled_axis(w);
            let h = 1e-6;
            for i in 0..3 {
                let mut e = Vector3::zeros();
                e[i] = h;
                let d = (r0.inverse() * UnitQuaternion::from_scaled_axis(w + e)).scaled_axis() / h;
                assert!(
                    (d - jr.column(i)).norm() < 1e-5,
                    "{w} col {i}: {d} vs {}",
                    jr.column(i)
                );
            }
        }
        let w = Vector3::new(0.0, 0.0, 170f64.to_radians());
        let c = DMatrix::<f64>::identity(6, 6) * 1e-4;
        let local = cov_rotations_local(&c, &[(0, w)]);
        // About the axis itself unchanged; perpendicular components scaled by |J_r| < 1.
        assert!((local[(2, 2)] - 1e-4).abs() < 1e-12);
        assert!(local[(0, 0)] < 0.6e-4, "{}", local[(0, 0)]);
        assert_eq!(local[(4, 4)], 1e-4);
    }

    fn k0() -> Intrinsics {
        Intrinsics {
            fx: 900.0,
            fy: 905.0,
            cx: 321.0,
            cy: 239.0,
            dist: [-0.08, 0.05, 0.001, -0.002, 0.01],
        }
    }

    #[test]
    fn projection_jacobians_match_finite_differences() {
        let k = k0();
        let p = Vector3::new(80.0, -55.0, 400.0);
        let (_, jp, ji) = project_jac(&k, &p).unwrap();
        let fp = |x: &DVector<f64>| {
            let uv = project(&k, &Vector3::new(x[0], x[1], x[2])).unwrap();
            DVector::from_vec(uv.to_vec())
        };
        let n = numeric_jacobian(fp, &DVector::from_vec(vec![p.x, p.y, p.z]), 1e-4);
        let e = (n - jp).abs().max();
        assert!(e < 1e-6, "point {e}");
        let fi = |x: &DVector<f64>| {
            let uv = project(&Intrinsics::from_slice(x.as_slice()), &p).unwrap();
            DVector::from_vec(uv.to_vec())
        };
        let n = numeric_jacobian(fi, &DVector::from_row_slice(&k.to_vec()), 1e-6);
        let e = (n - ji).abs().max();
        assert!(e < 1e-4, "intrinsics {e}");
    }

    /// `project` (no derivatives) gives `project_jac`'s pixel to the bit, and refuses what it
    /// refuses.
    #[test]
    fn project_is_project_jac_without_the_derivatives() {
        let k = k0();
        for i in 0..200 {
            let t = i as f64;
            let p = Vector3::new(
                300.0 * (0.37 * t).sin(),
                250.0 * (0.53 * t).cos(),
                50.0 + 7.0 * t,
            );
            let a = project(&k, &p).expect("in front");
            let (b, _, _) = project_jac(&k, &p).expect("in front");
            assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits), "{p:?}");
        }
        for p in [
            Vector3::new(1.0, 2.0, 0.0),
            Vector3::new(f64::NAN, 0.0, 10.0),
        ] {
            assert!(project(&k, &p).is_none() && project_jac(&k, &p).is_none());
        }
    }

    #[test]
    fn pose_jacobians_match_finite_differences() {
        let v = [0.3, -1.2, 2.1, 10.0, -20.0, 300.0];
        let p = Vector3::new(12.0, -7.0, 33.0);
        for inv in [false, true] {
            let f = |x: &DVector<f64>| {
                let (y, _) = if inv {
                    inv_transform_jac(x.as_slice(), &p)
                } else {
                    transform_jac(x.as_slice(), &p)
                };
                DVector::from_column_slice(y.as_slice())
            };
            let (_, ja) = if inv {
                inv_transform_jac(&v, &p)
            } else {
                transform_jac(&v, &p)
            };
            let n = numeric_jacobian(f, &DVector::from_row_slice(&v), 1e-6);
            let e = (n - ja).abs().max();
            assert!(e < 1e-6, "inv {inv}: {e}");
        }
    }

    #[test]
    fn unproject_inverts_project() {
        let k = k0();
        let p = Vector3::new(80.0, -55.0, 400.0);
        let uv = project(&k, &p).unwrap();
        let r = unproject(&k, uv[0], uv[1]);
        assert!((r - p / p.z).norm() < 1e-10);
    }
}
