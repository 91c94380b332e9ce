//! Analytic derivatives of the per-view correction residuals ([`super::viewcorr`]), accumulated
//! straight into the view's normal-equation blocks (speed: the central differences they
//! replace took 36 residual evaluations per view and step and dominated `calibrate camera`).
//!
//! A board point `P` of view `i` is seen at `p = X⁻¹ E(ξ)⁻¹ F⁻¹ B P` (camera frame), with every
//! pose a 6-vector `[ω rad, t mm]` (`R = exp(ω)`). With `L(ω)` the left Jacobian of SO(3):
//!
//! * `y₁ = B P`: `∂y₁/∂[ω_B, t_B] = [−[R_B P]ₓ L(ω_B), I]`,
//! * `y₂ = F⁻¹ y₁ = R_Fᵀ (y₁ − t_F)`,
//! * `y₃ = E⁻¹ y₂`: `∂y₃/∂[ω_ξ, t_ξ] = [R_Eᵀ [y₂ − t_E]ₓ L(ω_ξ), −R_Eᵀ]`,
//! * `p = X⁻¹ y₃`: `∂p/∂[ω_X, t_X] = [R_Xᵀ [y₃ − t_X]ₓ L(ω_X), −R_Xᵀ]`,
//!
//! so `∂p/∂θ_B = R_Xᵀ R_Eᵀ R_Fᵀ ∂y₁/∂θ_B` and `∂p/∂ξ = R_Xᵀ ∂y₃/∂ξ`; the pixel's derivative is
//! the projection's 2×3 Jacobian times these ([`super::geom::project_jac`]).
use nalgebra::{Matrix3, Matrix6, SMatrix, SVector, Vector3, Vector6};

use super::geom::{exp_so3, left_jacobian, project_jac, skew, Intrinsics};
use super::viewcorr::ViewObs;

pub(super) type M12 = SMatrix<f64, 12, 12>;
pub(super) type M12x6 = SMatrix<f64, 12, 6>;
pub(super) type V12 = SVector<f64, 12>;

/// A pose 6-vector's rotation, translation and left Jacobian.
struct PoseParts {
    r: Matrix3<f64>,
    t: Vector3<f64>,
    l: Matrix3<f64>,
}

fn parts(v: &[f64]) -> PoseParts {
    let w = Vector3::new(v[0], v[1], v[2]);
    PoseParts {
        r: *exp_so3(&w).matrix(),
        t: Vector3::new(v[3], v[4], v[5]),
        l: left_jacobian(&w),
    }
}

/// One corner's residual (px, predicted − detected) and its rows `∂r/∂θ` (2×12, `θ = [X, B]`)
/// and `∂r/∂ξ` (2×6).
type Rows = ([f64; 2], SMatrix<f64, 2, 12>, SMatrix<f64, 2, 6>);

/// Calls `each` with every corner's [`Rows`] of view `v`; `None` when a corner falls behind the
/// camera.
fn for_each_row(
    k: &Intrinsics,
    v: &ViewObs,
    xi: &[f64; 6],
    theta: &[f64; 12],
    mut each: impl FnMut(Rows),
) -> Option<()> {
    let x = parts(&theta[0..6]);
    let b = parts(&theta[6..12]);
    let e = parts(xi);
    let rf = *v.flange.rotation.to_rotation_matrix().matrix();
    let tf = v.flange.translation.vector;
    let (rft, ret, rxt) = (rf.transpose(), e.r.transpose(), x.r.transpose());
    let chain_b = rxt * ret * rft;
    for (p, uv) in &v.pts {
        let rbp = b.r * p;
        let y1 = rbp + b.t;
        let y2 = rft * (y1 - tf);
        let d2 = y2 - e.t;
        let y3 = ret * d2;
        let d3 = y3 - x.t;
        let pc = rxt * d3;
        let (q, jp, _) = project_jac(k, &pc)?;
        let mut dp_dt = SMatrix::<f64, 3, 12>::zeros();
        dp_dt
            .fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(rxt * skew(&d3) * x.l));
        dp_dt.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-rxt));
        dp_dt
            .fixed_view_mut::<3, 3>(0, 6)
            .copy_from(&(chain_b * (-skew(&rbp) * b.l)));
        dp_dt.fixed_view_mut::<3, 3>(0, 9).copy_from(&chain_b);
        let mut dp_dx = SMatrix::<f64, 3, 6>::zeros();
        dp_dx
            .fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(rxt * ret * skew(&d2) * e.l));
        dp_dx.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-rxt * ret));
        each(([q[0] - uv[0], q[1] - uv[1]], jp * dp_dt, jp * dp_dx));
    }
    Some(())
}

/// One view's residuals and derivatives as dense matrices `(r, J_θ, J_ξ)` (the layout of the
/// central differences this replaces; the tests compare the two).
#[cfg(test)]
pub(super) fn view_jac(
    k: &Intrinsics,
    v: &ViewObs,
    xi: &[f64; 6],
    theta: &[f64; 12],
) -> Option<(
    nalgebra::DVector<f64>,
    nalgebra::DMatrix<f64>,
    nalgebra::DMatrix<f64>,
)> {
    let m = 2 * v.pts.len();
    let mut r = nalgebra::DVector::zeros(m);
    let mut jt = nalgebra::DMatrix::zeros(m, 12);
    let mut jx = nalgebra::DMatrix::zeros(m, 6);
    let mut i = 0;
    for_each_row(k, v, xi, theta, |(ri, t, x)| {
        for a in 0..2 {
            r[i + a] = ri[a];
            jt.row_mut(i + a).copy_from(&t.row(a));
            jx.row_mut(i + a).copy_from(&x.row(a));
        }
        i += 2;
    })?;
    Some((r, jt, jx))
}

