//! Per-view robot-pose corrections in the pixel domain: every view's flange pose
//! is a noisy measurement, `F_i · E(ξ_i)`, and the hand-eye `X`, the target in the base `B` and
//! one small flange correction `ξ_i` per view (rotation vector rad, translation mm, in the
//! flange frame) are fitted jointly to the detected corners,
//!
//! `min Σ_ij |π(K, (F_i E(ξ_i) X)⁻¹ B P_j) − u_ij|² / σ_px²  +  Σ_i ξ_iᵀ Σ⁻¹ ξ_i`,
//!
//! with the intrinsics `K` held (the board alone determines them where the robot is the weaker
//! sensor). The prior `Σ` — the robot's pose noise — and the pixel noise `σ_px` are estimated
//! from the data by variance components (Helmert: each group's weighted square residual over
//! its redundancy, the redundancies from the Schur-complement covariance), so a correction
//! cannot absorb the hand-eye: a shift common to all views costs `n·ξᵀΣ⁻¹ξ` and is taken by
//! `X` instead, while a view's own flange error is taken by its `ξ_i`.
//!
//! Unlike [`super::posenoise`], which reconciles the board-only camera poses `T_i` in the pose
//! domain (treating them as exact), the corners themselves are the measurements here: where a
//! view's `T_i` is weakly determined (few corners, a small board far away: depth against
//! tilt), the pixel residual, not a pose residual, says how much that view can be moved.
//!
//! The normal equations have the bundle-adjustment arrow structure; each LM step eliminates the
//! per-view blocks (6×6) by the Schur complement onto the 12 shared parameters.
use nalgebra::{DMatrix, Isometry3, Matrix6, Vector3, Vector6};

use super::geom::{pose_from_slice, pose_to_vec, project, Intrinsics};
use super::viewcorr_jac::{view_blocks, M12x6, M12, V12};

/// Result of [`fit`].
#[derive(Debug, Clone)]
pub struct ViewCorrFit {
    pub x: Isometry3<f64>,
    pub target: Isometry3<f64>,
    /// Per-view flange correction `E(ξ_i)` (corrected flange = `F_i · E(ξ_i)`).
    pub corrections: Vec<Isometry3<f64>>,
    /// Estimated robot pose noise (the prior): rotation deg and translation mm, 1σ per axis.
    pub sigma_deg: f64,
    pub sigma_mm: f64,
    /// Estimated pixel noise per image coordinate (px).
    pub sigma_px: f64,
    /// Covariance of `[ω_X, t_X, ω_B, t_B]` (rad, mm), the corrections marginalised.
    pub cov: DMatrix<f64>,
    /// Per-corner RMS (px) of the corners under the corrected flange poses.
    pub corrected_rms_px: f64,
}

/// One view: flange pose and `(board point mm, detected pixel)`.
pub struct ViewObs {
    pub flange: Isometry3<f64>,
    pub pts: Vec<(Vector3<f64>, [f64; 2])>,
}

/// Residuals (predicted − detected, px) of one view; `None` when a corner falls behind the
/// camera.
fn residuals(
    k: &Intrinsics,
    v: &ViewObs,
    xi: &[f64],
    theta: &[f64],
    out: &mut Vec<f64>,
) -> Option<()> {
    let x = pose_from_slice(&theta[0..6]);
    let b = pose_from_slice(&theta[6..12]);
    let m = (v.flange * pose_from_slice(xi) * x).inverse() * b;
    out.clear();
    for (p, uv) in &v.pts {
        let q = project(k, &(m * nalgebra::Point3::from(*p)).coords)?;
        out.push(q[0] - uv[0]);
        out.push(q[1] - uv[1]);
    }
    Some(())
}

