//! `A X = X B` (hand-eye) and `A X = Y B` (robot-world) closed forms shared by the camera
//! hand-eye ([`crate::solve::camera::handeye`]) and the tracker ↔ robot registration
//! ([`crate::register::robot_world`]): Tsai & Lenz (1989) on pairs of relative motions.
use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};

use super::so3::{lstsq_full_rank, skew};

/// Why the motions do not determine `X`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AxxbError {
    /// Too few motions, or motions about too few axes.
    #[error("{0}")]
    Degenerate(String),
}

/// OpenCV ≥ 4.10's pair filter for Tsai (PR opencv#24897): motions whose rotation
/// `|2 sin(θ/2)|` is below this (θ ≈ 17.25°) are dropped as uninformative.
pub const OPENCV_TSAI_MIN_MOTION: f64 = 0.3;

/// `2 sin(θ/2)·axis` of a rotation (OpenCV's `2·rot2quatMinimal`), sign with `w ≥ 0`.
pub fn quat_minimal2(r: &UnitQuaternion<f64>) -> Vector3<f64> {
    let q = if r.w < 0.0 {
        -r.into_inner()
    } else {
        r.into_inner()
    };
    2.0 * Vector3::new(q.i, q.j, q.k)
}

fn rot(i: &Isometry3<f64>) -> Matrix3<f64> {
    i.rotation.to_rotation_matrix().into_inner()
}

fn degenerate(rank: usize, n: usize) -> AxxbError {
    AxxbError::Degenerate(format!(
        "robot-world: the poses determine only {rank} of {n} unknowns (rotate about at least two different axes)"
    ))
}

/// Tsai & Lenz `A X = X B` on relative motions `(A, B)`: the rotation from the modified
/// Rodrigues vectors (`[p_A + p_B]× p' = p_B − p_A`), then the translation by least squares
/// (`(R_A − I) t = R t_B − t_A`). Needs at least two motions about different axes.
pub fn tsai_lenz_pairs(
    pairs: &[(Isometry3<f64>, Isometry3<f64>)],
) -> Result<Isometry3<f64>, AxxbError> {
    let k = pairs.len();
    if k < 2 {
        return Err(AxxbError::Degenerate(format!(
            "Tsai: {k} pose pairs, need ≥ 2"
        )));
    }
    let mut a = DMatrix::zeros(3 * k, 3);
    let mut b = DVector::zeros(3 * k);
    for (idx, (ma, mb)) in pairs.iter().enumerate() {
        let (pg, pc) = (quat_minimal2(&ma.rotation), quat_minimal2(&mb.rotation));
        a.fixed_view_mut::<3, 3>(3 * idx, 0)
            .copy_from(&skew(&(pg + pc)));
        b.fixed_rows_mut::<3>(3 * idx).copy_from(&(pc - pg));
    }
    let p_ = lstsq_full_rank(&a, &b).map_err(|r| degenerate(r, 3))?;
    let p_ = Vector3::new(p_[0], p_[1], p_[2]);
    let pcg = 2.0 * p_ / (1.0 + p_.norm_squared()).sqrt();
    let q = pcg / 2.0;
    let w = (1.0 - q.norm_squared()).max(0.0).sqrt();
    let rcg = 2.0 * q * q.transpose()
        + 2.0 * w * skew(&q)
        + Matrix3::identity() * (1.0 - 2.0 * q.norm_squared());
    for (idx, (ma, mb)) in pairs.iter().enumerate() {
        a.fixed_view_mut::<3, 3>(3 * idx, 0)
            .copy_from(&(rot(ma) - Matrix3::identity()));
        b.fixed_rows_mut::<3>(3 * idx)
            .copy_from(&(rcg * mb.translation.vector - ma.translation.vector));
    }
    let t = lstsq_full_rank(&a, &b).map_err(|r| degenerate(r, 3))?;
    Ok(Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_matrix(&rcg),
    ))
}

/// Tsai & Lenz `A X = X B` for `X` from absolute poses `hg` (as OpenCV's `gripper2base`) and
/// `hc` (`target2cam`), over the pairs whose gripper motion `|2 sin(θ/2)| ≥ min_motion`
/// (`0.0`: all pairs, the 1989 paper and OpenCV < 4.10; [`OPENCV_TSAI_MIN_MOTION`]: OpenCV ≥
/// 4.10). On noise-free poses both give the same `X`; on noisy poses they are different
/// estimators (the dropped pairs carry little rotation information but still weigh in the
/// least squares).
pub fn tsai_lenz_min_motion(
    hg: &[Isometry3<f64>],
    hc: &[Isometry3<f64>],
    min_motion: f64,
) -> Result<Isometry3<f64>, AxxbError> {
    let n = hg.len();
    if n < 3 || hc.len() != n {
        return Err(AxxbError::Degenerate(format!("Tsai: {n} poses, need ≥ 3")));
    }
    let mut pairs = Vec::with_capacity(n * (n - 1) / 2);
    for i in 0..n {
        for j in i + 1..n {
            let hgij = hg[j].inverse() * hg[i];
            if quat_minimal2(&hgij.rotation).norm() >= min_motion {
                pairs.push((hgij, hc[j] * hc[i].inverse()));
            }
        }
    }
    if pairs.len() < 2 {
        return Err(AxxbError::Degenerate(format!(
            "Tsai: {} pose pairs rotate by |2 sin(θ/2)| ≥ {min_motion}, need ≥ 2",
            pairs.len()
        )));
    }
    tsai_lenz_pairs(&pairs)
}
