//! The board-only fit: the free intrinsics and one board pose per view, from the corners alone
//! (no robot), by Levenberg–Marquardt on the Schur complement of the pose blocks.
//!
//! Each view's residuals depend on the intrinsics and on that view's pose only, so the normal
//! equations are block-arrow: `[U W; Wᵀ V]` with `V` block-diagonal (6×6 per view). Eliminating
//! the poses leaves an `m × m` system in the intrinsics (`m ≤ 9`), so one iteration costs
//! `O(corners · (m + 6)²)` instead of the dense solver's `O(corners · (m + 6·views)²)`: on a
//! real UR3e set (66 views of 30 corners) the dense solver took ~0.3 s per fit, too slow for a
//! view jackknife and a bootstrap over every view. The damping, scaling, step acceptance and
//! stopping rules are those of [`crate::solve::lm::minimize`] (Moré scaling by the running
//! maximum of the column norms, Marquardt's damping on the scaled diagonal), and the test below
//! checks that both reach the same optimum and covariance.
use nalgebra::{DMatrix, DVector, Isometry3, Matrix6, Vector6};
use rayon::prelude::*;

use super::geom::{pose_from_slice, pose_to_vec, Intrinsics, N_INTR};
use super::problem::{BoardModel, Layout, Obs, Reproj};
use crate::solve::lm::{next_lambda, solve_spd, LmOptions, LsqProblem};

/// The outcome of [`fit`].
#[derive(Debug, Clone)]
pub struct BoardOnly {
    pub k: Intrinsics,
    /// Board pose (camera ← board) per view.
    pub poses: Vec<Isometry3<f64>>,
    /// Reprojection RMS over every corner (px).
    pub rms: f64,
    /// Covariance of the free intrinsics (in the order of `[fx, fy, cx, cy, k1, k2, p1, p2,
    /// k3]`): `σ² (JᵀJ)⁻¹`'s intrinsics block with `σ²` from the residual; empty when it
    /// cannot be formed (no redundancy, or a singular system).
    pub cov: DMatrix<f64>,
    pub iterations: usize,
}

/// Residuals and Jacobian blocks of every view (intrinsics columns, pose columns).
type Lin = Vec<(DVector<f64>, DMatrix<f64>, DMatrix<f64>)>;

fn linearize(
    per_view: &[&[Obs]],
    mask: [bool; N_INTR],
    k_fixed: &Intrinsics,
    xk: &DVector<f64>,
    xp: &[Vector6<f64>],
) -> Option<Lin> {
    let m = xk.len();
    let lin: Lin = per_view
        .iter()
        .zip(xp)
        .map(|(obs, p)| {
            let pr = Reproj {
                obs,
                flange: &[],
                layout: Layout::Views(1),
                intr_free: mask,
                intr_fixed: *k_fixed,
                board: BoardModel::default(),
                arm: None,
                flange_map: None,
            };
            let mut x = DVector::zeros(m + 6);
            x.rows_mut(0, m).copy_from(xk);
            x.rows_mut(m, 6).copy_from(p);
            let (r, j) = pr.residuals_jacobian(&x);
            (
                r,
                j.columns(0, m).into_owned(),
                j.columns(m, 6).into_owned(),
            )
        })
        .collect();
    let finite = lin.iter().all(|(r, a, b)| {
        r.iter()
            .chain(a.iter())
            .chain(b.iter())
            .all(|v| v.is_finite())
    });
    finite.then_some(lin)
}

/// The normal equations' blocks: `U` (m×m), `W_v` (m×6), `V_v` (6×6), `g_k`, `g_v`.
struct Normal {
    u: DMatrix<f64>,
    w: Vec<DMatrix<f64>>,
    v: Vec<Matrix6<f64>>,
    gk: DVector<f64>,
    gp: Vec<Vector6<f64>>,
}

