//! Identification-Jacobian quality of a pose set (`docs/effects.md` §5.3 / §5.4).
//!
//! `J` stacks `model.point_param_jacobian(q)` (3 rows per pose), keeps the free parameters
//! only and scales each column by a fixed scale (its RMS over the candidate set, so mm and
//! rad columns are comparable). With singular values σ_1 ≥ … ≥ σ_L over m poses:
//! O1 = (σ_1⋯σ_L)^{1/L}/√m (Borm & Menq, D-optimality), condition number σ_1/σ_L.
use nalgebra::{DMatrix, DVector};

use crate::model::KinematicModel;

/// Observability of one pose set.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Observability {
    /// Number of poses.
    pub poses: usize,
    /// Number of free parameters (columns).
    pub params: usize,
    /// O1 (0 when any direction is unobservable).
    #[serde(with = "super::file::nonfinite_f64")]
    pub o1: f64,
    /// σ_1/σ_L (infinite when σ_L = 0).
    #[serde(with = "super::file::nonfinite_f64")]
    pub condition: f64,
    #[serde(with = "super::file::nonfinite_f64")]
    pub sigma_max: f64,
    #[serde(with = "super::file::nonfinite_f64")]
    pub sigma_min: f64,
    /// Free parameters that are unidentifiable with this pose set: each entry lists the
    /// parameters of one (near-)null direction of J, largest component first.
    pub unidentifiable: Vec<Vec<String>>,
}

/// Free-parameter columns of the stacked, unscaled Jacobian.
pub fn stacked_jacobian(model: &KinematicModel, qs: &[&[f64]]) -> DMatrix<f64> {
    let free = model.free_indices();
    let mut j = DMatrix::zeros(3 * qs.len(), free.len());
    for (k, q) in qs.iter().enumerate() {
        let (_, jp) = model.point_param_jacobian(q);
        for (c, &fi) in free.iter().enumerate() {
            for r in 0..3 {
                j[(3 * k + r, c)] = jp[(r, fi)];
            }
        }
    }
    j
}

/// Column scales: RMS of each column over the rows (1 where a column is zero).
pub fn column_scales(j: &DMatrix<f64>) -> DVector<f64> {
    let rows = j.nrows().max(1) as f64;
    DVector::from_iterator(
        j.ncols(),
        j.column_iter().map(|c| {
            let s = c.norm() / rows.sqrt();
            if s > 0.0 {
                s
            } else {
                1.0
            }
        }),
    )
}

/// Divide column `c` of `j` by `scales[c]`.
pub fn scale_columns(j: &mut DMatrix<f64>, scales: &DVector<f64>) {
    for (c, mut col) in j.column_iter_mut().enumerate() {
        col /= scales[c];
    }
}

/// O1, condition number and null directions of a scaled stacked Jacobian with `poses` poses.
pub fn analyse(j: &DMatrix<f64>, poses: usize, names: &[String], rel_tol: f64) -> Observability {
    let l = j.ncols();
    let empty = Observability {
        poses,
        params: l,
        o1: 0.0,
        condition: f64::INFINITY,
        sigma_max: 0.0,
        sigma_min: 0.0,
        unidentifiable: if l > 0 { vec![names.to_vec()] } else { vec![] },
    };
    if l == 0 || poses == 0 || !j.iter().all(|x| x.is_finite()) {
        return empty;
    }
    // J (3m × L) with 3m ≥ L is typical; pad with zero rows otherwise so the SVD has L values.
    let jj = if j.nrows() >= l {
        j.clone()
    } else {
        let mut p = DMatrix::zeros(l, l);
        p.view_mut((0, 0), (j.nrows(), l)).copy_from(j);
        p
    };
    let svd = jj.svd(false, true);
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
    let sv: Vec<f64> = order.iter().map(|&i| svd.singular_values[i]).collect();
    let smax = sv[0];
    let smin = sv[l - 1];
    let o1 = if smin > 0.0 {
        (sv.iter().map(|s| s.ln()).sum::<f64>() / l as f64).exp() / (poses as f64).sqrt()
    } else {
        0.0
    };
    let mut unid = Vec::new();
    if let Some(vt) = &svd.v_t {
        for (k, &i) in order.iter().enumerate() {
            if sv[k] <= rel_tol * smax || smax == 0.0 {
                let row = vt.row(i);
                let mut comps: Vec<(usize, f64)> =
                    row.iter().enumerate().map(|(c, v)| (c, v.abs())).collect();
                comps.sort_by(|a, b| b.1.total_cmp(&a.1));
                let big = comps[0].1;
                unid.push(
                    comps
                        .iter()
                        .filter(|(_, v)| *v >= 0.2 * big)
                        .map(|(c, _)| names[*c].clone())
                        .collect(),
                );
            }
        }
    }
    Observability {
        poses,
        params: l,
        o1,
        condition: if smin > 0.0 {
            smax / smin
        } else {
            f64::INFINITY
        },
        sigma_max: smax,
        sigma_min: smin,
        unidentifiable: unid,
    }
}

/// Names of the free parameters in column order.
pub fn free_names(model: &KinematicModel) -> Vec<String> {
    model
        .free_indices()
        .into_iter()
        .map(|i| model.params()[i].name.clone())
        .collect()
}

/// Observability of the poses `qs` with columns scaled by `scales`.
pub fn observability(
    model: &KinematicModel,
    qs: &[&[f64]],
    scales: &DVector<f64>,
    rel_tol: f64,
) -> Observability {
    let mut j = stacked_jacobian(model, qs);
    scale_columns(&mut j, scales);
    analyse(&j, qs.len(), &free_names(model), rel_tol)
}

/// Greedy D-optimal selection of `n` rows-blocks (3 rows per pose) from a scaled stacked
/// Jacobian: each step adds the pose maximising `log det(M + J_iᵀJ_i)`, i.e.
/// `log det(I₃ + J_i M⁻¹ J_iᵀ)`, starting from a small ridge `M₀ = δI`. Returns pose indices
/// in the order chosen.
pub fn select_d_optimal(j: &DMatrix<f64>, n: usize) -> Vec<usize> {
    let m = j.nrows() / 3;
    let l = j.ncols();
    let n = n.min(m);
    if l == 0 || n == 0 {
        return (0..n).collect();
    }
    let blocks: Vec<DMatrix<f64>> = (0..m).map(|k| j.rows(3 * k, 3).into_owned()).collect();
    let trace: f64 = j.iter().map(|x| x * x).sum::<f64>() / m as f64;
    let delta = 1e-6 * trace.max(1e-300) / l as f64;
    let mut info = DMatrix::<f64>::identity(l, l) * delta;
    let mut chosen = Vec::with_capacity(n);
    let mut used = vec![false; m];
    for _ in 0..n {
        let Some(inv) = info.clone().cholesky().map(|c| c.inverse()) else {
            break;
        };
        let mut best: Option<(usize, f64)> = None;
        for (k, b) in blocks.iter().enumerate() {
            if used[k] {
                continue;
            }
            let s = DMatrix::<f64>::identity(3, 3) + b * &inv * b.transpose();
            let ld = s.determinant().max(1e-300).ln();
            if best.is_none_or(|(_, v)| ld > v) {
                best = Some((k, ld));
            }
        }
        let Some((k, _)) = best else { break };
        used[k] = true;
        chosen.push(k);
        info += blocks[k].transpose() * &blocks[k];
    }
    chosen
}
