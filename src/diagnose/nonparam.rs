//! Data-driven correction of what no physical effect explains: Gaussian-kernel ridge
//! regression (a GP posterior mean) of the 3-D residual on joint space, with the length
//! scale and ridge chosen by time-blocked cross-validation. Used only after the physical
//! effects are exhausted, and labelled `nonparametric`.
use faer::{linalg::solvers::Solve, Mat, Side};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use super::error::RbfFileError;
use crate::model::KinematicModel;
use serde_json::{json, Map, Value};

mod shared;
pub use shared::MAX_CV_CENTRES;

/// A fitted kernel correction: `Σ_k w_k exp(−|q − c_k|² / (2ℓ²))` (mm), `q` in rad.
#[derive(Debug, Clone, PartialEq)]
pub struct Rbf {
    /// When true the inputs are the wrist centre and marker positions in MDH frame 1 (which
    /// turns with joint 1; units of 100 mm) and the correction is expressed in that frame:
    /// gravity-driven effects do not depend on `q1` there.
    pub arm_frame: bool,
    pub length_scale: f64,
    pub centers: Vec<Vec<f64>>,
    pub weights: Vec<[f64; 3]>,
}

fn kern(a: &[f64], b: &[f64], ell: f64) -> f64 {
    let d2: f64 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
    (-d2 / (2.0 * ell * ell)).exp()
}

/// Kernel matrix `K[a, b] = k(q[rows[a]], q[cols[b]])` (dense, faer). A square kernel of
/// one index set (`rows == cols`) evaluates each pair once (half the `exp` calls).
fn kernel(q: &[Vec<f64>], rows: &[usize], cols: &[usize], ell: f64) -> Mat<f64> {
    if rows != cols {
        return Mat::from_fn(rows.len(), cols.len(), |a, b| {
            kern(&q[rows[a]], &q[cols[b]], ell)
        });
    }
    let n = rows.len();
    let mut k = Mat::<f64>::zeros(n, n);
    for b in 0..n {
        let qb = &q[cols[b]];
        k[(b, b)] = 1.0;
        for a in b + 1..n {
            let v = kern(&q[rows[a]], qb, ell);
            k[(a, b)] = v;
            k[(b, a)] = v;
        }
    }
    k
}

/// The `rows × cols` block of a kernel matrix of all samples.
fn sub_kernel(full: &Mat<f64>, rows: &[usize], cols: &[usize]) -> Mat<f64> {
    Mat::from_fn(rows.len(), cols.len(), |a, b| full[(rows[a], cols[b])])
}

/// Residual targets of the samples `idx` as an `n × 3` matrix.
fn targets(r: &[Vector3<f64>], idx: &[usize]) -> Mat<f64> {
    Mat::from_fn(idx.len(), 3, |i, j| r[idx[i]][j])
}

/// Above this many training samples the correction uses a subset of regressors (Nyström):
/// `MAX_CENTRES` centres spread evenly through the (time-ordered) samples. The exact kernel
/// system costs O(n³); the subset one O(n·m²).
pub const MAX_CENTRES: usize = 2000;

/// `m` indices spread evenly over `idx` (all of them when `idx.len() ≤ m`).
fn centre_subset(idx: &[usize], m: usize) -> Vec<usize> {
    if idx.len() <= m {
        return idx.to_vec();
    }
    (0..m).map(|k| idx[k * idx.len() / m]).collect()
}

fn all_finite(w: &Mat<f64>) -> bool {
    (0..w.nrows()).all(|i| (0..w.ncols()).all(|j| w[(i, j)].is_finite()))
}

/// The kernel ridge system of one training set, factorised per λ.
///
/// Exact: `W = (K + λI)⁻¹ Y`, centres = the training samples. Subset of regressors
/// (training set larger than [`MAX_CENTRES`]): `W = (K_mn K_nm + λ K_mm)⁻¹ K_mn Y`, centres =
/// `m` of the samples: the same GP posterior mean (noise variance λ) on a Nyström kernel.
/// Solved by a blocked Cholesky (faer); nalgebra's unblocked one made a 2,000-pose
/// diagnosis take ~40 s.
struct RidgeSystem {
    centres: Vec<usize>,
    /// `K_nm` (subset only): predicts the training samples from the centres' weights.
    kfit: Option<Mat<f64>>,
    /// `K` (exact) or `K_mn K_nm` (subset).
    gram: Mat<f64>,
    /// `I` (exact: `None`) or `K_mm` (subset): what λ multiplies.
    reg: Option<Mat<f64>>,
    /// `Y` (exact) or `K_mn Y` (subset).
    rhs: Mat<f64>,
}