/// One view's residuals and their derivatives by central differences: `(r, J_θ, J_ξ)` (the
/// reference the analytic [`super::viewcorr_jac`] is tested against).
#[cfg(test)]
pub(super) fn view_jac_numeric(
    k: &Intrinsics,
    v: &ViewObs,
    xi: &[f64; 6],
    theta: &[f64; 12],
) -> Option<(nalgebra::DVector<f64>, DMatrix<f64>, DMatrix<f64>)> {
    let mut r = vec![];
    residuals(k, v, xi, theta, &mut r)?;
    let m = r.len();
    let step = |a: usize| if a % 6 < 3 { 1e-6 } else { 1e-4 };
    let (mut rp, mut rm) = (vec![], vec![]);
    let mut jt = DMatrix::zeros(m, 12);
    for a in 0..12 {
        let h = step(a);
        let (mut tp, mut tm) = (*theta, *theta);
        tp[a] += h;
        tm[a] -= h;
        residuals(k, v, xi, &tp, &mut rp)?;
        residuals(k, v, xi, &tm, &mut rm)?;
        for i in 0..m {
            jt[(i, a)] = (rp[i] - rm[i]) / (2.0 * h);
        }
    }
    let mut jx = DMatrix::zeros(m, 6);
    for a in 0..6 {
        let h = step(a);
        let (mut xp, mut xm) = (*xi, *xi);
        xp[a] += h;
        xm[a] -= h;
        residuals(k, v, &xp, theta, &mut rp)?;
        residuals(k, v, &xm, theta, &mut rm)?;
        for i in 0..m {
            jx[(i, a)] = (rp[i] - rm[i]) / (2.0 * h);
        }
    }
    Some((nalgebra::DVector::from_vec(r), jt, jx))
}

/// Cost `Σ|r|²/σ² + Σ ξᵀ P ξ` (`P = Σ⁻¹`), infinite when a corner is behind the camera.
fn cost(
    k: &Intrinsics,
    views: &[ViewObs],
    xis: &[[f64; 6]],
    theta: &[f64; 12],
    s2: f64,
    prec: &Matrix6<f64>,
) -> f64 {
    let mut r = vec![];
    let mut c = 0.0;
    for (v, xi) in views.iter().zip(xis) {
        if residuals(k, v, xi, theta, &mut r).is_none() {
            return f64::INFINITY;
        }
        let e = Vector6::from_column_slice(xi);
        c += r.iter().map(|a| a * a).sum::<f64>() / s2 + (e.transpose() * prec * e)[0];
    }
    c
}

/// The linear system at a state: shared block, per-view blocks.
struct Normal {
    h: M12,
    g: V12,
    /// Per view: `A_i` (6×6), `C_i = J_θᵀJ_ξ/σ²` (12×6), `g_i`.
    blocks: Vec<(Matrix6<f64>, M12x6, Vector6<f64>)>,
    /// Per view: residual square sum (px²) and count of residual components.
    ss: Vec<(f64, usize)>,
}

fn normal(
    k: &Intrinsics,
    views: &[ViewObs],
    xis: &[[f64; 6]],
    theta: &[f64; 12],
    s2: f64,
    prec: &Matrix6<f64>,
) -> Option<Normal> {
    let mut h = M12::zeros();
    let mut g = V12::zeros();
    let mut blocks = vec![];
    let mut ss = vec![];
    for (v, xi) in views.iter().zip(xis) {
        let vb = view_blocks(k, v, xi, theta)?;
        h += vb.tt / s2;
        g += vb.tr / s2;
        let e = Vector6::from_column_slice(xi);
        blocks.push((vb.xx / s2 + prec, vb.tx / s2, vb.xr / s2 + prec * e));
        ss.push((vb.ss, vb.m));
    }
    Some(Normal { h, g, blocks, ss })
}

