//! Cross-validation of the kernel correction when a fold's training set is larger than
//! [`super::MAX_CENTRES`] (`diagnose` on 10,000 poses).
//!
//! Subset of regressors with **one set of centres for every fold**, spread evenly through
//! all samples in time order: chosen from the inputs only (no target enters the choice), so
//! each fold's weights still see only its training targets. Fold `f`'s system is
//! `(Σ_{b≠f} K_mb K_bm + λ K_mm) W = Σ_{b≠f} K_mb Y_b`: every block's product `K_mb K_bm` is
//! computed once per length scale and summed, instead of a fresh `K_mn K_nm` (2·m²·n flops)
//! per fold. With per-fold centres (the earlier path) Series A's 7,147-sample folds cost
//! ≈ 1.1 TFlop per search; here `m²·n` once plus one `m³/3` factorisation per fold and ridge.
use faer::linalg::matmul::triangular::{matmul, BlockStructure};
use faer::linalg::solvers::Solve;
use faer::{Accum, Mat, Side};
use nalgebra::Vector3;
use rayon::prelude::*;

use super::{all_finite, centre_subset, kernel, sse_of, targets, FoldSse};

/// Centres of the shared-centre cross-validation (the final fit keeps
/// [`super::MAX_CENTRES`]): the cross-validation only ranks the grid's settings.
pub const MAX_CV_CENTRES: usize = 1000;

