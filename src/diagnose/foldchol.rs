//! Time-blocked cross-validation of a kernel ridge system with one shared factorisation
//! (`diagnose` speed).
//!
//! Fold `f` of a time-blocked CV trains on every block but `f`: the system
//! `(K + λI)_{−f,−f} W_f = Y_{−f}`. Factorised one fold at a time this costs
//! `k · ((k−1)/k)³ · n³/3` per ridge (5 folds: 2.56 · n³/3). Here the blocked Cholesky of
//! the whole `K + λI` runs once, block by block in time order; before block `f` is
//! eliminated, the trailing Schur complement `T_f` (blocks ≥ `f` given blocks < `f`) is
//! the matrix the later blocks need given the earlier ones, so fold `f`'s factor is the
//! factor of the earlier blocks (already computed) plus the Cholesky of `T_f` without block
//! `f`'s rows and columns: `(1 + Σ_f ((k−1−f)/k)³) · n³/3` in all (5 folds: 1.8 · n³/3,
//! 1.42× fewer flops). In exact arithmetic the weights are the ones of the per-fold
//! factorisation (the Cholesky factor of a matrix is unique, and the factor of
//! `[[A_PP, A_PR], [A_RP, A_RR]]` is `[[L_PP, 0], [L_RP, chol(A_RR − L_RP L_RPᵀ)]]`);
//! in floating point they agree to rounding (the test below: ≤ 1e-9 relative).
use faer::linalg::matmul::triangular::{matmul, BlockStructure};
use faer::linalg::triangular_solve::{
    solve_lower_triangular_in_place, solve_upper_triangular_in_place,
};
use faer::{Accum, Mat, MatRef};

/// `A X = B` for lower-triangular `A` (in place).
fn lower_solve(a: MatRef<'_, f64>, b: &mut Mat<f64>) {
    solve_lower_triangular_in_place(a, b.as_mut(), faer::get_global_parallelism());
}

/// `Aᵀ X = B` for lower-triangular `A` (in place).
fn lower_t_solve(a: MatRef<'_, f64>, b: &mut Mat<f64>) {
    solve_upper_triangular_in_place(a.transpose(), b.as_mut(), faer::get_global_parallelism());
}

/// Cholesky factor (lower) of the lower triangle of `a`; `None` if not positive definite.
/// The steps of faer's `Llt::new` (lower triangle copied into zeros, factorised in place
/// with the global parallelism, upper triangle zeroed: the same factor bit for bit) without
/// its two extra copies of the matrix.
fn chol(a: MatRef<'_, f64>) -> Option<Mat<f64>> {
    use faer::dyn_stack::{MemBuffer, MemStack};
    use faer::linalg::cholesky::llt::factor::{cholesky_in_place, cholesky_in_place_scratch};
    let n = a.nrows();
    let mut l = Mat::<f64>::zeros(n, n);
    l.copy_from_triangular_lower(a);
    let par = faer::get_global_parallelism();
    let mut mem = MemBuffer::new(cholesky_in_place_scratch::<f64>(n, par, Default::default()));
    cholesky_in_place(
        l.as_mut(),
        Default::default(),
        par,
        MemStack::new(&mut mem),
        Default::default(),
    )
    .ok()?;
    for j in 1..n {
        l.as_mut().col_mut(j).subrows_mut(0, j).fill(0.0);
    }
    Some(l)
}