/// Solve the damped system (`λ`: Marquardt scaling of the diagonal): `(δθ, δξ_i)`.
fn step(n: &Normal, lambda: f64) -> Option<(V12, Vec<Vector6<f64>>)> {
    let damp12 = |m: &M12| {
        let mut d = *m;
        for a in 0..12 {
            d[(a, a)] *= 1.0 + lambda;
        }
        d
    };
    let mut s = damp12(&n.h);
    let mut b = n.g;
    let mut inv = vec![];
    for (a, c, gi) in &n.blocks {
        let mut ad = *a;
        for q in 0..6 {
            ad[(q, q)] *= 1.0 + lambda;
        }
        let ai = ad.try_inverse()?;
        s -= c * ai * c.transpose();
        b -= c * ai * gi;
        inv.push(ai);
    }
    let dt = -s.try_inverse()? * b;
    let dx = n
        .blocks
        .iter()
        .zip(&inv)
        .map(|((_, c, gi), ai)| -ai * (gi + c.transpose() * dt))
        .collect();
    Some((dt, dx))
}

/// LM on `(θ, ξ)` at fixed noise levels; returns the final cost.
fn solve(
    k: &Intrinsics,
    views: &[ViewObs],
    xis: &mut [[f64; 6]],
    theta: &mut [f64; 12],
    s2: f64,
    prec: &Matrix6<f64>,
) -> Option<f64> {
    let mut c0 = cost(k, views, xis, theta, s2, prec);
    if !c0.is_finite() {
        return None;
    }
    let mut lambda = 1e-4;
    for _ in 0..60 {
        let n = normal(k, views, xis, theta, s2, prec)?;
        let mut improved = false;
        for _ in 0..12 {
            let Some((dt, dx)) = step(&n, lambda) else {
                lambda *= 10.0;
                continue;
            };
            let mut t1 = *theta;
            for a in 0..12 {
                t1[a] += dt[a];
            }
            let x1: Vec<[f64; 6]> = xis
                .iter()
                .zip(&dx)
                .map(|(x, d)| std::array::from_fn(|a| x[a] + d[a]))
                .collect();
            let c1 = cost(k, views, &x1, &t1, s2, prec);
            if c1.is_finite() && c1 < c0 {
                let rel = (c0 - c1) / c0.max(1e-300);
                *theta = t1;
                xis.copy_from_slice(&x1);
                c0 = c1;
                lambda = (lambda * 0.3).max(1e-12);
                improved = rel > 1e-10;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    Some(c0)
}

fn diag(r_rad: f64, t_mm: f64) -> Matrix6<f64> {
    let (r2, t2) = (r_rad * r_rad, t_mm * t_mm);
    Matrix6::from_diagonal(&Vector6::new(r2, r2, r2, t2, t2, t2))
}

/// Fit `X`, `B` and one flange correction per view to the corners of `views` with the
/// intrinsics `k` held, from `x0`, `b0`; the pose-noise prior starts at `(σ_r rad, σ_t mm)` =
/// `noise0` and the pixel noise at `sigma_px0` (per coordinate), both then estimated. `None`
/// with fewer than 3 views or a singular fit.
pub fn fit(
    k: &Intrinsics,
    views: &[ViewObs],
    x0: &Isometry3<f64>,
    b0: &Isometry3<f64>,
    noise0: (f64, f64),
    sigma_px0: f64,
) -> Option<ViewCorrFit> {
    let start = diag(noise0.0.max(1e-7), noise0.1.max(1e-5));
    fit_inner(k, views, x0, b0, start, sigma_px0, true)
}

/// As [`fit`] with the prior `Σ` (6×6, `[ω rad, t mm]`, e.g. a scaled [`super::posenoise`]
/// estimate) and the pixel noise held: the family between the fit that treats the flange
/// poses as exact (`Σ → 0`) and the pose-domain fit (`σ_px → 0`).
pub fn fit_fixed(
    k: &Intrinsics,
    views: &[ViewObs],
    x0: &Isometry3<f64>,
    b0: &Isometry3<f64>,
    prior: &Matrix6<f64>,
    sigma_px: f64,
) -> Option<ViewCorrFit> {
    fit_inner(k, views, x0, b0, *prior, sigma_px, false)
}

fn fit_inner(
    k: &Intrinsics,
    views: &[ViewObs],
    x0: &Isometry3<f64>,
    b0: &Isometry3<f64>,
    mut sig: Matrix6<f64>,
    sigma_px0: f64,
    estimate: bool,
) -> Option<ViewCorrFit> {
    let n = views.len();
    if n < 3 || views.iter().any(|v| v.pts.len() < 4) {
        return None;
    }
    let m_total: usize = views.iter().map(|v| 2 * v.pts.len()).sum();
    let mut theta = [0.0; 12];
    theta[0..6].copy_from_slice(&pose_to_vec(x0));
    theta[6..12].copy_from_slice(&pose_to_vec(b0));
    let mut xis = vec![[0.0; 6]; n];
    let mut sp = sigma_px0.max(1e-4);
    for _ in 0..if estimate { 10 } else { 0 } {
        let prec = sig.try_inverse()?;
        solve(k, views, &mut xis, &mut theta, sp * sp, &prec)?;
        // Variance components: redundancy of the prior of component a, Σ_i (1 − Cov(ξ_i)_aa
        // / Σ_aa), with Cov(ξ_i) = A_i⁻¹ + A_i⁻¹ C_iᵀ S⁻¹ C_i A_i⁻¹ (Schur complement).
        let nm = normal(k, views, &xis, &theta, sp * sp, &prec)?;
        let (_, cov_xi) = covariances(&nm)?;
        let (mut red, mut sq) = ([0.0f64; 2], [0.0f64; 2]);
        for (xi, c) in xis.iter().zip(&cov_xi) {
            for a in 0..6 {
                red[a / 3] += 1.0 - c[(a, a)] / sig[(a, a)];
                sq[a / 3] += xi[a] * xi[a];
            }
        }
        let ss: f64 = nm.ss.iter().map(|s| s.0).sum();
        let red_px = (m_total as f64 - 12.0 - red[0] - red[1]).max(1.0);
        let nr = (sq[0] / red[0].max(0.5)).sqrt().max(1e-7);
        let nt = (sq[1] / red[1].max(0.5)).sqrt().max(1e-5);
        let np = (ss / red_px).sqrt().max(1e-4);
        let done = [(nr * nr, sig[(0, 0)]), (nt * nt, sig[(3, 3)]), (np, sp)]
            .iter()
            .all(|(a, b)| (a / b - 1.0).abs() < 1e-2);
        (sig, sp) = (diag(nr, nt), np);
        if done {
            break;
        }
    }
    let prec = sig.try_inverse()?;
    solve(k, views, &mut xis, &mut theta, sp * sp, &prec)?;
    let nm = normal(k, views, &xis, &theta, sp * sp, &prec)?;
    let (cov, _) = covariances(&nm)?;
    let ss: f64 = nm.ss.iter().map(|s| s.0).sum();
    let nc: usize = nm.ss.iter().map(|s| s.1 / 2).sum();
    let mean = |o: usize| ((o..o + 3).map(|a| sig[(a, a)]).sum::<f64>() / 3.0).sqrt();
    Some(ViewCorrFit {
        x: pose_from_slice(&theta[0..6]),
        target: pose_from_slice(&theta[6..12]),
        corrections: xis.iter().map(|x| pose_from_slice(x)).collect(),
        sigma_deg: mean(0).to_degrees(),
        sigma_mm: mean(3),
        sigma_px: sp,
        cov: DMatrix::from_iterator(12, 12, cov.iter().copied()),
        corrected_rms_px: (ss / nc.max(1) as f64).sqrt(),
    })
}

/// Covariance of θ (`S⁻¹`) and of every `ξ_i`, at the undamped normal equations.
fn covariances(n: &Normal) -> Option<(M12, Vec<Matrix6<f64>>)> {
    let mut s = n.h;
    let mut inv = vec![];
    for (a, c, _) in &n.blocks {
        let ai = a.try_inverse()?;
        s -= c * ai * c.transpose();
        inv.push(ai);
    }
    let si = s.try_inverse()?;
    let cx = n
        .blocks
        .iter()
        .zip(&inv)
        .map(|((_, c, _), ai)| ai + ai * c.transpose() * si * c * ai)
        .collect();
    Some((si, cx))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A 9×7 board (20 mm) seen from 30 flange poses whose stated values are wrong by
    /// 0.05° / 0.5 mm: the pixel-domain fit recovers X, the pose noise and the pixel noise, and
    /// its X is closer than the fit that treats the flange poses as exact would be.
    #[test]
    fn recovers_x_and_noise_levels_from_corners() {
        let k = Intrinsics {
            fx: 900.0,
            fy: 900.0,
            cx: 640.0,
            cy: 480.0,
            dist: [0.0; 5],
        };
        let x = Isometry3::from_parts(
            Translation3::new(30.0, -50.0, 80.0),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.05, -0.1, 1.2)),
        );
        let b = Isometry3::from_parts(
            Translation3::new(550.0, -80.0, 0.0),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 0.4)),
        );
        let pts: Vec<Vector3<f64>> = (0..63)
            .map(|i| Vector3::new((i % 9) as f64 * 20.0, (i / 9) as f64 * 20.0, 0.0))
            .collect();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let (nr, nt, np) = (
            Normal::new(0.0, 0.05f64.to_radians()).unwrap(),
            Normal::new(0.0, 0.5).unwrap(),
            Normal::new(0.0, 0.1).unwrap(),
        );
        let mut views = vec![];
        for i in 0..30 {
            let a = i as f64 * 0.9;
            // Camera 450 mm above the board centre, looking down, tilted.
            let cam = Isometry3::from_parts(
                Translation3::new(630.0 + 60.0 * a.cos(), 0.0 + 60.0 * a.sin(), 450.0),
                UnitQuaternion::from_scaled_axis(Vector3::new(
                    std::f64::consts::PI + 0.2 * a.sin(),
                    0.2 * a.cos(),
                    0.0,
                )) * UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, a)),
            );
            let f_true = cam * x.inverse();
            let xi = [
                nr.sample(&mut rng),
                nr.sample(&mut rng),
                nr.sample(&mut rng),
                nt.sample(&mut rng),
                nt.sample(&mut rng),
                nt.sample(&mut rng),
            ];
            // Stated = true · E(ξ)⁻¹, so that the correction E(ξ) recovers the truth.
            let stated = f_true * pose_from_slice(&xi).inverse();
            let m = cam.inverse() * b;
            let obs: Vec<(Vector3<f64>, [f64; 2])> = pts
                .iter()
                .filter_map(|p| {
                    let q = project(&k, &(m * nalgebra::Point3::from(*p)).coords)?;
                    Some((*p, [q[0] + np.sample(&mut rng), q[1] + np.sample(&mut rng)]))
                })
                .collect();
            views.push(ViewObs {
                flange: stated,
                pts: obs,
            });
        }
        let x0 = x * Isometry3::translation(2.0, -2.0, 3.0);
        let f = fit(&k, &views, &x0, &b, (0.01f64.to_radians(), 0.1), 0.3).unwrap();
        let (dt, dr) = super::super::geom::pose_error(&f.x, &x);
        eprintln!(
            "X {dt:.3} mm {dr:.4} deg; noise {:.4} deg {:.3} mm, pixel {:.3}; corrected RMS {:.3} px",
            f.sigma_deg, f.sigma_mm, f.sigma_px, f.corrected_rms_px
        );
        assert!(dt < 1.0 && dr < 0.05, "{dt} mm {dr} deg");
        assert!((f.sigma_deg / 0.05 - 1.0).abs() < 0.35, "{}", f.sigma_deg);
        assert!((f.sigma_mm / 0.5 - 1.0).abs() < 0.35, "{}", f.sigma_mm);
        assert!((f.sigma_px / 0.1 - 1.0).abs() < 0.1, "{}", f.sigma_px);
        // The corrections take the pose error: the corrected RMS is the pixel noise.
        assert!(f.corrected_rms_px < 0.2, "{}", f.corrected_rms_px);
        let sx = (f.cov[(3, 3)] + f.cov[(4, 4)] + f.cov[(5, 5)]).sqrt();
        assert!(dt < 4.0 * sx, "{dt} mm vs σ {sx}");
    }
}
