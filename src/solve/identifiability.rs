//! Automatic identifiability analysis of an identification Jacobian (`docs/effects.md` §5.3–5.4).
//!
//! Columns are scaled to unit norm (so mm and rad parameters compare), then taken in a
//! priority order (base, tool, then joints from the flange down to the base, then effect
//! parameters). A column whose distance to the span of the columns kept before it — the
//! sine of the angle between the column and that span — is below `tol` is *redundant*:
//! it is fixed, and the kept parameters it trades off with are named from the least-squares
//! coefficients of the column on the kept ones (e.g. `d1` ≈ `base_z`). This is a
//! rank-revealing QR with a prescribed pivot order (Khalil's base parameters, with the
//! choice of which member of a dependent set to keep made physically rather than by
//! column norm). The SVD of the kept scaled columns (faer) then gives the observability
//! indices O1…O5 and the condition number.
use nalgebra::{DMatrix, DVector};

use crate::model::{KinematicModel, ParamGroup};

/// Default sine threshold: a scaled column closer than this to the span of the kept ones
/// is treated as redundant.
pub const DEFAULT_TOL: f64 = 1e-4;

/// One parameter fixed as redundant.
#[derive(Debug, Clone, PartialEq)]
pub struct Dropped {
    /// Index into the analysed columns.
    pub index: usize,
    /// Sine of the angle between the column and the span of the kept columns.
    pub sine: f64,
    /// Kept parameters it trades off with and their coefficients (scaled columns).
    pub partners: Vec<(String, f64)>,
    pub reason: String,
}

/// Result of [`analyse`].
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Identifiability {
    /// Names of the analysed columns (indices below refer to these).
    pub names: Vec<String>,
    /// Kept columns (indices) and their sine to the span of the columns kept before them.
    pub kept: Vec<(usize, f64)>,
    pub dropped: Vec<Dropped>,
    /// Singular values of the kept scaled Jacobian, descending.
    pub singular_values: Vec<f64>,
    /// σ_max / σ_min.
    pub condition: f64,
    /// Observability indices O1…O5 (Sun & Hollerbach) of the kept scaled Jacobian.
    pub o1: f64,
    pub o2: f64,
    pub o3: f64,
    pub o4: f64,
    pub o5: f64,
    /// The weakest kept combination: the right singular vector of σ_min, largest entries.
    pub weakest: Vec<(String, f64)>,
}

/// Priority order of the free columns of `model` (`free` are parameter indices), followed
/// by `n_total − free.len()` extra (effect) columns.
pub fn priority_order(model: &KinematicModel, free: &[usize], n_total: usize) -> Vec<usize> {
    let ps = model.params();
    let rank = |i: usize| -> (usize, usize, usize) {
        let p = &ps[free[i]];
        match p.group {
            ParamGroup::Base => (0, 0, i),
            ParamGroup::Tool => (1, 0, i),
            ParamGroup::Flange => (2, 0, i),
            // Joints from the flange side: the base/tool absorb the end joints' redundant
            // parameters first (seed 001 fixes d1, φ6, d6).
            ParamGroup::Joint(j) => (3, usize::MAX - j, i),
        }
    };
    let mut idx: Vec<usize> = (0..free.len()).collect();
    idx.sort_by_key(|&i| rank(i));
    idx.extend(free.len()..n_total);
    idx
}

/// Analyse the columns of `j` (named by `names`) in the order `priority`.
pub fn analyse(
    j: &DMatrix<f64>,
    names: &[String],
    priority: &[usize],
    tol: f64,
) -> Identifiability {
    analyse_with_floor(j, names, priority, tol, None)
}

/// A column's least independent norm, below which the parameter is not determined.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Floor {
    /// Noise of one residual row (the residual's unit, e.g. mm).
    pub noise: f64,
    /// Tolerance of the parameter (its unit): the parameter is determined when the poses
    /// give it a standard deviation at most this large.
    pub tol: f64,
    /// The parameter's unit as printed (`mm`, `°`) and the factor from the column's unit to it.
    pub unit: &'static str,
    pub scale: f64,
}

