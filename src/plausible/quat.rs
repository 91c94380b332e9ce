//! The one quaternion check of every reader that takes quaternions: a file
//! quaternion `[w, x, y, z]` is finite and of unit norm (a non-unit one is Euler angles, a
//! rotation vector, wrong columns or a corrupted value — normalising it would silently turn
//! it into some other rotation), and, where the same rotations are also known from the robot
//! (a flange block, or the nominal FK of `q`), in the declared order: a tracked marker fixed
//! on the flange turns between two poses as the flange does, up to one fixed rotation; read
//! in the wrong order it does not, and read in the other order it does.
use nalgebra::{Isometry3, Matrix3, Quaternion, Translation3, UnitQuaternion, Vector3};

/// Largest accepted deviation of a file quaternion's norm from 1.
pub const NORM_TOL: f64 = 1e-3;

/// Median mismatch (deg) of relative rotation angles above which a set of quaternions does
/// not follow the robot's rotations (noise and the nominal model's errors stay far below).
pub const ORDER_MISMATCH_DEG: f64 = 2.0;

/// A file quaternion `[w, x, y, z]` as a unit quaternion; `Err` says why it is not one and
/// the likely cause.
pub fn unit_wxyz(q: &[f64; 4]) -> Result<UnitQuaternion<f64>, String> {
    if !q.iter().all(|x| x.is_finite()) {
        return Err(format!("quaternion {q:?} is not finite: a corrupted value"));
    }
    let v = Quaternion::new(q[0], q[1], q[2], q[3]);
    let n = v.norm();
    if !n.is_finite() || (n - 1.0).abs() > NORM_TOL {
        return Err(format!(
            "quaternion {q:?} has norm {n:.6e}, not 1: Euler angles or a rotation vector in the \
             quaternion fields, the wrong columns, or a corrupted value"
        ));
    }
    Ok(UnitQuaternion::from_quaternion(v))
}

/// A file pose (position mm, quaternion `[w, x, y, z]`): both finite, the quaternion unit.
pub fn pose(p: &[f64; 3], q: &[f64; 4]) -> Result<Isometry3<f64>, String> {
    if !p.iter().all(|x| x.is_finite()) {
        return Err(format!("position {p:?} is not finite: a corrupted value"));
    }
    Ok(Isometry3::from_parts(
        Translation3::new(p[0], p[1], p[2]),
        unit_wxyz(q)?,
    ))
}

/// `[w, x, y, z]` of a file quaternion written `[x, y, z, w]` (scalar last).
fn scalar_last(q: &[f64; 4]) -> UnitQuaternion<f64> {
    UnitQuaternion::from_quaternion(Quaternion::new(q[3], q[0], q[1], q[2]))
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        0.0
    } else {
        v[v.len() / 2]
    }
}

/// Median residual (deg) of the rotations between consecutive poses of a body rigidly
/// fixed to the flange against the flange's: `R_m = A R_f B` makes each relative rotation
/// `R_m,i-1ᵀ R_m,i = Bᵀ (R_f,i-1ᵀ R_f,i) B`, so the rotation vectors of the two agree after one
/// fixed rotation (fitted in closed form, Kabsch). Quaternions read in the wrong order break
/// that (a permutation of the components keeps the angles, not the axes).
fn rigid_residual_deg(robot: &[UnitQuaternion<f64>], body: &[UnitQuaternion<f64>]) -> f64 {
    let n = robot.len().min(body.len());
    let rel = |v: &[UnitQuaternion<f64>], i: usize| (v[i - 1].inverse() * v[i]).scaled_axis();
    let pairs: Vec<(Vector3<f64>, Vector3<f64>)> =
        (1..n).map(|i| (rel(robot, i), rel(body, i))).collect();
    let h = pairs
        .iter()
        .fold(Matrix3::zeros(), |h, (f, m)| h + m * f.transpose());
    let svd = h.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return f64::INFINITY;
    };
    let d = (u * vt).determinant().signum();
    let x = u * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * vt;
    median(
        pairs
            .iter()
            .map(|(f, m)| (m - x * f).norm().to_degrees())
            .collect(),
    )
}

/// How well a body's file quaternions follow the robot's rotations (see
/// [`rigid_residual_deg`]): the median residual (deg) as declared (`[w, x, y, z]`) and read
/// scalar-last. `robot[i]` is the flange rotation at the pose of `file[i]`.
pub fn order_mismatch_deg(robot: &[UnitQuaternion<f64>], file: &[[f64; 4]]) -> (f64, f64) {
    let decl: Vec<UnitQuaternion<f64>> = file
        .iter()
        .map(|q| UnitQuaternion::from_quaternion(Quaternion::new(q[0], q[1], q[2], q[3])))
        .collect();
    let alt: Vec<UnitQuaternion<f64>> = file.iter().map(scalar_last).collect();
    (
        rigid_residual_deg(robot, &decl),
        rigid_residual_deg(robot, &alt),
    )
}

/// Refuses quaternions in the wrong order: at least 5 poses that rotate, whose declared
/// reading does not follow the robot's rotations ([`ORDER_MISMATCH_DEG`]) while the
/// scalar-last reading does. `what` names the field. Returns the mismatches otherwise.
pub fn check_order(
    robot: &[UnitQuaternion<f64>],
    file: &[[f64; 4]],
    what: &str,
) -> Result<(), String> {
    if robot.len() < 5 || file.len() != robot.len() {
        return Ok(());
    }
    let turns = (1..robot.len())
        .filter(|&i| robot[i - 1].angle_to(&robot[i]).to_degrees() > 5.0)
        .count();
    if turns < 4 {
        return Ok(());
    }
    let (decl, alt) = order_mismatch_deg(robot, file);
    if decl > ORDER_MISMATCH_DEG && alt < 0.25 * decl {
        return Err(format!(
            "{what}: the quaternions look like [x, y, z, w] (scalar last): read as [w, x, y, z] \
             their rotations between poses differ from the robot's by {decl:.1}° (median, after \
             the best fixed mounting rotation), read scalar-last by {alt:.3}°; files use \
             [w, x, y, z]"
        ));
    }
    Ok(())
}

