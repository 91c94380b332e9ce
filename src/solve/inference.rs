//! Small statistics kit: F distribution tail, linear least squares by SVD with column
//! scaling, orthogonal projection and time-blocked linear cross-validation.
use nalgebra::{DMatrix, DVector};

fn ln_gamma(x: f64) -> f64 {
    // Lanczos approximation (g = 7, n = 9).
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        let pi = std::f64::consts::PI;
        return (pi / (pi * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut a = C[0];
    let t = x + 7.5;
    for (i, c) in C.iter().enumerate().skip(1) {
        a += c / (x + i as f64);
    }
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

fn beta_cf(a: f64, b: f64, x: f64) -> f64 {
    let (qab, qap, qam) = (a + b, a + 1.0, a - 1.0);
    let tiny = 1e-300;
    let mut c = 1.0;
    let mut d = 1.0 - qab * x / qap;
    if d.abs() < tiny {
        d = tiny;
    }
    d = 1.0 / d;
    let mut h = d;
    for m in 1..400 {
        let m = m as f64;
        let m2 = 2.0 * m;
        let aa = m * (b - m) * x / ((qam + m2) * (a + m2));
        d = 1.0 + aa * d;
        if d.abs() < tiny {
            d = tiny;
        }
        c = 1.0 + aa / c;
        if c.abs() < tiny {
            c = tiny;
        }
        d = 1.0 / d;
        h *= d * c;
        let aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2));
        d = 1.0 + aa * d;
        if d.abs() < tiny {
            d = tiny;
        }
        c = 1.0 + aa / c;
        if c.abs() < tiny {
            c = tiny;
        }
        d = 1.0 / d;
        let del = d * c;
        h *= del;
        if (del - 1.0).abs() < 1e-14 {
            break;
        }
    }
    h
}

/// Regularised incomplete beta function I_x(a, b).
pub fn beta_inc(a: f64, b: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    if x >= 1.0 {
        return 1.0;
    }
    let lbt = ln_gamma(a + b) - ln_gamma(a) - ln_gamma(b) + a * x.ln() + b * (1.0 - x).ln();
    let bt = lbt.exp();
    if x < (a + 1.0) / (a + b + 2.0) {
        bt * beta_cf(a, b, x) / a
    } else {
        1.0 - bt * beta_cf(b, a, 1.0 - x) / b
    }
}

/// Upper tail P(F > f) of the F distribution with (d1, d2) degrees of freedom.
pub fn f_sf(f: f64, d1: f64, d2: f64) -> f64 {
    if !f.is_finite() {
        return 0.0;
    }
    if f <= 0.0 {
        return 1.0;
    }
    beta_inc(d2 / 2.0, d1 / 2.0, d2 / (d2 + d1 * f)).clamp(0.0, 1.0)
}

/// Least squares `min |A x − b|` by SVD of the column-scaled `A`; singular values below
/// `1e-10·σ_max` are dropped. Returns `x` and the rank.
pub fn lstsq(a: &DMatrix<f64>, b: &DVector<f64>) -> (DVector<f64>, usize) {
    let p = a.ncols();
    if p == 0 {
        return (DVector::zeros(0), 0);
    }
    let scale: Vec<f64> = (0..p)
        .map(|j| {
            let n = a.column(j).norm();
            if n > 0.0 {
                1.0 / n
            } else {
                0.0
            }
        })
        .collect();
    let mut s = a.clone();
    for (j, sc) in scale.iter().enumerate() {
        s.column_mut(j).scale_mut(*sc);
    }
    let svd = s.svd(true, true);
    let smax = svd.singular_values.max();
    let tol = smax * 1e-10;
    let rank = svd.singular_values.iter().filter(|v| **v > tol).count();
    let x = svd.solve(b, tol).unwrap_or_else(|_| DVector::zeros(p));
    (
        DVector::from_iterator(p, x.iter().zip(&scale).map(|(v, s)| v * s)),
        rank,
    )
}

/// `(A^T A)^+` of the column-scaled `A`, unscaled back: the parameter covariance per unit
/// noise variance.
pub fn normal_inverse(a: &DMatrix<f64>) -> DMatrix<f64> {
    let p = a.ncols();
    let scale: Vec<f64> = (0..p)
        .map(|j| {
            let n = a.column(j).norm();
            if n > 0.0 {
                1.0 / n
            } else {
                0.0
            }
        })
        .collect();
    let mut s = a.clone();
    for (j, sc) in scale.iter().enumerate() {
        s.column_mut(j).scale_mut(*sc);
    }
    let ata = s.transpose() * &s;
    let inv = ata
        .clone()
        .pseudo_inverse(1e-12)
        .unwrap_or_else(|_| DMatrix::zeros(p, p));
    DMatrix::from_fn(p, p, |i, j| inv[(i, j)] * scale[i] * scale[j])
}

/// Orthonormal basis (columns) of the column space of `a` (thin SVD, rank-revealing).
pub fn orth_basis(a: &DMatrix<f64>) -> DMatrix<f64> {
    if a.ncols() == 0 {
        return DMatrix::zeros(a.nrows(), 0);
    }
    let mut s = a.clone();
    for mut c in s.column_iter_mut() {
        let n = c.norm();
        if n > 0.0 {
            c /= n;
        }
    }
    let svd = s.svd(true, false);
    let u = svd.u.expect("u requested");
    let smax = svd.singular_values.max();
    let keep: Vec<usize> = (0..svd.singular_values.len())
        .filter(|&i| svd.singular_values[i] > smax * 1e-9)
        .collect();
    DMatrix::from_fn(a.nrows(), keep.len(), |i, j| u[(i, keep[j])])
}

/// `(I − Q Qᵀ) M` for an orthonormal `Q`.
pub fn project_out(q: &DMatrix<f64>, m: &DMatrix<f64>) -> DMatrix<f64> {
    project_out_t(q, &q.transpose(), m)
}

/// [`project_out`] with `Qᵀ` given (`qt`): a caller projecting many blocks against one `Q`
/// transposes it once (the same products, the same values).
pub fn project_out_t(q: &DMatrix<f64>, qt: &DMatrix<f64>, m: &DMatrix<f64>) -> DMatrix<f64> {
    if q.ncols() == 0 {
        return m.clone();
    }
    m - q * (qt * m)
}

/// How much of a candidate block lies outside the current model's column space: the
/// largest sine of the principal angles between `span(G)` and `span(J)` (given `G` and
/// `G̃ = (I − P_J) G`). 1 = some direction of the block is orthogonal to the model,
/// 0 = the model absorbs the whole block (not identifiable: not an effect).
pub fn independence(g: &DMatrix<f64>, g_perp: &DMatrix<f64>) -> f64 {
    if g.ncols() == 0 || g.column_iter().any(|c| c.norm() == 0.0) {
        return 0.0;
    }
    // Orthonormal basis of span(G) expressed as G·T, then apply the same T to G̃.
    let mut gn = g.clone();
    let mut gpn = g_perp.clone();
    for j in 0..g.ncols() {
        let n = g.column(j).norm();
        gn.column_mut(j).scale_mut(1.0 / n);
        gpn.column_mut(j).scale_mut(1.0 / n);
    }
    let svd = gn.svd(false, true);
    let Some(vt) = svd.v_t else {
        return 0.0;
    };
    let smax = svd.singular_values.max();
    let mut best: f64 = 0.0;
    for (i, sv) in svd.singular_values.iter().enumerate() {
        if *sv <= 1e-6 * smax {
            continue;
        }
        // unit direction u_i = G v_i / σ_i; its projection is G̃ v_i / σ_i
        let v = vt.row(i).transpose();
        let s = (&gpn * v).norm() / sv;
        best = best.max(s);
    }
    best.min(1.0)
}

/// Time-blocked linear cross-validation of `min |[J G] x − r|`, prepared once for `J` so
/// that each candidate block `G` costs only its own cross products (normal equations on
/// column-scaled matrices, solved by a truncated symmetric eigendecomposition).
pub struct CvBase {
    folds: Vec<CvFold>,
    jscale: Vec<f64>,
    /// `J` column-scaled (what every candidate is tested against).
    js: DMatrix<f64>,
}

struct CvFold {
    test: Vec<usize>,
    train: Vec<usize>,
    /// The transpose of the fold's training rows of the scaled `J` (formed once), the
    /// training rows of `r`, and their cross products.
    jt_t: DMatrix<f64>,
    rt: DVector<f64>,
    jtj: DMatrix<f64>,
    jtr: DVector<f64>,
}

fn col_scales(a: &DMatrix<f64>) -> Vec<f64> {
    a.column_iter()
        .map(|c| {
            let n = c.norm();
            if n > 0.0 {
                1.0 / n
            } else {
                0.0
            }
        })
        .collect()
}

fn scaled(a: &DMatrix<f64>, s: &[f64]) -> DMatrix<f64> {
    let mut m = a.clone();
    for (j, sc) in s.iter().enumerate() {
        m.column_mut(j).scale_mut(*sc);
    }
    m
}

impl CvBase {
    /// Prepare the folds (`row_fold[i]` = fold of row `i`).
    pub fn new(j: &DMatrix<f64>, r: &DVector<f64>, row_fold: &[usize], n_folds: usize) -> Self {
        let jscale = col_scales(j);
        let js = scaled(j, &jscale);
        let folds = (0..n_folds)
            .filter_map(|f| {
                let test: Vec<usize> = (0..r.len()).filter(|&i| row_fold[i] == f).collect();
                let train: Vec<usize> = (0..r.len()).filter(|&i| row_fold[i] != f).collect();
                if test.is_empty() || train.len() <= j.ncols() {
                    return None;
                }
                let jt = js.select_rows(&train);
                let rt = r.select_rows(&train);
                let jt_t = jt.transpose();
                Some(CvFold {
                    jtj: &jt_t * &jt,
                    jtr: &jt_t * &rt,
                    jt_t,
                    rt,
                    test,
                    train,
                })
            })
            .collect();
        CvBase { folds, jscale, js }
    }

    /// CV RMS per row of the fit augmented with the columns `g` (`g` may have no column).
    /// `j` and `r` are the ones given to [`CvBase::new`] (its scaled `J` and each fold's
    /// training rows are kept from there, not rebuilt per candidate).
    pub fn rms(&self, j: &DMatrix<f64>, g: &DMatrix<f64>, r: &DVector<f64>) -> f64 {
        debug_assert_eq!(j.shape(), self.js.shape());
        debug_assert_eq!(self.jscale.len(), j.ncols());
        let js = &self.js;
        let gs = scaled(g, &col_scales(g));
        let (p0, pk) = (j.ncols(), g.ncols());
        let mut sse = 0.0;
        let mut cnt = 0usize;
        for f in &self.folds {
            let p = p0 + pk;
            let mut m = DMatrix::zeros(p, p);
            let mut b = DVector::zeros(p);
            m.view_mut((0, 0), (p0, p0)).copy_from(&f.jtj);
            b.rows_mut(0, p0).copy_from(&f.jtr);
            if pk > 0 {
                let gt = gs.select_rows(&f.train);
                let gt_t = gt.transpose();
                let jg = &f.jt_t * &gt;
                m.view_mut((0, p0), (p0, pk)).copy_from(&jg);
                m.view_mut((p0, 0), (pk, p0)).copy_from(&jg.transpose());
                m.view_mut((p0, p0), (pk, pk)).copy_from(&(&gt_t * &gt));
                b.rows_mut(p0, pk).copy_from(&(&gt_t * &f.rt));
            }
            let eig = m.symmetric_eigen();
            let lmax = eig.eigenvalues.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            let mut x = DVector::zeros(p);
            for (k, l) in eig.eigenvalues.iter().enumerate() {
                if *l > 1e-12 * lmax {
                    let v = eig.eigenvectors.column(k);
                    x += v * (v.dot(&b) / l);
                }
            }
            for &i in &f.test {
                let mut pred = 0.0;
                for c in 0..p0 {
                    pred += js[(i, c)] * x[c];
                }
                for c in 0..pk {
                    pred += gs[(i, c)] * x[p0 + c];
                }
                sse += (r[i] - pred).powi(2);
                cnt += 1;
            }
        }
        if cnt == 0 {
            f64::NAN
        } else {
            (sse / cnt as f64).sqrt()
        }
    }
}

/// One-shot time-blocked linear cross-validation of `min |A x − r|` (see [`CvBase`]).
pub fn cv_rms(a: &DMatrix<f64>, r: &DVector<f64>, row_fold: &[usize], n_folds: usize) -> f64 {
    CvBase::new(a, r, row_fold, n_folds).rms(a, &DMatrix::zeros(a.nrows(), 0), r)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn f_tail_matches_known_values() {
        // F(1, ∞) = χ²₁: P(F > 3.841) ≈ 0.05; F(2, 20) critical 3.49 at 0.05.
        assert!((f_sf(3.841_458_8, 1.0, 1e7) - 0.05).abs() < 1e-3);
        assert!((f_sf(3.492_828, 2.0, 20.0) - 0.05).abs() < 1e-4);
        assert!((f_sf(1.0, 5.0, 5.0) - 0.5).abs() < 1e-9);
    }

    #[test]
    fn projection_independence() {
        let a = DMatrix::from_fn(50, 2, |i, j| ((i * (j + 1)) as f64 * 0.37).sin());
        let q = orth_basis(&a);
        // a column inside span(a) is absorbed, an unrelated one is not
        let g_in = DMatrix::from_fn(50, 1, |i, _| a[(i, 0)] - 2.0 * a[(i, 1)]);
        let g_out = DMatrix::from_fn(50, 1, |i, _| ((i as f64) * 1.91).cos());
        assert!(independence(&g_in, &project_out(&q, &g_in)) < 1e-8);
        assert!(independence(&g_out, &project_out(&q, &g_out)) > 0.5);
        let (x, rank) = lstsq(&a, &DVector::from_fn(50, |i, _| a[(i, 0)] * 3.0));
        assert_eq!(rank, 2);
        assert!((x[0] - 3.0).abs() < 1e-9 && x[1].abs() < 1e-9);
    }
}