fn normal(lin: &Lin, m: usize) -> Normal {
    let mut n = Normal {
        u: DMatrix::zeros(m, m),
        w: Vec::with_capacity(lin.len()),
        v: Vec::with_capacity(lin.len()),
        gk: DVector::zeros(m),
        gp: Vec::with_capacity(lin.len()),
    };
    for (r, jk, jp) in lin {
        n.u += jk.tr_mul(jk);
        n.gk += jk.tr_mul(r);
        n.w.push(jk.tr_mul(jp));
        let v = jp.tr_mul(jp);
        n.v.push(Matrix6::from_iterator(v.iter().copied()));
        let g = jp.tr_mul(r);
        n.gp.push(Vector6::from_iterator(g.iter().copied()));
    }
    n
}

/// Inverse of a symmetric positive semi-definite 6×6 block (pseudo-inverse when singular).
fn inv6(b: &Matrix6<f64>) -> Matrix6<f64> {
    if let Some(c) = b.cholesky() {
        return c.inverse();
    }
    b.pseudo_inverse(1e-12 * b.norm().max(f64::MIN_POSITIVE))
        .unwrap_or_else(|_| Matrix6::zeros())
}

/// The Schur complement `S = U − Σ W_v V_v⁻¹ W_vᵀ` (with damping `λ·d²` on both blocks) and,
/// for the step, `V_v⁻¹` per view.
fn schur(
    n: &Normal,
    lambda: f64,
    dk: &DVector<f64>,
    dp: &[Vector6<f64>],
) -> (DMatrix<f64>, Vec<Matrix6<f64>>) {
    let mut s = n.u.clone();
    for i in 0..s.nrows() {
        s[(i, i)] += lambda * dk[i] * dk[i];
    }
    let mut binv = Vec::with_capacity(n.v.len());
    for ((v, w), d) in n.v.iter().zip(&n.w).zip(dp) {
        let mut b = *v;
        for i in 0..6 {
            b[(i, i)] += lambda * d[i] * d[i];
        }
        let bi = inv6(&b);
        s -= w * bi * w.transpose();
        binv.push(bi);
    }
    (s, binv)
}

fn cost_of(lin: &Lin) -> f64 {
    0.5 * lin.iter().map(|(r, _, _)| r.norm_squared()).sum::<f64>()
}