/// Weights of every fold's ridge system, the folds being the contiguous blocks
/// `bounds[f]..bounds[f + 1]` of the samples (`bounds` ascending, from 0 to `k.nrows()`):
/// entry `f` is `(K + λI)_{−f,−f}⁻¹ Y_{−f}` (rows: the samples outside block `f`, in
/// order), or `None` where this factorisation could not be completed (a block that is not
/// numerically positive definite: the caller factorises that fold on its own, which then
/// decides). `k` is symmetric (only its lower triangle is read); `y` has one row per sample.
pub fn fold_weights(
    k: MatRef<'_, f64>,
    lambda: f64,
    y: MatRef<'_, f64>,
    bounds: &[usize],
) -> Vec<Option<Mat<f64>>> {
    let n = k.nrows();
    let nb = bounds.len().saturating_sub(1);
    let mut out: Vec<Option<Mat<f64>>> = vec![None; nb];
    if nb == 0 || bounds[nb] != n || bounds.windows(2).any(|w| w[0] > w[1]) {
        return out;
    }
    // Trailing Schur complement (lower triangle valid) and the factor built so far.
    let mut t = k.to_owned();
    for i in 0..n {
        t[(i, i)] += lambda;
    }
    let mut l = Mat::<f64>::zeros(n, n);
    for f in 0..nb {
        let (s, e) = (bounds[f], bounds[f + 1]);
        let (np, nr) = (s, n - e);
        // Fold f: factor [[L_PP, 0], [L_RP, chol(T_RR)]], solved by substitution.
        let lrr = if nr > 0 {
            chol(t.as_ref().submatrix(e, e, nr, nr))
        } else {
            Some(Mat::zeros(0, 0))
        };
        if let Some(lrr) = lrr {
            let lpp = l.as_ref().submatrix(0, 0, np, np);
            let lrp = l.as_ref().submatrix(e, 0, nr, np);
            let mut zp = y.submatrix(0, 0, np, y.ncols()).to_owned();
            lower_solve(lpp, &mut zp);
            let mut zr = y.submatrix(e, 0, nr, y.ncols()).to_owned() - lrp * &zp;
            lower_solve(lrr.as_ref(), &mut zr);
            lower_t_solve(lrr.as_ref(), &mut zr);
            let mut wp = &zp - lrp.transpose() * &zr;
            lower_t_solve(lpp, &mut wp);
            let w = Mat::from_fn(np + nr, y.ncols(), |i, j| {
                if i < np {
                    wp[(i, j)]
                } else {
                    zr[(i - np, j)]
                }
            });
            let finite = (0..w.nrows()).all(|i| (0..w.ncols()).all(|j| w[(i, j)].is_finite()));
            out[f] = finite.then_some(w);
        }
        if f + 1 == nb {
            break;
        }
        // Eliminate block f: L_ff, L_Rf and T_RR −= L_Rf L_Rfᵀ (lower triangle).
        let Some(lff) = chol(t.as_ref().submatrix(s, s, e - s, e - s)) else {
            // Later folds need this block eliminated: leave them to the caller.
            break;
        };
        let mut x = t.as_ref().submatrix(e, s, nr, e - s).transpose().to_owned();
        lower_solve(lff.as_ref(), &mut x);
        l.as_mut().submatrix_mut(s, s, e - s, e - s).copy_from(&lff);
        l.as_mut()
            .submatrix_mut(e, s, nr, e - s)
            .copy_from(x.transpose());
        matmul(
            t.as_mut().submatrix_mut(e, e, nr, nr),
            BlockStructure::TriangularLower,
            Accum::Add,
            x.transpose(),
            BlockStructure::Rectangular,
            &x,
            BlockStructure::Rectangular,
            -1.0,
            faer::get_global_parallelism(),
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::Side;

    /// Every fold's weights equal those of its own factorisation (to rounding), on a
    /// Gaussian kernel of uneven folds, small and large ridges.
    #[test]
    fn shared_factorisation_gives_every_folds_weights() {
        let n = 97;
        let x: Vec<[f64; 2]> = (0..n)
            .map(|i| {
                let t = i as f64;
                [(t * 0.37).sin() * 2.0, (t * 0.11).cos()]
            })
            .collect();
        let k = Mat::from_fn(n, n, |a, b| {
            let d2 = (x[a][0] - x[b][0]).powi(2) + (x[a][1] - x[b][1]).powi(2);
            (-d2 / 2.0).exp()
        });
        let y = Mat::from_fn(n, 3, |i, j| ((i * (j + 2)) as f64 * 0.7).sin());
        let bounds = [0, 19, 40, 58, 77, 97];
        for lambda in [0.03, 3.0] {
            let got = fold_weights(k.as_ref(), lambda, y.as_ref(), &bounds);
            for f in 0..5 {
                let tr: Vec<usize> = (0..n)
                    .filter(|&i| i < bounds[f] || i >= bounds[f + 1])
                    .collect();
                let mut a = Mat::from_fn(tr.len(), tr.len(), |p, q| k[(tr[p], tr[q])]);
                for i in 0..tr.len() {
                    a[(i, i)] += lambda;
                }
                let yt = Mat::from_fn(tr.len(), 3, |p, j| y[(tr[p], j)]);
                use faer::linalg::solvers::Solve;
                let want = a.llt(Side::Lower).unwrap().solve(&yt);
                let w = got[f].as_ref().expect("factorised");
                let scale = (0..tr.len())
                    .flat_map(|i| (0..3).map(move |j| (i, j)))
                    .map(|(i, j)| want[(i, j)].abs())
                    .fold(0.0f64, f64::max);
                let worst = (0..tr.len())
                    .flat_map(|i| (0..3).map(move |j| (i, j)))
                    .map(|(i, j)| (w[(i, j)] - want[(i, j)]).abs())
                    .fold(0.0f64, f64::max);
                assert!(
                    worst <= 1e-9 * scale,
                    "fold {f}, λ {lambda}: {worst} vs {scale}"
                );
            }
        }
    }

    /// Inconsistent fold bounds leave every fold to the caller (no panic).
    #[test]
    fn bad_bounds_are_left_to_the_caller() {
        let k = Mat::<f64>::identity(4, 4);
        let y = Mat::<f64>::zeros(4, 3);
        assert!(fold_weights(k.as_ref(), 1.0, y.as_ref(), &[0, 3, 2, 4])
            .iter()
            .all(Option::is_none));
        assert!(fold_weights(k.as_ref(), 1.0, y.as_ref(), &[0, 3])
            .iter()
            .all(Option::is_none));
    }
}