impl RidgeSystem {
    /// The system of the samples `tr`; `full` is the kernel of all samples when already
    /// computed (the exact system's kernel is then its `tr × tr` block: the same values).
    fn new(
        q: &[Vec<f64>],
        r: &[Vector3<f64>],
        tr: &[usize],
        ell: f64,
        full: Option<&Mat<f64>>,
    ) -> RidgeSystem {
        let centres = centre_subset(tr, MAX_CENTRES);
        let y = targets(r, tr);
        if centres.len() == tr.len() {
            RidgeSystem {
                gram: match full {
                    Some(k) => sub_kernel(k, tr, tr),
                    None => kernel(q, tr, tr, ell),
                },
                reg: None,
                rhs: y,
                centres,
                kfit: None,
            }
        } else {
            let kmn = kernel(q, &centres, tr, ell);
            RidgeSystem {
                gram: &kmn * kmn.transpose(),
                reg: Some(kernel(q, &centres, &centres, ell)),
                rhs: &kmn * &y,
                centres,
                kfit: Some(kmn.transpose().to_owned()),
            }
        }
    }

    /// Weights for ridge `lambda`; `None` if not positive definite or not finite.
    fn solve(&self, lambda: f64) -> Option<Mat<f64>> {
        let m = self.gram.nrows();
        let mut a = self.gram.clone();
        match &self.reg {
            None => (0..m).for_each(|i| a[(i, i)] += lambda),
            Some(kmm) => {
                // λ K_mm plus a tiny jitter: K_mm of near-duplicate centres is singular.
                for i in 0..m {
                    for j in 0..m {
                        a[(i, j)] += lambda * kmm[(i, j)];
                    }
                    a[(i, i)] += 1e-9 * lambda;
                }
            }
        }
        let w = a.llt(Side::Lower).ok()?.solve(&self.rhs);
        all_finite(&w).then_some(w)
    }

    /// Prediction at the training samples (`n × 3`) of the weights `w`.
    fn fitted(&self, w: &Mat<f64>) -> Mat<f64> {
        match &self.kfit {
            None => &self.gram * w,
            Some(knm) => knm * w,
        }
    }
}

/// Squared errors of one fold under one ridge: on the fold's test samples (held out) and on
/// its training samples (the fit itself).
#[derive(Debug, Clone, Copy)]
struct FoldSse {
    test: f64,
    fit: f64,
    n_fit: usize,
}

/// Sum of squared 3-D differences `r[idx[a]] − pred[a]`.
fn sse_of(r: &[Vector3<f64>], idx: &[usize], pred: &Mat<f64>) -> f64 {
    idx.iter()
        .enumerate()
        .map(|(a, &i)| {
            (r[i] - Vector3::new(pred[(a, 0)], pred[(a, 1)], pred[(a, 2)])).norm_squared()
        })
        .sum()
}

/// Fold boundaries (`n_folds + 1`, from 0 to the number of samples) when every fold is one
/// contiguous block in fold order (the time-blocked folds of [`super::folds`]); `None`
/// otherwise.
fn block_bounds(fold: &[usize], n_folds: usize) -> Option<Vec<usize>> {
    (fold.windows(2).all(|w| w[0] <= w[1]) && fold.iter().all(|&f| f < n_folds)).then(|| {
        (0..=n_folds)
            .map(|f| fold.partition_point(|&g| g < f))
            .collect()
    })
}

