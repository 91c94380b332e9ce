//! The small SO(3) / linear-algebra helpers every solver shares: the cross-product matrix,
//! the exponential and logarithm of rotation vectors, the left Jacobian, and a rank-checked
//! least-squares solve.
use nalgebra::{DMatrix, DVector, Matrix3, Rotation3, Vector3};

/// `[v]×`: the matrix of `x ↦ v × x`.
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Rotation of a rotation vector (rad).
pub fn exp_so3(w: &Vector3<f64>) -> Rotation3<f64> {
    Rotation3::new(*w)
}

/// Rotation vector (rad) of a rotation.
pub fn log_so3(r: &Rotation3<f64>) -> Vector3<f64> {
    r.scaled_axis()
}

/// Left Jacobian of SO(3): `Exp(w + δ) ≈ Exp(J_l(w) δ) Exp(w)`. Below 1e-6 rad the series
/// (to second order) is exact to double precision.
pub fn left_jacobian(w: &Vector3<f64>) -> Matrix3<f64> {
    let th = w.norm();
    let k = skew(w);
    if th < 1e-6 {
        return Matrix3::identity() + 0.5 * k + k * k / 6.0;
    }
    let (s, c) = th.sin_cos();
    Matrix3::identity() + (1.0 - c) / (th * th) * k + (th - s) / (th * th * th) * (k * k)
}

/// `min |A x − b|` by SVD when `A` has full column rank (singular values above `1e-12·σ_max`);
/// `Err(rank)` when it does not (the data do not determine every unknown).
pub fn lstsq_full_rank(a: &DMatrix<f64>, b: &DVector<f64>) -> Result<DVector<f64>, usize> {
    let svd = a.clone().svd(true, true);
    let smax = svd.singular_values.max();
    let rank = svd
        .singular_values
        .iter()
        .filter(|s| **s > smax * 1e-12)
        .count();
    if rank < a.ncols() {
        return Err(rank);
    }
    svd.solve(b, smax * 1e-14).map_err(|_| rank)
}