/// Where only pivot data exist (no robot rotation to compare with): a probe pivoting about a
/// fixed point fits `R_i·tip + p_i = pivot` to its noise when its rotations are read in the
/// right order, and misses by far more read in the other. Refuses frames (as read, `[w, x, y,
/// z]`) whose algebraic pivot fits more than 5 times worse, and worse than 1 mm RMS, than
/// with their quaternions read scalar-last. `what` names the records.
pub fn check_order_pivot(frames: &[Isometry3<f64>], what: &str) -> Result<(), String> {
    if frames.len() < 6 {
        return Ok(());
    }
    let alt: Vec<Isometry3<f64>> = frames
        .iter()
        .map(|f| {
            let c = f.rotation.as_ref().coords; // [x, y, z, w]
            Isometry3::from_parts(f.translation, scalar_last(&[c[3], c[0], c[1], c[2]]))
        })
        .collect();
    let fit = |f: &[Isometry3<f64>]| crate::solve::tool::pivot_algebraic(f).map(|r| r.rms_mm);
    let (Ok(decl), Ok(swapped)) = (fit(frames), fit(&alt)) else {
        return Ok(());
    };
    if decl > 1.0 && decl > 5.0 * swapped {
        return Err(format!(
            "{what}: the quaternions look like [x, y, z, w] (scalar last): read as [w, x, y, z] \
             the pivot fits with RMS {decl:.3} mm, read scalar-last with {swapped:.3} mm; files \
             use [w, x, y, z]"
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    /// A pivot recording written scalar-last is refused naming the order; as written, it
    /// passes.
    #[test]
    fn pivot_frames_in_the_wrong_quaternion_order_are_named() {
        let tip = Vector3::new(-14.0, 395.0, -7.0);
        let pivot = Vector3::new(100.0, -50.0, -1500.0);
        let frames: Vec<Isometry3<f64>> = (0..40)
            .map(|i| {
                let a = i as f64 * 0.37;
                let r = UnitQuaternion::from_euler_angles(0.4 * a.sin(), 0.4 * a.cos(), 0.2 * a);
                Isometry3::from_parts(Translation3::from(pivot - r * tip), r)
            })
            .collect();
        assert!(check_order_pivot(&frames, "pivot").is_ok());
        // The same file written [x, y, z, w] and read as [w, x, y, z].
        let wrong: Vec<Isometry3<f64>> = frames
            .iter()
            .map(|f| {
                let c = f.rotation.as_ref().coords;
                let q = UnitQuaternion::from_quaternion(Quaternion::new(c[0], c[1], c[2], c[3]));
                Isometry3::from_parts(f.translation, q)
            })
            .collect();
        let e = check_order_pivot(&wrong, "pivot").unwrap_err();
        assert!(e.contains("scalar last"), "{e}");
    }

    #[test]
    fn non_unit_and_non_finite_quaternions_are_named() {
        assert!(unit_wxyz(&[1.0, 0.0, 0.0, 0.0]).is_ok());
        let e = unit_wxyz(&[1e308, 0.0, 0.0, 0.0]).unwrap_err();
        assert!(e.contains("norm"), "{e}");
        let e = unit_wxyz(&[10.0, 20.0, 30.0, 0.0]).unwrap_err();
        assert!(e.contains("Euler"), "{e}");
        let e = unit_wxyz(&[f64::NAN, 0.0, 0.0, 1.0]).unwrap_err();
        assert!(e.contains("not finite"), "{e}");
        assert!(pose(&[f64::INFINITY, 0.0, 0.0], &[1.0, 0.0, 0.0, 0.0]).is_err());
    }

    #[test]
    fn scalar_last_quaternions_are_refused_the_declared_order_passes() {
        // A marker fixed on the flange, seen from a tracker: R_m = A R_f B.
        let a = UnitQuaternion::from_scaled_axis(Vector3::new(0.3, -1.2, 0.4));
        let b = UnitQuaternion::from_scaled_axis(Vector3::new(0.1, 0.5, -0.2));
        let robot: Vec<UnitQuaternion<f64>> = (0..12)
            .map(|i| {
                let t = i as f64;
                UnitQuaternion::from_scaled_axis(Vector3::new(
                    0.4 * (0.7 * t).sin(),
                    0.5 * (1.1 * t).cos(),
                    0.9 * (0.3 * t).sin(),
                ))
            })
            .collect();
        let wxyz: Vec<[f64; 4]> = robot
            .iter()
            .map(|r| {
                let q = (a * r * b).into_inner();
                [q.w, q.i, q.j, q.k]
            })
            .collect();
        assert!(check_order(&robot, &wxyz, "marker.quat").is_ok());
        let xyzw: Vec<[f64; 4]> = wxyz.iter().map(|q| [q[1], q[2], q[3], q[0]]).collect();
        let e = check_order(&robot, &xyzw, "marker.quat").unwrap_err();
        assert!(e.contains("[x, y, z, w]"), "{e}");
    }
}