/// Fit the free intrinsics (`mask`; the others held at `k`'s values) and one board pose per
/// view (`per_view`: each view's corners, every `Obs::view` 0; `poses`: where to start) from
/// `k`. `None` when the start point or the result is not finite.
pub fn fit(
    per_view: &[&[Obs]],
    poses: &[Isometry3<f64>],
    k: &Intrinsics,
    mask: [bool; N_INTR],
    o: &LmOptions,
) -> Option<BoardOnly> {
    if per_view.len() != poses.len()
        || per_view.is_empty()
        || per_view.iter().any(|ob| ob.iter().any(|o| o.view != 0))
    {
        return None;
    }
    let kv = k.to_vec();
    let free: Vec<usize> = (0..N_INTR).filter(|i| mask[*i]).collect();
    let m = free.len();
    let nv = per_view.len();
    let mut xk = DVector::from_iterator(m, free.iter().map(|&i| kv[i]));
    let mut xp: Vec<Vector6<f64>> = poses
        .iter()
        .map(|p| Vector6::from_column_slice(&pose_to_vec(p)))
        .collect();
    let mut lin = linearize(per_view, mask, k, &xk, &xp)?;
    let mut cost = cost_of(&lin);
    if !cost.is_finite() {
        return None;
    }
    let mut lambda = o.lambda0;
    let mut dk = DVector::zeros(m);
    let mut dp = vec![Vector6::zeros(); nv];
    let mut iters = 0;
    'outer: while iters < o.max_iter {
        iters += 1;
        if cost <= f64::MIN_POSITIVE {
            break;
        }
        let n = normal(&lin, m);
        let scale = |c: f64, d: &mut f64| {
            let c = c.sqrt();
            if c > *d {
                *d = c;
            }
            if *d == 0.0 {
                *d = 1.0;
            }
        };
        for i in 0..m {
            scale(n.u[(i, i)], &mut dk[i]);
        }
        for (v, d) in n.v.iter().zip(dp.iter_mut()) {
            for i in 0..6 {
                scale(v[(i, i)], &mut d[i]);
            }
        }
        let rn = (2.0 * cost).sqrt();
        let gmax = (0..m)
            .map(|i| (n.gk[i] / (dk[i] * rn)).abs())
            .chain(
                n.gp.iter()
                    .zip(&dp)
                    .flat_map(|(g, d)| (0..6).map(move |i| (g[i] / (d[i] * rn)).abs())),
            )
            .fold(0.0, f64::max);
        if !gmax.is_finite() || gmax <= o.gtol {
            break;
        }
        loop {
            let (s, binv) = schur(&n, lambda, &dk, &dp);
            let mut b = -&n.gk;
            for ((w, bi), g) in n.w.iter().zip(&binv).zip(&n.gp) {
                b += w * (bi * g);
            }
            let stepk = solve_spd(&s, &b);
            let stepp: Vec<Vector6<f64>> = binv
                .iter()
                .zip(&n.w)
                .zip(&n.gp)
                .map(|((bi, w), g)| {
                    bi * (-g - Vector6::from_iterator(w.tr_mul(&stepk).iter().copied()))
                })
                .collect();
            let nk = &xk + &stepk;
            let np: Vec<Vector6<f64>> = xp.iter().zip(&stepp).map(|(x, d)| x + d).collect();
            let dx_scaled = (stepk.component_mul(&dk).norm_squared()
                + stepp
                    .iter()
                    .zip(&dp)
                    .map(|(s, d)| s.component_mul(d).norm_squared())
                    .sum::<f64>())
            .sqrt();
            let x_scaled = (xk.component_mul(&dk).norm_squared()
                + xp.iter()
                    .zip(&dp)
                    .map(|(s, d)| s.component_mul(d).norm_squared())
                    .sum::<f64>())
            .sqrt();
            let small = dx_scaled <= o.xtol * (x_scaled + o.xtol);
            if let Some(nl) = linearize(per_view, mask, k, &nk, &np) {
                let cnew = cost_of(&nl);
                if cnew.is_finite() && cnew < cost {
                    // Predicted reduction −gᵀδ − ½ δᵀJᵀJδ, from the blocks.
                    let mut quad = stepk.dot(&(&n.u * &stepk));
                    let mut gd = n.gk.dot(&stepk);
                    for (((w, v), g), sp) in n.w.iter().zip(&n.v).zip(&n.gp).zip(&stepp) {
                        let wsp = w * DVector::from_column_slice(sp.as_slice());
                        quad += 2.0 * stepk.dot(&wsp) + sp.dot(&(v * sp));
                        gd += g.dot(sp);
                    }
                    let pred = -gd - 0.5 * quad;
                    let rho = if pred > 0.0 {
                        (cost - cnew) / pred
                    } else {
                        0.0
                    };
                    let rel = (cost - cnew) / cost;
                    (xk, xp, lin, cost) = (nk, np, nl, cnew);
                    lambda = next_lambda(lambda, rho);
                    if rel <= o.ftol || small {
                        break 'outer;
                    }
                    break;
                }
            }
            if small {
                break 'outer;
            }
            lambda *= 4.0;
            if lambda > 1e16 {
                break 'outer;
            }
        }
    }
    let mut kvec = kv;
    for (a, &i) in free.iter().enumerate() {
        kvec[i] = xk[a];
    }
    let k = Intrinsics::from_slice(&kvec);
    if !kvec.iter().all(|v| v.is_finite()) {
        return None;
    }
    let rows: usize = lin.iter().map(|(r, _, _)| r.len()).sum();
    let nparams = m + 6 * nv;
    // Covariance: the undamped Schur complement's inverse is (JᵀJ)⁻¹'s intrinsics block.
    let cov = if rows > nparams && m > 0 {
        let n = normal(&lin, m);
        let (s, _) = schur(&n, 0.0, &DVector::zeros(m), &vec![Vector6::zeros(); nv]);
        let s2 = 2.0 * cost / (rows - nparams) as f64;
        s.try_inverse()
            .map(|i| i * s2)
            .unwrap_or_else(|| DMatrix::zeros(0, 0))
    } else {
        DMatrix::zeros(0, 0)
    };
    Some(BoardOnly {
        k,
        poses: xp.iter().map(|p| pose_from_slice(p.as_slice())).collect(),
        // Per corner: sqrt(Σ r² / corners), as the rest of the camera code states it.
        rms: (2.0 * cost / (rows / 2).max(1) as f64).sqrt(),
        cov,
        iterations: iters,
    })
}