/// [`analyse`] that also drops a column whose part independent of the kept columns is too
/// small for the noise: with `floors[k] = Some(f)`, column `k` is dropped when the standard
/// deviation the poses give its parameter, `f.noise / (‖c_k‖ · sine_k)` (the least-squares
/// standard deviation of the last column of a fit on the columns kept so far), exceeds
/// `f.tol`. Such a parameter stays where it was (the caller's nominal) instead of moving
/// along a direction the poses hardly see.
pub fn analyse_with_floor(
    j: &DMatrix<f64>,
    names: &[String],
    priority: &[usize],
    tol: f64,
    floors: Option<&[Option<Floor>]>,
) -> Identifiability {
    let m = j.nrows();
    let mut q: Vec<DVector<f64>> = Vec::new();
    let mut kept: Vec<(usize, f64)> = Vec::new();
    let mut dropped = Vec::new();
    let unit = |k: usize| -> Option<DVector<f64>> {
        let c = j.column(k).into_owned();
        let n = c.norm();
        (n > 0.0 && n.is_finite()).then(|| c / n)
    };
    for &k in priority {
        let Some(c) = unit(k) else {
            dropped.push(Dropped {
                index: k,
                sine: 0.0,
                partners: Vec::new(),
                reason: "has no effect on the measurements (zero Jacobian column)".into(),
            });
            continue;
        };
        let mut r = c.clone();
        for _ in 0..2 {
            for b in &q {
                let d = b.dot(&r);
                r.axpy(-d, b, 1.0);
            }
        }
        let s = r.norm();
        // Standard deviation the poses give this parameter (its unit), against its floor.
        let undetermined = floors
            .and_then(|f| f.get(k).copied().flatten())
            .map(|f| (f, f.noise / (j.column(k).norm() * s)))
            .filter(|(f, sd)| sd.is_nan() || *sd > f.tol);
        if s < tol || undetermined.is_some() {
            // Coefficients of c on the kept (scaled) columns.
            let mut a = DMatrix::zeros(m, kept.len());
            for (c_i, &(kk, _)) in kept.iter().enumerate() {
                if let Some(u) = unit(kk) {
                    a.set_column(c_i, &u);
                }
            }
            let ata = a.tr_mul(&a);
            let coef = super::lm::solve_spd(&ata, &a.tr_mul(&c));
            let mut partners: Vec<(String, f64)> = kept
                .iter()
                .enumerate()
                .map(|(ci, &(kk, _))| (names[kk].clone(), coef[ci]))
                .filter(|(_, v)| v.abs() > 0.05)
                .collect();
            partners.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
            partners.truncate(4);
            let list = partners
                .iter()
                .map(|(n, v)| format!("{n} ({v:+.2})"))
                .collect::<Vec<_>>()
                .join(", ");
            let reason = if s < 1e-8 {
                format!("redundant: its effect is exactly a combination of {list}")
            } else if let (true, Some((f, sd))) = (s >= tol, undetermined) {
                let near = if list.is_empty() {
                    String::new()
                } else {
                    format!(", within sin={s:.1e} of a combination of {list}")
                };
                format!(
                    "not determined by these poses: ±{:.2}{} from them (more than the ±{:.2}{} a geometric calibration must reach){near}",
                    sd * f.scale,
                    f.unit,
                    f.tol * f.scale,
                    f.unit
                )
            } else {
                format!(
                    "not identifiable from these poses: within sin={s:.1e} of a combination of {list}"
                )
            };
            dropped.push(Dropped {
                index: k,
                sine: s,
                partners,
                reason,
            });
        } else {
            q.push(r / s);
            kept.push((k, s));
        }
    }
    let mut out = Identifiability {
        names: names.to_vec(),
        kept,
        dropped,
        ..Default::default()
    };
    if out.kept.is_empty() {
        return out;
    }
    let nk = out.kept.len();
    // Column norms once (computing the norm inside the element closure made this
    // O(rows² · columns): 90 % of a 10,000-pose identification).
    let norms: Vec<f64> = out.kept.iter().map(|&(k, _)| j.column(k).norm()).collect();
    let js = faer::Mat::<f64>::from_fn(m, nk, |r, c| j[(r, out.kept[c].0)] / norms[c]);
    if let Ok(svd) = js.thin_svd() {
        let s: Vec<f64> = (0..nk).map(|i| svd.S()[i]).collect();
        let smax = s[0];
        let smin = s[nk - 1];
        out.condition = smax / smin;
        out.o1 = (s.iter().map(|v| v.ln()).sum::<f64>() / nk as f64).exp() / (m as f64).sqrt();
        out.o2 = smin / smax;
        out.o3 = smin;
        out.o4 = smin * smin / smax;
        out.o5 = 1.0 / s.iter().map(|v| 1.0 / v).sum::<f64>();
        let v = svd.V();
        let mut w: Vec<(String, f64)> = (0..nk)
            .map(|r| (names[out.kept[r].0].clone(), v[(r, nk - 1)]))
            .filter(|(_, x)| x.abs() > 0.2)
            .collect();
        w.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
        out.weakest = w;
        out.singular_values = s;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn detects_exact_and_near_dependencies_in_priority_order() {
        // columns: a, b, c = a + 2b (exact), d independent, e = a + 1e-6·noise (near)
        let m = 50;
        let a = DVector::from_fn(m, |i, _| (i as f64 * 0.3).sin());
        let b = DVector::from_fn(m, |i, _| (i as f64 * 0.11).cos());
        let c = &a + &b * 2.0;
        let d = DVector::from_fn(m, |i, _| ((i * i) as f64 * 0.01).sin());
        let e = &a + DVector::from_fn(m, |i, _| if i == 3 { 1e-7 } else { 0.0 });
        let j = DMatrix::from_columns(&[a, b, c, d, e, DVector::zeros(m)]);
        let names: Vec<String> = ["a", "b", "c", "d", "e", "z"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        let r = analyse(&j, &names, &[0, 1, 2, 3, 4, 5], 1e-4);
        let kept: Vec<usize> = r.kept.iter().map(|k| k.0).collect();
        assert_eq!(kept, vec![0, 1, 3]);
        let dropped: Vec<usize> = r.dropped.iter().map(|d| d.index).collect();
        assert_eq!(dropped, vec![2, 4, 5]);
        assert_eq!(r.dropped[0].partners[0].0, "b");
        assert!(
            r.dropped[0].reason.contains("redundant"),
            "{}",
            r.dropped[0].reason
        );
        assert!(r.condition.is_finite() && r.condition >= 1.0);
        // A different priority keeps c and drops b instead.
        let r2 = analyse(&j, &names, &[2, 0, 1, 3], 1e-4);
        assert_eq!(r2.dropped[0].index, 1);
    }
}