/// One view's contribution to the normal equations (unscaled by the pixel variance).
pub(super) struct ViewBlocks {
    /// `J_θᵀ J_θ`, `J_θᵀ r`.
    pub tt: M12,
    pub tr: V12,
    /// `J_ξᵀ J_ξ`, `J_θᵀ J_ξ`, `J_ξᵀ r`.
    pub xx: Matrix6<f64>,
    pub tx: M12x6,
    pub xr: Vector6<f64>,
    /// Residual square sum (px²) and count of residual components.
    pub ss: f64,
    pub m: usize,
}

/// [`ViewBlocks`] of view `v` at `(ξ, θ)`; `None` when a corner falls behind the camera.
pub(super) fn view_blocks(
    k: &Intrinsics,
    v: &ViewObs,
    xi: &[f64; 6],
    theta: &[f64; 12],
) -> Option<ViewBlocks> {
    let mut o = ViewBlocks {
        tt: M12::zeros(),
        tr: V12::zeros(),
        xx: Matrix6::zeros(),
        tx: M12x6::zeros(),
        xr: Vector6::zeros(),
        ss: 0.0,
        m: 0,
    };
    for_each_row(k, v, xi, theta, |(r, jt, jx)| {
        let r = nalgebra::Vector2::new(r[0], r[1]);
        let (jtt, jxt) = (jt.transpose(), jx.transpose());
        o.tt += jtt * jt;
        o.tr += jtt * r;
        o.xx += jxt * jx;
        o.tx += jtt * jx;
        o.xr += jxt * r;
        o.ss += r.norm_squared();
        o.m += 2;
    })?;
    Some(o)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    /// A tilted 6×5 board seen through a distorted camera, every pose and correction away from
    /// zero so that no derivative term vanishes.
    fn setup() -> (Intrinsics, ViewObs, [f64; 6], [f64; 12]) {
        let k = Intrinsics {
            fx: 905.0,
            fy: 898.0,
            cx: 641.0,
            cy: 479.0,
            dist: [-0.08, 0.05, 0.001, -0.002, 0.01],
        };
        let flange = Isometry3::from_parts(
            Translation3::new(520.0, -60.0, 480.0),
            UnitQuaternion::from_scaled_axis(Vector3::new(3.0, 0.15, -0.1)),
        );
        let pts = (0..30)
            .map(|i| {
                let p = Vector3::new((i % 6) as f64 * 25.0, (i / 6) as f64 * 25.0, 0.0);
                (p, [600.0 + i as f64, 450.0 - i as f64])
            })
            .collect();
        let xi = [0.002, -0.003, 0.001, 0.4, -0.3, 0.2];
        let theta = [
            0.05, -0.1, 1.2, 30.0, -50.0, 80.0, 0.02, -0.01, 0.4, 480.0, -120.0, 5.0,
        ];
        (k, ViewObs { flange, pts }, xi, theta)
    }

    #[test]
    fn analytic_jacobian_matches_central_differences() {
        let (k, v, xi, theta) = setup();
        let (r, jt, jx) = view_jac(&k, &v, &xi, &theta).unwrap();
        let (rn, jtn, jxn) = super::super::viewcorr::view_jac_numeric(&k, &v, &xi, &theta).unwrap();
        assert!((&r - &rn).amax() < 1e-9, "residuals {}", (&r - &rn).amax());
        for (a, n, what) in [(&jt, &jtn, "theta"), (&jx, &jxn, "xi")] {
            for c in 0..a.ncols() {
                let e = (a.column(c) - n.column(c)).norm() / (1.0 + n.column(c).norm());
                assert!(e < 1e-6, "{what} column {c}: {e}");
            }
        }
        // A wrong chain (no correction in it) would fail the same check.
        assert!(jx.column(3).norm() > 1.0);
    }

    #[test]
    fn accumulated_blocks_equal_the_dense_products() {
        let (k, v, xi, theta) = setup();
        let (r, jt, jx) = view_jac(&k, &v, &xi, &theta).unwrap();
        let b = view_blocks(&k, &v, &xi, &theta).unwrap();
        let close = |a: &[f64], d: &[f64]| {
            let s = d.iter().fold(1.0f64, |m, x| m.max(x.abs()));
            a.len() == d.len() && a.iter().zip(d).all(|(x, y)| (x - y).abs() <= 1e-12 * s)
        };
        assert!(close(b.tt.as_slice(), (jt.transpose() * &jt).as_slice()));
        assert!(close(b.tr.as_slice(), (jt.transpose() * &r).as_slice()));
        assert!(close(b.xx.as_slice(), (jx.transpose() * &jx).as_slice()));
        assert!(close(b.tx.as_slice(), (jt.transpose() * &jx).as_slice()));
        assert!(close(b.xr.as_slice(), (jx.transpose() * &r).as_slice()));
        assert!((b.ss - r.norm_squared()).abs() <= 1e-12 * r.norm_squared());
        assert_eq!(b.m, r.len());
    }

    #[test]
    fn a_corner_behind_the_camera_gives_none() {
        let (k, mut v, xi, mut theta) = setup();
        assert!(view_blocks(&k, &v, &xi, &theta).is_some());
        // Board moved 5 m up, behind the downward-looking camera.
        theta[11] = 5000.0;
        assert!(view_blocks(&k, &v, &xi, &theta).is_none());
        v.pts.clear();
        theta[11] = 5.0;
        assert_eq!(view_blocks(&k, &v, &xi, &theta).unwrap().m, 0);
    }
}