/// Delete-one-view jackknife covariance of the free intrinsics (`mask`) of the board-only fit
/// on every view of `per_view` (started from `fit`'s intrinsics and poses). `None` with fewer
/// than 5 views or when more than one refit fails.
pub fn jackknife(
    per_view: &[&[Obs]],
    fit: &BoardOnly,
    mask: [bool; N_INTR],
) -> Option<DMatrix<f64>> {
    let n = per_view.len();
    if n < 5 || fit.poses.len() != n {
        return None;
    }
    let free: Vec<usize> = (0..N_INTR).filter(|i| mask[*i]).collect();
    let ks: Vec<Vec<f64>> = (0..n)
        .into_par_iter()
        .filter_map(|drop| {
            let ob: Vec<&[Obs]> = (0..n).filter(|&v| v != drop).map(|v| per_view[v]).collect();
            let ps: Vec<Isometry3<f64>> = (0..n)
                .filter(|&v| v != drop)
                .map(|v| fit.poses[v])
                .collect();
            let f = self::fit(&ob, &ps, &fit.k, mask, &LmOptions::default())?;
            let kv = f.k.to_vec();
            Some(free.iter().map(|&i| kv[i]).collect())
        })
        .collect();
    if ks.len() + 1 < n {
        return None;
    }
    let m = free.len();
    let nk = ks.len() as f64;
    let mean: Vec<f64> = (0..m)
        .map(|a| ks.iter().map(|v| v[a]).sum::<f64>() / nk)
        .collect();
    let mut c = DMatrix::zeros(m, m);
    for v in &ks {
        for a in 0..m {
            for b in 0..m {
                c[(a, b)] += (v[a] - mean[a]) * (v[b] - mean[b]);
            }
        }
    }
    Some(c * ((nk - 1.0) / nk))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::lm::minimize;
    use nalgebra::{Point3, Translation3, UnitQuaternion, Vector3};
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// 12 views of a 7×5 board (30 mm) under known intrinsics, 0.1 px noise.
    fn views() -> (Intrinsics, Vec<Vec<Obs>>, Vec<Isometry3<f64>>) {
        let k = Intrinsics {
            fx: 810.0,
            fy: 812.0,
            cx: 322.0,
            cy: 244.0,
            dist: [-0.12, 0.08, 0.0, 0.0, 0.0],
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let noise = Normal::new(0.0, 0.1).unwrap();
        let mut per_view = vec![];
        let mut poses = vec![];
        for v in 0..12 {
            let a = v as f64 * 0.52;
            let pose = Isometry3::from_parts(
                Translation3::new(
                    -90.0 + 8.0 * a.cos(),
                    -60.0 + 8.0 * a.sin(),
                    420.0 + 7.0 * v as f64,
                ),
                UnitQuaternion::from_scaled_axis(Vector3::new(
                    0.35 * a.cos(),
                    0.3 * a.sin(),
                    0.1 * a,
                )),
            );
            let mut ob = vec![];
            for j in 0..5 {
                for i in 0..7 {
                    let pt = Vector3::new(30.0 * i as f64, 30.0 * j as f64, 0.0);
                    let uv =
                        super::super::geom::project(&k, &(pose * Point3::from(pt)).coords).unwrap();
                    ob.push(Obs {
                        view: 0,
                        pt,
                        uv: [
                            uv[0] + noise.sample(&mut rng),
                            uv[1] + noise.sample(&mut rng),
                        ],
                    });
                }
            }
            per_view.push(ob);
            poses.push(pose);
        }
        (k, per_view, poses)
    }

    fn mask() -> [bool; N_INTR] {
        [true, true, true, true, true, true, false, false, false]
    }

    #[test]
    fn the_schur_fit_reaches_the_dense_solvers_optimum_and_covariance() {
        let (k_true, per_view, poses) = views();
        // Start away from the truth: focal +3 %, principal point +6 px, no distortion, poses
        // moved by 5 mm / 0.02 rad.
        let k0 = Intrinsics {
            fx: k_true.fx * 1.03,
            fy: k_true.fy * 1.03,
            cx: k_true.cx + 6.0,
            cy: k_true.cy - 6.0,
            dist: [0.0; 5],
        };
        let p0: Vec<Isometry3<f64>> = poses
            .iter()
            .map(|p| {
                Isometry3::from_parts(
                    Translation3::new(5.0, -5.0, 5.0),
                    UnitQuaternion::from_scaled_axis(Vector3::new(0.02, 0.0, -0.02)),
                ) * p
            })
            .collect();
        let ob: Vec<&[Obs]> = per_view.iter().map(Vec::as_slice).collect();
        let f = fit(&ob, &p0, &k0, mask(), &LmOptions::default()).expect("fit");
        // The dense solver on the same problem, from the same start.
        let flat: Vec<Obs> = per_view
            .iter()
            .enumerate()
            .flat_map(|(v, o)| o.iter().map(move |o| Obs { view: v, ..*o }))
            .collect();
        let p = Reproj {
            obs: &flat,
            flange: &[],
            layout: Layout::Views(per_view.len()),
            intr_free: mask(),
            intr_fixed: k0,
            board: BoardModel::default(),
            arm: None,
            flange_map: None,
        };
        let rep = minimize(&p, p.pack(&k0, &p0, 1.0, [0.0; 2]), &LmOptions::default());
        let kd = p.intrinsics(&rep.x);
        let (a, b) = (f.k.to_vec(), kd.to_vec());
        for i in 0..N_INTR {
            assert!(
                (a[i] - b[i]).abs() <= 1e-6 * b[i].abs().max(1e-3),
                "{i}: {a:?} vs {b:?}"
            );
        }
        for (v, q) in f.poses.iter().enumerate() {
            let d = p.pose(&rep.x, v);
            assert!((q.translation.vector - d.translation.vector).norm() < 1e-6);
        }
        let dense_rms = (rep.residuals.norm_squared() / (rep.residuals.len() / 2) as f64).sqrt();
        assert!((f.rms - dense_rms).abs() < 1e-9, "{} vs {dense_rms}", f.rms);
        // The covariance: σ²(JᵀJ)⁻¹'s intrinsics block of the dense Jacobian.
        let (r, n) = (rep.jacobian.nrows(), rep.jacobian.ncols());
        let s2 = 2.0 * rep.cost / (r - n) as f64;
        let full = (rep.jacobian.transpose() * &rep.jacobian)
            .try_inverse()
            .unwrap()
            * s2;
        let m = 6;
        assert_eq!(f.cov.nrows(), m);
        for i in 0..m {
            for j in 0..m {
                let d = full[(i, j)];
                let tol = 1e-6 * (full[(i, i)] * full[(j, j)]).sqrt();
                assert!(
                    (f.cov[(i, j)] - d).abs() <= tol,
                    "cov {i},{j}: {} vs {d}",
                    f.cov[(i, j)]
                );
            }
        }
        // And it found the truth to within its own 1σ scale.
        assert!((f.k.fx - k_true.fx).abs() < 5.0 * f.cov[(0, 0)].sqrt() + 0.5);
        assert!(
            (f.rms - 0.1 * std::f64::consts::SQRT_2).abs() < 0.03,
            "rms {}",
            f.rms
        );
    }

    #[test]
    fn the_view_jackknife_of_the_intrinsics_agrees_with_the_model_when_the_noise_is_white() {
        let (k, per_view, poses) = views();
        let ob: Vec<&[Obs]> = per_view.iter().map(Vec::as_slice).collect();
        let f = fit(&ob, &poses, &k, mask(), &LmOptions::default()).unwrap();
        let j = jackknife(&ob, &f, mask()).expect("jackknife");
        for i in 0..4 {
            let r = (j[(i, i)] / f.cov[(i, i)]).sqrt();
            assert!(
                (0.4..2.5).contains(&r),
                "parameter {i}: jackknife / model σ = {r}"
            );
        }
        // Corners labelled with their view index are refused, not misread.
        let bad: Vec<Obs> = per_view[0].iter().map(|o| Obs { view: 1, ..*o }).collect();
        let mut ob2 = ob.clone();
        ob2[0] = &bad;
        assert!(fit(&ob2, &poses, &k, mask(), &LmOptions::default()).is_none());
    }
}