/// Squared prediction error per fold and per λ, on the fold's test samples and on its own
/// training samples: for each fold the training kernel system is built once and factorised
/// once per λ (folds run in parallel). When every fold's system is exact (no subset of
/// regressors), the kernel of all samples is evaluated once and every fold takes its blocks
/// from it: each pair's `exp` once instead of once per fold that uses it (5× fewer with 5
/// folds; the same values, so the same errors). When a fold's training set exceeds
/// [`MAX_CENTRES`], every fold uses the same [`MAX_CV_CENTRES`] centres ([`shared`]).
fn fold_errors(
    q: &[Vec<f64>],
    r: &[Vector3<f64>],
    fold: &[usize],
    n_folds: usize,
    ell: f64,
    lambdas: &[f64],
) -> Vec<(usize, Vec<Option<FoldSse>>)> {
    let n = q.len();
    let all: Vec<usize> = (0..n).collect();
    let exact = (0..n_folds).all(|f| fold.iter().filter(|&&g| g != f).count() <= MAX_CENTRES);
    if !exact {
        // Subset of regressors: centres shared by every fold ([`shared`]).
        return shared::fold_errors_shared(q, r, fold, n_folds, ell, lambdas, MAX_CV_CENTRES);
    }
    let full = exact.then(|| kernel(q, &all, &all, ell));
    // Time-blocked folds (contiguous blocks): every fold's weights from one shared blocked
    // factorisation per λ ([`super::foldchol`]: the same weights in exact arithmetic, 1.42×
    // fewer flops with 5 folds); a fold it could not complete is factorised on its own below.
    let shared: Vec<Vec<Option<Mat<f64>>>> = match (&full, block_bounds(fold, n_folds)) {
        (Some(k), Some(bounds)) => {
            let y = targets(r, &all);
            lambdas
                .par_iter()
                .map(|&lam| super::foldchol::fold_weights(k.as_ref(), lam, y.as_ref(), &bounds))
                .collect()
        }
        _ => Vec::new(),
    };
    (0..n_folds)
        .into_par_iter()
        .filter_map(|f| {
            let tr: Vec<usize> = (0..n).filter(|&i| fold[i] != f).collect();
            let te: Vec<usize> = (0..n).filter(|&i| fold[i] == f).collect();
            if tr.len() < 10 || te.is_empty() {
                return None;
            }
            let sys = RidgeSystem::new(q, r, &tr, ell, full.as_ref());
            let kx = match &full {
                Some(k) => sub_kernel(k, &te, &sys.centres),
                None => kernel(q, &te, &sys.centres, ell),
            };
            let sse = lambdas
                .iter()
                .enumerate()
                .map(|(li, &lam)| {
                    let w = match shared.get(li).and_then(|w| w.get(f)) {
                        Some(Some(w)) => w.clone(),
                        _ => sys.solve(lam)?,
                    };
                    Some(FoldSse {
                        test: sse_of(r, &te, &(&kx * &w)),
                        fit: sse_of(r, &tr, &sys.fitted(&w)),
                        n_fit: tr.len(),
                    })
                })
                .collect();
            Some((te.len(), sse))
        })
        .collect()
}

/// Inputs (wrist centre and marker in MDH frame 1, 100 mm units) and the rotation tracker ← frame 1.
pub fn arm_frame(model: &KinematicModel, q: &[f64]) -> (Vec<f64>, Matrix3<f64>) {
    let f1 = model.joint_frame(q, 1);
    let r = model.base().rotation * f1.rotation;
    // Features: the wrist centre and the marker in frame 1 (units of 100 mm). Gravity-driven
    // effects are smooth functions of where the masses are, not of q1.
    let n = model.dof();
    let to1 =
        |p: nalgebra::Vector3<f64>| f1.rotation.inverse() * (p - f1.translation.vector) / 100.0;
    let w = to1(model
        .joint_frame(q, n.saturating_sub(2).max(1))
        .translation
        .vector);
    let m = to1(model.tool_pose_in_base(q).translation.vector);
    (
        vec![w.x, w.y, w.z, m.x, m.y, m.z],
        *r.to_rotation_matrix().matrix(),
    )
}

/// Inputs and residuals in the arm-frame representation.
pub fn arm_frame_data(
    model: &KinematicModel,
    q: &[Vec<f64>],
    r: &[Vector3<f64>],
) -> (Vec<Vec<f64>>, Vec<Vector3<f64>>) {
    q.iter()
        .zip(r)
        .map(|(qk, rk)| {
            let (x, rot) = arm_frame(model, qk);
            (x, rot.transpose() * rk)
        })
        .unzip()
}

impl Rbf {
    /// Correction (mm, tracker frame) at joint angles `q` (rad) for `model`.
    pub fn correction(&self, model: &KinematicModel, q: &[f64]) -> Vector3<f64> {
        if self.arm_frame {
            let (x, rot) = arm_frame(model, q);
            rot * self.predict(&x)
        } else {
            self.predict(q)
        }
    }

