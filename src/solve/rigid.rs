//! Closed-form rigid registration (Kabsch/Horn via SVD), rotation averaging and the
//! Park–Martin closed form of `AX = XB`. All lengths in mm, angles in radians.
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

use super::SolveError;

/// Nearest rotation (Frobenius) to a 3×3 matrix, det = +1.
pub fn project_rotation(m: &Matrix3<f64>) -> Rotation3<f64> {
    // Non-finite input would never converge in an unbounded SVD: identity instead (callers
    // check their inputs are finite; this is the last line of defence).
    if !m.iter().all(|x| x.is_finite()) {
        return Rotation3::identity();
    }
    let Some(svd) = nalgebra::SVD::try_new(*m, true, true, f64::EPSILON, 1000) else {
        return Rotation3::identity();
    };
    let (u, vt) = match (svd.u, svd.v_t) {
        (Some(u), Some(v)) => (u, v),
        _ => return Rotation3::identity(),
    };
    let d = (u * vt).determinant().signum();
    let s = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, if d == 0.0 { 1.0 } else { d }));
    Rotation3::from_matrix_unchecked(u * s * vt)
}

/// Least-squares rigid transform `T` with `T·a_i ≈ b_i` (Kabsch / Horn).
/// Needs ≥ 3 non-collinear points.
pub fn register_points(a: &[Point3<f64>], b: &[Point3<f64>]) -> Result<Isometry3<f64>, SolveError> {
    if a.len() != b.len() {
        return Err(SolveError::Invalid(format!(
            "register_points: {} vs {} points",
            a.len(),
            b.len()
        )));
    }
    if a.len() < 3 {
        return Err(SolveError::TooFewData {
            what: "rigid registration".into(),
            need: 3,
            got: a.len(),
        });
    }
    let n = a.len() as f64;
    let ca = a.iter().fold(Vector3::zeros(), |s, p| s + p.coords) / n;
    let cb = b.iter().fold(Vector3::zeros(), |s, p| s + p.coords) / n;
    let mut h = Matrix3::zeros();
    for (pa, pb) in a.iter().zip(b) {
        h += (pb.coords - cb) * (pa.coords - ca).transpose();
    }
    let sv = h.singular_values();
    if sv[1] <= 1e-9 * sv[0].max(1e-300) {
        return Err(SolveError::Degenerate(
            "rigid registration: points are collinear".into(),
        ));
    }
    let r = project_rotation(&h);
    let t = cb - r * ca;
    Ok(Isometry3::from_parts(
        Translation3::from(t),
        UnitQuaternion::from_rotation_matrix(&r),
    ))
}

/// Chordal L2 mean of rotations.
pub fn mean_rotation(rs: &[UnitQuaternion<f64>]) -> UnitQuaternion<f64> {
    let mut m = Matrix3::zeros();
    for r in rs {
        m += r.to_rotation_matrix().into_inner();
    }
    UnitQuaternion::from_rotation_matrix(&project_rotation(&m))
}

/// Mean of rigid transforms: chordal mean rotation, arithmetic mean translation.
pub fn mean_isometry(ts: &[Isometry3<f64>]) -> Isometry3<f64> {
    if ts.is_empty() {
        return Isometry3::identity();
    }
    let rs: Vec<_> = ts.iter().map(|t| t.rotation).collect();
    let t = ts
        .iter()
        .fold(Vector3::zeros(), |s, t| s + t.translation.vector)
        / ts.len() as f64;
    Isometry3::from_parts(Translation3::from(t), mean_rotation(&rs))
}

/// Solve `A_k X = X B_k` for `X` (Park & Martin 1994): the rotation registers the
/// rotation vectors `log(B_k)` onto `log(A_k)`; the translation solves the stacked
/// `(R_Ak − I) t_X = R_X t_Bk − t_Ak` by least squares. Needs ≥ 2 motions with
/// non-parallel rotation axes.
pub fn solve_ax_xb(
    a: &[Isometry3<f64>],
    b: &[Isometry3<f64>],
) -> Result<Isometry3<f64>, SolveError> {
    if a.len() != b.len() || a.len() < 2 {
        return Err(SolveError::TooFewData {
            what: "AX = XB".into(),
            need: 2,
            got: a.len().min(b.len()),
        });
    }
    let mut m = Matrix3::zeros();
    let mut used = 0;
    for (ak, bk) in a.iter().zip(b) {
        let al = ak.rotation.scaled_axis();
        let be = bk.rotation.scaled_axis();
        if al.norm() < 1e-6 || be.norm() < 1e-6 {
            continue;
        }
        m += al * be.transpose();
        used += 1;
    }
    if used < 2 || m.singular_values()[1] <= 1e-9 * m.norm() {
        return Err(SolveError::Degenerate(
            "AX = XB: fewer than two motions with distinct rotation axes".into(),
        ));
    }
    // The project's one Park–Martin implementation (the camera hand-eye's).
    let pairs: Vec<(Isometry3<f64>, Isometry3<f64>)> =
        a.iter().copied().zip(b.iter().copied()).collect();
    crate::solve::camera::handeye::solve(crate::solve::camera::handeye::Method::ParkMartin, &pairs)
        .ok_or_else(|| SolveError::Degenerate("AX = XB: translation unobservable".into()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn rand_iso(rng: &mut ChaCha8Rng, t: f64) -> Isometry3<f64> {
        let axis = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        Isometry3::new(
            Vector3::new(
                rng.random_range(-t..t),
                rng.random_range(-t..t),
                rng.random_range(-t..t),
            ),
            axis.normalize() * rng.random_range(0.2..2.5),
        )
    }

    #[test]
    fn kabsch_recovers_transform() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let t = rand_iso(&mut rng, 1000.0);
        let a: Vec<Point3<f64>> = (0..20)
            .map(|_| {
                Point3::new(
                    rng.random_range(-300.0..300.0),
                    rng.random_range(-300.0..300.0),
                    rng.random_range(-300.0..300.0),
                )
            })
            .collect();
        let b: Vec<_> = a.iter().map(|p| t * p).collect();
        let e = register_points(&a, &b).unwrap();
        assert!((e.translation.vector - t.translation.vector).norm() < 1e-9);
        assert!(e.rotation.angle_to(&t.rotation) < 1e-12);
    }

    #[test]
    fn kabsch_rejects_collinear_and_too_few() {
        let a: Vec<_> = (0..5).map(|i| Point3::new(i as f64, 0.0, 0.0)).collect();
        assert!(matches!(
            register_points(&a, &a),
            Err(SolveError::Degenerate(_))
        ));
        assert!(matches!(
            register_points(&a[..2], &a[..2]),
            Err(SolveError::TooFewData { .. })
        ));
    }

    #[test]
    fn ax_xb_recovers_x() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let x = rand_iso(&mut rng, 100.0);
        let bs: Vec<_> = (0..10).map(|_| rand_iso(&mut rng, 200.0)).collect();
        let as_: Vec<_> = bs.iter().map(|b| x * b * x.inverse()).collect();
        let e = solve_ax_xb(&as_, &bs).unwrap();
        assert!((e.translation.vector - x.translation.vector).norm() < 1e-8);
        assert!(e.rotation.angle_to(&x.rotation) < 1e-10);
    }

    #[test]
    fn rotation_mean_of_identical_is_identity_op() {
        let q = UnitQuaternion::from_euler_angles(0.3, -0.2, 1.0);
        let m = mean_rotation(&[q, q, q]);
        assert!(m.angle_to(&q) < 1e-12);
    }
}