/// Per fold (as [`super::fold_errors`]): the fold's number of test samples and, per ridge,
/// the squared errors on its test and training samples; folds with fewer than 10 training
/// samples or no test sample are left out. `m` centres shared by every fold.
pub(super) fn fold_errors_shared(
    q: &[Vec<f64>],
    r: &[Vector3<f64>],
    fold: &[usize],
    n_folds: usize,
    ell: f64,
    lambdas: &[f64],
    m: usize,
) -> Vec<(usize, Vec<Option<FoldSse>>)> {
    let n = q.len();
    let all: Vec<usize> = (0..n).collect();
    let centres = centre_subset(&all, m);
    let m = centres.len();
    // K_cn: every sample against the centres (m × n), and K_mm from its centre columns.
    let kcn = kernel(q, &centres, &all, ell);
    let kmm = Mat::from_fn(m, m, |a, b| kcn[(a, centres[b])]);
    let members: Vec<Vec<usize>> = (0..n_folds)
        .map(|f| (0..n).filter(|&i| fold[i] == f).collect())
        .collect();
    // Each block's K_mb K_bm (lower triangle) and K_mb Y_b.
    let blocks: Vec<(Mat<f64>, Mat<f64>)> = members
        .par_iter()
        .map(|idx| {
            let kb = Mat::from_fn(m, idx.len(), |a, b| kcn[(a, idx[b])]);
            let mut g = Mat::<f64>::zeros(m, m);
            matmul(
                g.as_mut(),
                BlockStructure::TriangularLower,
                Accum::Replace,
                &kb,
                BlockStructure::Rectangular,
                kb.transpose(),
                BlockStructure::Rectangular,
                1.0,
                faer::get_global_parallelism(),
            );
            let h = &kb * targets(r, idx);
            (g, h)
        })
        .collect();
    (0..n_folds)
        .into_par_iter()
        .filter_map(|f| {
            let te = &members[f];
            let tr: Vec<usize> = (0..n).filter(|&i| fold[i] != f).collect();
            if tr.len() < 10 || te.is_empty() {
                return None;
            }
            let mut g = Mat::<f64>::zeros(m, m);
            let mut h = Mat::<f64>::zeros(m, 3);
            for (b, (gb, hb)) in blocks.iter().enumerate() {
                if b != f {
                    g += gb;
                    h += hb;
                }
            }
            let sse = lambdas
                .iter()
                .map(|&lam| {
                    // λ K_mm plus a tiny jitter (near-duplicate centres); lower triangle only.
                    let mut a = g.clone();
                    for j in 0..m {
                        for i in j..m {
                            a[(i, j)] += lam * kmm[(i, j)];
                        }
                        a[(j, j)] += 1e-9 * lam;
                    }
                    let w = a.llt(Side::Lower).ok()?.solve(&h);
                    if !all_finite(&w) {
                        return None;
                    }
                    let pred = kcn.transpose() * &w;
                    let rows = |idx: &[usize]| Mat::from_fn(idx.len(), 3, |a, j| pred[(idx[a], j)]);
                    Some(FoldSse {
                        test: sse_of(r, te, &rows(te)),
                        fit: sse_of(r, &tr, &rows(&tr)),
                        n_fit: tr.len(),
                    })
                })
                .collect();
            Some((te.len(), sse))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::super::RidgeSystem;
    use super::*;

    fn field(n: usize) -> (Vec<Vec<f64>>, Vec<Vector3<f64>>) {
        let q = super::super::tests::wave_inputs(n, [0.031, 0.0137, 0.053]);
        let r = q
            .iter()
            .enumerate()
            .map(|(i, x)| {
                let e = 0.01 * ((i * 7919 % 101) as f64 / 50.0 - 1.0);
                Vector3::new(0.1 * x[0].sin() + e, 0.05 * x[1] * x[2], 0.02 * x[2] - e)
            })
            .collect();
        (q, r)
    }

    /// The block sums give each fold the system it would build on its own with the same
    /// centres (`K_mn K_nm` of its training samples), so the same errors.
    #[test]
    fn block_sums_give_each_folds_own_system() {
        let n = 240;
        let (q, r) = field(n);
        let fold: Vec<usize> = (0..n).map(|i| i * 5 / n).collect();
        let m = 60;
        let lambdas = [0.03, 3.0];
        let got = fold_errors_shared(&q, &r, &fold, 5, 1.0, &lambdas, m);
        assert_eq!(got.len(), 5);
        let all: Vec<usize> = (0..n).collect();
        let centres = centre_subset(&all, m);
        for (f, (nte, sse)) in got.iter().enumerate() {
            let tr: Vec<usize> = (0..n).filter(|&i| fold[i] != f).collect();
            let te: Vec<usize> = (0..n).filter(|&i| fold[i] == f).collect();
            assert_eq!(*nte, te.len());
            let kmn = kernel(&q, &centres, &tr, 1.0);
            let sys = RidgeSystem {
                gram: &kmn * kmn.transpose(),
                reg: Some(kernel(&q, &centres, &centres, 1.0)),
                rhs: &kmn * targets(&r, &tr),
                centres: centres.clone(),
                kfit: Some(kmn.transpose().to_owned()),
            };
            for (li, &lam) in lambdas.iter().enumerate() {
                let w = sys.solve(lam).unwrap();
                let test = sse_of(&r, &te, &(kernel(&q, &te, &centres, 1.0) * &w));
                let fit = sse_of(&r, &tr, &sys.fitted(&w));
                let s = sse[li].expect("solved");
                assert!(
                    (s.test - test).abs() <= 1e-8 * test,
                    "fold {f}: {} vs {test}",
                    s.test
                );
                assert!(
                    (s.fit - fit).abs() <= 1e-8 * fit,
                    "fold {f}: {} vs {fit}",
                    s.fit
                );
                assert_eq!(s.n_fit, tr.len());
            }
        }
    }

    /// On a smooth field the shared-centre CV ranks the grid as the exact per-fold CV does
    /// and its CV RMS is within 5 % of the exact one at the best setting.
    #[test]
    fn shared_centres_rank_like_the_exact_cv() {
        let n = 600;
        let (q, r) = field(n);
        let fold: Vec<usize> = (0..n).map(|i| i * 5 / n).collect();
        let lambdas = [0.03, 0.3, 3.0];
        let rms = |e: &[(usize, Vec<Option<FoldSse>>)], li: usize| {
            let cnt: usize = e.iter().map(|x| x.0).sum();
            let s: f64 = e.iter().map(|x| x.1[li].unwrap().test).sum();
            (s / cnt as f64 / 3.0).sqrt()
        };
        let exact = super::super::fold_errors(&q, &r, &fold, 5, 1.0, &lambdas);
        let shared = fold_errors_shared(&q, &r, &fold, 5, 1.0, &lambdas, 200);
        let best = |e: &[(usize, Vec<Option<FoldSse>>)]| {
            (0..lambdas.len())
                .min_by(|&a, &b| rms(e, a).total_cmp(&rms(e, b)))
                .unwrap()
        };
        let (be, bs) = (best(&exact), best(&shared));
        assert_eq!(
            be,
            bs,
            "exact {:?} shared {:?}",
            rms(&exact, be),
            rms(&shared, bs)
        );
        let (a, b) = (rms(&exact, be), rms(&shared, bs));
        assert!((a - b).abs() <= 0.05 * a, "exact {a} vs shared {b}");
    }
}