    /// Correction (mm) at the raw inputs.
    pub fn predict(&self, q: &[f64]) -> Vector3<f64> {
        let mut v = Vector3::zeros();
        for (c, w) in self.centers.iter().zip(&self.weights) {
            let k = kern(q, c, self.length_scale);
            v += Vector3::new(w[0], w[1], w[2]) * k;
        }
        v
    }

    /// Fit on residuals `r` (mm) at `q` (rad) with ridge `lambda`. `None` if singular.
    pub fn fit(q: &[Vec<f64>], r: &[Vector3<f64>], ell: f64, lambda: f64) -> Option<Rbf> {
        let idx: Vec<usize> = (0..q.len()).collect();
        let sys = RidgeSystem::new(q, r, &idx, ell, None);
        let w = sys.solve(lambda)?;
        Some(Rbf {
            arm_frame: false,
            length_scale: ell,
            centers: sys.centres.iter().map(|&i| q[i].clone()).collect(),
            weights: (0..w.nrows())
                .map(|i| [w[(i, 0)], w[(i, 1)], w[(i, 2)]])
                .collect(),
        })
    }

    /// File form (degrees for the centres and length scale).
    pub fn to_json(&self) -> Map<String, Value> {
        let mut m = Map::new();
        m.insert("model".into(), json!("rbf_kernel_ridge"));
        m.insert(
            "frame".into(),
            json!(if self.arm_frame { "joint1" } else { "tracker" }),
        );
        m.insert(
            "length_scale_deg".into(),
            json!(self.length_scale.to_degrees()),
        );
        m.insert(
            "centers_deg".into(),
            json!(self
                .centers
                .iter()
                .map(|c| c.iter().map(|x| x.to_degrees()).collect::<Vec<_>>())
                .collect::<Vec<_>>()),
        );
        m.insert("weights_mm".into(), json!(self.weights));
        m
    }

    /// Read the file form.
    pub fn from_json(p: &Map<String, Value>) -> Result<Rbf, RbfFileError> {
        let ell = p
            .get("length_scale_deg")
            .and_then(|v| v.as_f64())
            .filter(|v| v.is_finite() && *v > 0.0)
            .ok_or(RbfFileError::LengthScale)?;
        let rows = |k: &str| -> Result<Vec<Vec<f64>>, RbfFileError> {
            p.get(k)
                .and_then(|v| v.as_array())
                .ok_or_else(|| RbfFileError::Missing(k.into()))?
                .iter()
                .map(|r| {
                    r.as_array()
                        .ok_or_else(|| RbfFileError::Row(k.into()))?
                        .iter()
                        .map(|x| {
                            x.as_f64()
                                .filter(|v| v.is_finite())
                                .ok_or_else(|| RbfFileError::Number(k.into()))
                        })
                        .collect()
                })
                .collect()
        };
        let centers: Vec<Vec<f64>> = rows("centers_deg")?
            .into_iter()
            .map(|c| c.into_iter().map(|x| x.to_radians()).collect())
            .collect();
        let w = rows("weights_mm")?;
        if w.len() != centers.len() || w.iter().any(|r| r.len() != 3) {
            return Err(RbfFileError::Weights);
        }
        Ok(Rbf {
            arm_frame: p.get("frame").and_then(|v| v.as_str()) == Some("joint1"),
            length_scale: ell.to_radians(),
            centers,
            weights: w.into_iter().map(|r| [r[0], r[1], r[2]]).collect(),
        })
    }
}

/// One setting of the cross-validated grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RbfSetting {
    pub length_scale: f64,
    pub lambda: f64,
    /// CV RMS (mm, per axis) on the held-out folds.
    pub cv_rms: f64,
    /// RMS (mm, per axis) of each fold's fit on its own training samples, pooled: what the
    /// correction's training RMS will be, to compare with `cv_rms` (the overfitting gap).
    pub fit_rms: f64,
}

impl RbfSetting {
    /// Expected held-out / training gap of this setting: `cv_rms / fit_rms − 1`.
    pub fn gap(&self) -> f64 {
        if self.fit_rms > 0.0 {
            self.cv_rms / self.fit_rms - 1.0
        } else {
            f64::INFINITY
        }
    }
}

/// Result of the cross-validated search.
#[derive(Debug, Clone)]
pub struct RbfCv {
    pub length_scale: f64,
    pub lambda: f64,
    /// CV RMS (mm, 3-D) of the residual without / with the correction.
    pub cv_rms_before: f64,
    pub cv_rms_after: f64,
    /// In-fold training RMS of the chosen setting (see [`RbfSetting::fit_rms`]).
    pub fit_rms: f64,
    /// Every setting that could be evaluated on every fold.
    pub grid: Vec<RbfSetting>,
}

impl RbfCv {
    fn of(&self, s: &RbfSetting) -> RbfCv {
        RbfCv {
            length_scale: s.length_scale,
            lambda: s.lambda,
            cv_rms_before: self.cv_rms_before,
            cv_rms_after: s.cv_rms,
            fit_rms: s.fit_rms,
            grid: self.grid.clone(),
        }
    }

    /// The best setting (lowest CV RMS) among those whose expected held-out / training gap
    /// ([`RbfSetting::gap`]) is at most `max_gap` or whose CV RMS exceeds the fit by at
    /// most `min_abs_mm`: a correction that predicts its own training poses far better than
    /// unseen ones has learned the poses, not the robot. `None` when no setting qualifies.
    pub fn within_gap(&self, max_gap: f64, min_abs_mm: f64) -> Option<RbfCv> {
        self.grid
            .iter()
            .filter(|s| s.gap() <= max_gap || s.cv_rms - s.fit_rms <= min_abs_mm)
            .min_by(|a, b| a.cv_rms.total_cmp(&b.cv_rms))
            .map(|s| self.of(s))
    }
}

/// Ridges and length scales (inputs' units) of the cross-validated grid.
const LAMBDAS: [f64; 4] = [0.03, 0.3, 3.0, 30.0];
const ELLS: [f64; 4] = [0.5, 1.0, 2.0, 4.0];

/// Choose length scale and ridge by cross-validation over the given folds (index of the
/// fold of each sample). Returns the best setting (with the whole grid), or `None` with
/// fewer than 20 samples.
pub fn cross_validate(
    q: &[Vec<f64>],
    r: &[Vector3<f64>],
    fold: &[usize],
    n_folds: usize,
) -> Option<RbfCv> {
    if q.len() < 20 {
        return None;
    }
    let var: f64 = r.iter().map(|v| v.norm_squared()).sum::<f64>() / r.len() as f64;
    let before = (var / 3.0).sqrt();
    // Every length scale in parallel (each runs its folds in parallel too): 20 kernel
    // systems keep both cores busy where 5 folds alone left one idle half the time.
    let per_ell: Vec<Vec<(usize, Vec<Option<FoldSse>>)>> = ELLS
        .par_iter()
        .map(|&ell| fold_errors(q, r, fold, n_folds, ell, &LAMBDAS))
        .collect();
    let mut grid = Vec::new();
    for (&ell, per_fold) in ELLS.iter().zip(&per_ell) {
        for (li, &lam) in LAMBDAS.iter().enumerate() {
            // A setting whose factorisation failed on any fold is not comparable: skip it.
            let Some(e) = per_fold
                .iter()
                .map(|(_, e)| e[li])
                .collect::<Option<Vec<_>>>()
            else {
                continue;
            };
            let cnt: usize = per_fold.iter().map(|(n, _)| n).sum();
            let n_fit: usize = e.iter().map(|x| x.n_fit).sum();
            if cnt == 0 || n_fit == 0 {
                continue;
            }
            grid.push(RbfSetting {
                length_scale: ell,
                lambda: lam,
                cv_rms: (e.iter().map(|x| x.test).sum::<f64>() / cnt as f64 / 3.0).sqrt(),
                fit_rms: (e.iter().map(|x| x.fit).sum::<f64>() / n_fit as f64 / 3.0).sqrt(),
            });
        }
    }
    let best = *grid.iter().min_by(|a, b| a.cv_rms.total_cmp(&b.cv_rms))?;
    Some(
        RbfCv {
            length_scale: 0.0,
            lambda: 0.0,
            cv_rms_before: before,
            cv_rms_after: 0.0,
            fit_rms: 0.0,
            grid,
        }
        .of(&best),
    )
}

/// Cross-validated (per-axis) RMS of the residual without / with a correction of fixed
/// length scale and ridge, over the given folds.
pub fn cv_fixed(
    q: &[Vec<f64>],
    r: &[Vector3<f64>],
    fold: &[usize],
    n_folds: usize,
    ell: f64,
    lambda: f64,
) -> Option<(f64, f64)> {
    let per_fold = fold_errors(q, r, fold, n_folds, ell, &[lambda]);
    let mut sse1 = 0.0;
    let mut cnt = 0usize;
    for (n, e) in &per_fold {
        sse1 += e[0]?.test;
        cnt += n;
    }
    // Same test samples as the folds that were fitted.
    let mut sse0 = 0.0;
    for f in 0..n_folds {
        let tr = fold.iter().filter(|&&g| g != f).count();
        if tr < 10 {
            continue;
        }
        sse0 += (0..q.len())
            .filter(|&i| fold[i] == f)
            .map(|i| r[i].norm_squared())
            .sum::<f64>();
    }
    (cnt > 0).then(|| {
        (
            (sse0 / cnt as f64 / 3.0).sqrt(),
            (sse1 / cnt as f64 / 3.0).sqrt(),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `n` smooth 3-D inputs `[1.5 sin(w₀ i), cos(w₁ i), sin(w₂ i)]`.
    pub(super) fn wave_inputs(n: usize, w: [f64; 3]) -> Vec<Vec<f64>> {
        (0..n)
            .map(|i| {
                let t = i as f64;
                vec![(t * w[0]).sin() * 1.5, (t * w[1]).cos(), (t * w[2]).sin()]
            })
            .collect()
    }

    /// Above [`MAX_CENTRES`] samples the subset-of-regressors system predicts what the
    /// exact one does on a smooth field (and keeps only `MAX_CENTRES` centres).
    #[test]
    fn subset_of_regressors_matches_the_exact_system() {
        let n = MAX_CENTRES + 400;
        let q = wave_inputs(n, [0.011, 0.0037, 0.023]);
        let r: Vec<Vector3<f64>> = q
            .iter()
            .map(|x| Vector3::new(0.1 * x[0].sin(), 0.05 * x[1] * x[2], 0.02 * x[2]))
            .collect();
        let sub = Rbf::fit(&q, &r, 1.0, 0.03).unwrap();
        assert_eq!(sub.centers.len(), MAX_CENTRES);
        let idx: Vec<usize> = (0..n).collect();
        let exact = RidgeSystem {
            centres: idx.clone(),
            gram: kernel(&q, &idx, &idx, 1.0),
            reg: None,
            rhs: targets(&r, &idx),
            kfit: None,
        };
        let w = exact.solve(0.03).unwrap();
        let mut worst: f64 = 0.0;
        for probe in [[0.3, 0.2, -0.4], [-1.1, 0.9, 0.5], [1.2, -0.5, 0.0]] {
            let mut e = Vector3::zeros();
            for (i, c) in q.iter().enumerate() {
                e += Vector3::new(w[(i, 0)], w[(i, 1)], w[(i, 2)]) * kern(&probe, c, 1.0);
            }
            worst = worst.max((sub.predict(&probe) - e).norm());
        }
        assert!(worst < 2e-3, "subset vs exact: {worst} mm");
    }

    #[test]
    fn rbf_learns_a_smooth_field_and_round_trips() {
        let q: Vec<Vec<f64>> = (0..80)
            .map(|i| vec![(i as f64 * 0.07).sin() * 1.5, (i as f64 * 0.13).cos()])
            .collect();
        let r: Vec<Vector3<f64>> = q
            .iter()
            .map(|x| Vector3::new(0.1 * x[0].sin(), 0.05 * x[1], 0.0))
            .collect();
        let fold: Vec<usize> = (0..80).map(|i| i * 4 / 80).collect();
        let cv = cross_validate(&q, &r, &fold, 4).unwrap();
        assert!(cv.cv_rms_after < 0.3 * cv.cv_rms_before, "{cv:?}");
        let m = Rbf::fit(&q, &r, cv.length_scale, cv.lambda).unwrap();
        let back = Rbf::from_json(&m.to_json()).unwrap();
        let a = m.predict(&[0.2, 0.3]);
        let b = back.predict(&[0.2, 0.3]);
        assert!((a - b).norm() < 1e-9);
    }
}
