//! The transmission error map stage: after the chain of named effects, every joint's angular
//! transmission error as a Fourier series of its own angle ([`TransmissionMap`]), all joints
//! at once, estimated on what the chain leaves by ridge regression through the joint-angle
//! columns `∂p/∂θ_j`:
//!
//! `min_x ‖r − A x‖² + λ ‖x‖²`, `A[pose, (h, j, cos|sin)] = ∂p/∂θ_j · (cos hq_j | sin hq_j)`.
//!
//! The number of harmonics `H` and the ridge `λ` (relative to the mean diagonal of `AᵀA`)
//! are chosen by time-blocked cross-validation on the training poses, under the rule the
//! kernel correction follows: the best CV among the settings whose CV RMS exceeds their own
//! in-fold training RMS by at most `correction_max_gap` (or by [`OVERFIT_MIN_MM`]), and the
//! map is kept only when its CV RMS is at least `transmission_map_min_gain` below the
//! residual's. Columns are ordered harmonic-major (`h`, then joint), so the settings with
//! fewer harmonics are leading blocks of one set of normal equations per fold.
//!
//! Why (docs/findings.md, round 9): on the real UR10 series the named ripples leave a
//! residual that a per-joint function of the joint's own angle explains where a kernel on
//! the 6-D joint space has no neighbours (grid poses 11–14° apart).
use faer::{
    linalg::solvers::{DenseSolveCore, Solve},
    Mat, Side,
};
use nalgebra::Vector3;
use rayon::prelude::*;

use super::effects::{
    joint_angle_columns, spread, Block, Effect, EffectModel, JointRange, TransmissionMap,
};
use super::fit::{residuals, State};
use super::{Options, OVERFIT_MIN_MM};
use crate::solve::obs::PoseObs;

/// Harmonic counts the cross-validation tries.
pub const MAP_HARMONICS: [u32; 6] = [4, 8, 16, 24, 32, 48];
/// Ridge values tried, relative to the mean diagonal of `AᵀA` (half decades).
pub const MAP_RIDGE: [f64; 9] = [1e-4, 3e-4, 1e-3, 3e-3, 1e-2, 3e-2, 1e-1, 3e-1, 1.0];
/// A joint whose training angles spread less than this (rad, standard deviation) gets no
/// map: its map would be a constant, which the joint's zero offset already is.
pub const MIN_JOINT_SPREAD: f64 = 0.05;

/// One setting of the cross-validation.
#[derive(Debug, Clone, PartialEq)]
pub struct MapSetting {
    /// The joints mapped (1-based).
    pub joints: Vec<usize>,
    pub harmonics: u32,
    /// Ridge relative to the mean diagonal of `AᵀA`.
    pub ridge: f64,
    /// Out-of-fold RMS (3-D per pose, mm).
    pub cv_rms: f64,
    /// In-fold training RMS of the same fits (mm).
    pub fit_rms: f64,
}

/// The chosen map: the setting, the residual's RMS before (the CV of predicting zero) and
/// every setting tried.
#[derive(Debug, Clone)]
pub struct MapChoice {
    pub chosen: MapSetting,
    pub cv_rms_before: f64,
    pub grid: Vec<MapSetting>,
    /// The fitted maps (one per mapped joint), internal units.
    pub effects: Vec<Effect>,
    /// Covariance (rad²) of all the maps' coefficients, in the effects' order (each
    /// effect's `cos 1q, sin 1q, …` after the previous effect's): the ridge posterior
    /// `σ² (AᵀA + λI)⁻¹` (`σ²` the training residual variance after the maps) plus the
    /// delete-one-block jackknife over contiguous time blocks ([`fit_map`]).
    pub cov: Mat<f64>,
}

impl MapChoice {
    /// The map of joint `joint` (1-based) at angle `q` (rad): `δθ` and its stated standard
    /// deviation (rad, from [`MapChoice::cov`]); `None` for a joint without a map.
    pub fn curve(&self, joint: usize, q: f64) -> Option<(f64, f64)> {
        let mut off = 0;
        for e in &self.effects {
            let n = e.coefs.len();
            if e.block.joint() == Some(joint) {
                let phi: Vec<f64> = (0..n / 2)
                    .flat_map(|k| {
                        let (s, c) = ((k + 1) as f64 * q).sin_cos();
                        [c, s]
                    })
                    .collect();
                let v = TransmissionMap::value(&e.coefs, q);
                let mut var = 0.0;
                for a in 0..n {
                    for b in 0..n {
                        var += phi[a] * self.cov[(off + a, off + b)] * phi[b];
                    }
                }
                return Some((v, var.max(0.0).sqrt()));
            }
            off += n;
        }
        None
    }
}

/// The joints (0-based) that move enough in `train` to carry a map and have a joint-angle
/// column.
fn mapped_joints(state: &State, train: &[PoseObs]) -> Vec<usize> {
    (0..state.model.dof())
        .filter(|&j| {
            spread(train.iter().filter_map(|o| o.ctx.q.get(j).copied())) >= MIN_JOINT_SPREAD
        })
        .collect()
}

/// Normal equations of a set of poses: `AᵀA`, `Aᵀr`, `rᵀr`, and its pose count.
#[derive(Clone)]
struct Normal {
    g: Mat<f64>,
    b: Mat<f64>,
    c: f64,
    n: usize,
}

impl Normal {
    fn zeros(ncol: usize) -> Normal {
        Normal {
            g: Mat::zeros(ncol, ncol),
            b: Mat::zeros(ncol, 1),
            c: 0.0,
            n: 0,
        }
    }
    fn add(&mut self, o: &Normal) {
        self.g += &o.g;
        self.b += &o.b;
        self.c += o.c;
        self.n += o.n;
    }
    fn minus(&self, o: &Normal) -> Normal {
        Normal {
            g: &self.g - &o.g,
            b: &self.b - &o.b,
            c: self.c - o.c,
            n: self.n - o.n,
        }
    }
    /// The normal equations on the columns `idx` only.
    fn sub(&self, idx: &[usize]) -> Normal {
        Normal {
            g: Mat::from_fn(idx.len(), idx.len(), |a, b| self.g[(idx[a], idx[b])]),
            b: Mat::from_fn(idx.len(), 1, |a, _| self.b[(idx[a], 0)]),
            c: self.c,
            n: self.n,
        }
    }
    /// `x` of the ridge system `(G + λI) x = b` (`None` when not positive definite).
    fn solve(&self, lambda: f64) -> Option<Mat<f64>> {
        let mut m = self.g.clone();
        for i in 0..m.nrows() {
            m[(i, i)] += lambda;
        }
        Some(m.llt(Side::Lower).ok()?.solve(&self.b))
    }
    /// `‖r − A x‖²` from the normal equations.
    fn sse(&self, x: &Mat<f64>) -> f64 {
        let gx = &self.g * x;
        let (mut xgx, mut xb) = (0.0, 0.0);
        for i in 0..x.nrows() {
            xgx += x[(i, 0)] * gx[(i, 0)];
            xb += x[(i, 0)] * self.b[(i, 0)];
        }
        (self.c - 2.0 * xb + xgx).max(0.0)
    }
    /// The ridge `ridge` relative to the mean diagonal.
    fn lambda(&self, ridge: f64) -> f64 {
        let k = self.g.nrows().max(1);
        ridge * (0..self.g.nrows()).map(|i| self.g[(i, i)]).sum::<f64>() / k as f64
    }
}

/// Column of harmonic `h` (0-based), mapped joint `ji` (index into the mapped joints),
/// cos (0) or sin (1), with `nj` mapped joints: harmonic-major.
fn col(h: usize, ji: usize, cs: usize, nj: usize) -> usize {
    (h * nj + ji) * 2 + cs
}

/// The columns of the maps of the mapped joints `subset` (indices into the mapped joints)
/// with `harmonics` harmonics, in the effects' order (joint-major: each joint's `cos 1q,
/// sin 1q, cos 2q, …`).
fn columns(subset: &[usize], harmonics: u32, nj: usize) -> Vec<usize> {
    subset
        .iter()
        .flat_map(|&ji| {
            (0..harmonics as usize).flat_map(move |h| [col(h, ji, 0, nj), col(h, ji, 1, nj)])
        })
        .collect()
}

/// Sub-blocks per cross-validation fold for the jackknife of the chosen map (contiguous in
/// time inside each fold).
const JACKKNIFE_PER_FOLD: usize = 4;

/// A setting must lower the CV RMS of the maps chosen so far by this fraction to add a joint.
const JOINT_MIN_GAIN: f64 = 0.01;

/// Choose and fit the maps of what `state` leaves on `train` (`fold_of`: each pose's
/// time-blocked fold, poses in time order). Joints are added one at a time (the joint whose
/// map alone predicts the folds best first) while the cross-validated RMS falls by
/// [`JOINT_MIN_GAIN`]; each step tries every harmonic count and ridge of the grid. `None`
/// when no joint moves, too few poses, or no setting passes the gap and gain rules.
///
/// The stated covariance is the ridge posterior `σ² (AᵀA + λI)⁻¹` plus the delete-one-block
/// jackknife over contiguous time blocks (residuals correlated in time or drifting make the
/// coefficients vary between blocks more than independent noise would; measured on the
/// real UR10 series, the posterior alone was 1.2–5× too small in split halves).
pub fn fit_map(
    state: &State,
    train: &[PoseObs],
    fold_of: &[usize],
    opt: &Options,
) -> Option<MapChoice> {
    tracing::debug!("transmission map: start");
    let joints = mapped_joints(state, train);
    let n = train.len();
    if joints.is_empty() || n < 40 || fold_of.len() != n {
        return None;
    }
    let nj = joints.len();
    let hmax = *MAP_HARMONICS.iter().max()?;
    let ncol = 2 * hmax as usize * nj;
    let r = residuals(state, train);
    // One row block of A per pose (3 rows), computed in parallel.
    let cols: Vec<Vec<Option<Vector3<f64>>>> = train
        .par_iter()
        .map(|o| joint_angle_columns(&state.model, &state.effects, &o.ctx))
        .collect();
    let n_folds = fold_of.iter().max().map_or(1, |m| m + 1);
    // Jackknife blocks: each fold's poses cut into contiguous sub-blocks.
    let mut block_of = vec![0usize; n];
    for f in 0..n_folds {
        let idx: Vec<usize> = (0..n).filter(|&i| fold_of[i] == f).collect();
        for (k, &i) in idx.iter().enumerate() {
            block_of[i] = f * JACKKNIFE_PER_FOLD + k * JACKKNIFE_PER_FOLD / idx.len().max(1);
        }
    }
    let n_blocks = n_folds * JACKKNIFE_PER_FOLD;
    let blocks: Vec<Normal> = (0..n_blocks)
        .into_par_iter()
        .map(|bk| {
            let idx: Vec<usize> = (0..n).filter(|&i| block_of[i] == bk).collect();
            let mut a = Mat::<f64>::zeros(3 * idx.len(), ncol);
            let mut y = Mat::<f64>::zeros(3 * idx.len(), 1);
            for (row, &i) in idx.iter().enumerate() {
                for ax in 0..3 {
                    y[(3 * row + ax, 0)] = r[3 * i + ax];
                }
                for (ji, &j) in joints.iter().enumerate() {
                    let (Some(c), Some(&q)) = (cols[i][j], train[i].ctx.q.get(j)) else {
                        continue;
                    };
                    for h in 0..hmax as usize {
                        let (s, co) = ((h + 1) as f64 * q).sin_cos();
                        for ax in 0..3 {
                            a[(3 * row + ax, col(h, ji, 0, nj))] = c[ax] * co;
                            a[(3 * row + ax, col(h, ji, 1, nj))] = c[ax] * s;
                        }
                    }
                }
            }
            let at = a.transpose();
            let mut c = 0.0;
            for i in 0..y.nrows() {
                c += y[(i, 0)] * y[(i, 0)];
            }
            Normal {
                g: at * &a,
                b: at * &y,
                c,
                n: idx.len(),
            }
        })
        .collect();
    tracing::debug!("transmission map: normal equations of {n} poses, {ncol} columns");
    let mut folds = vec![Normal::zeros(ncol); n_folds];
    let mut all = Normal::zeros(ncol);
    for (bk, nb) in blocks.iter().enumerate() {
        folds[bk / JACKKNIFE_PER_FOLD].add(nb);
        all.add(nb);
    }
    let cv_rms_before = (all.c / n as f64).sqrt();
    // Each fold's complement, formed once for every setting.
    let rests: Vec<(Normal, &Normal)> = folds
        .iter()
        .filter(|f| f.n > 0)
        .map(|f| (all.minus(f), f))
        .collect();
    // The whole grid for the maps of `subset` (indices into `joints`).
    let evaluate = |subset: &[usize]| -> Vec<MapSetting> {
        let settings: Vec<(u32, f64)> = MAP_HARMONICS
            .iter()
            .flat_map(|&h| MAP_RIDGE.iter().map(move |&l| (h, l)))
            .collect();
        settings
            .par_iter()
            .filter_map(|&(h, ridge)| {
                let idx = columns(subset, h, nj);
                let lambda =
                    ridge * idx.iter().map(|&i| all.g[(i, i)]).sum::<f64>() / idx.len() as f64;
                let (mut out, mut inn, mut n_in) = (0.0, 0.0, 0usize);
                for (rest, f) in &rests {
                    let rest = rest.sub(&idx);
                    let x = rest.solve(lambda)?;
                    out += f.sub(&idx).sse(&x);
                    inn += rest.sse(&x);
                    n_in += rest.n;
                }
                Some(MapSetting {
                    joints: subset.iter().map(|&ji| joints[ji] + 1).collect(),
                    harmonics: h,
                    ridge,
                    cv_rms: (out / n as f64).sqrt(),
                    fit_rms: (inn / n_in.max(1) as f64).sqrt(),
                })
            })
            .collect()
    };
    let passes = |s: &MapSetting| {
        s.cv_rms <= (1.0 + opt.correction_max_gap) * s.fit_rms
            || s.cv_rms - s.fit_rms <= OVERFIT_MIN_MM
    };
    let best = |grid: &[MapSetting]| -> Option<MapSetting> {
        grid.iter()
            .filter(|s| passes(s))
            .min_by(|a, b| a.cv_rms.total_cmp(&b.cv_rms))
            .cloned()
    };
    // Each joint's map alone, then the joints added best first while the CV falls.
    let mut grid: Vec<MapSetting> = Vec::new();
    let mut singles: Vec<(usize, f64)> = Vec::new();
    for ji in 0..nj {
        let g = evaluate(&[ji]);
        if let Some(b) = best(&g) {
            singles.push((ji, b.cv_rms));
        }
        grid.extend(g);
    }
    singles.sort_by(|a, b| a.1.total_cmp(&b.1));
    let mut subset: Vec<usize> = Vec::new();
    let mut chosen: Option<MapSetting> = None;
    for &(ji, _) in &singles {
        let mut trial = subset.clone();
        trial.push(ji);
        trial.sort_unstable();
        let g = evaluate(&trial);
        let cand = best(&g);
        grid.extend(g);
        let current = chosen.as_ref().map_or(cv_rms_before, |c| c.cv_rms);
        if let Some(c) = cand.filter(|c| c.cv_rms < (1.0 - JOINT_MIN_GAIN) * current) {
            subset = trial;
            chosen = Some(c);
        }
    }
    tracing::debug!("transmission map: grid of {} settings done", grid.len());
    for g in &grid {
        tracing::trace!(
            "transmission map grid: joints {:?}, {} harmonics, ridge {:e}: CV {:.4} (before {:.4}), in-fold {:.4}",
            g.joints,
            g.harmonics,
            g.ridge,
            g.cv_rms,
            cv_rms_before,
            g.fit_rms
        );
    }
    let chosen = chosen?;
    if chosen.cv_rms >= (1.0 - opt.transmission_map_min_gain) * cv_rms_before {
        return None;
    }
    // The chosen setting on every training pose; its covariance: the ridge posterior plus
    // the delete-one-block jackknife.
    let idx = columns(&subset, chosen.harmonics, nj);
    let k = idx.len();
    let sys = all.sub(&idx);
    let lambda = sys.lambda(chosen.ridge);
    let x = sys.solve(lambda)?;
    let sigma2 = sys.sse(&x) / (3 * n).saturating_sub(k).max(1) as f64;
    let mut m = sys.g.clone();
    for i in 0..k {
        m[(i, i)] += lambda;
    }
    let inv = m.llt(Side::Lower).ok()?.inverse();
    let loo: Vec<Mat<f64>> = blocks
        .par_iter()
        .filter(|b| b.n > 0)
        .filter_map(|b| all.minus(b).sub(&idx).solve(lambda))
        .collect();
    let nb = loo.len().max(1) as f64;
    let mean = Mat::from_fn(k, 1, |i, _| loo.iter().map(|v| v[(i, 0)]).sum::<f64>() / nb);
    let jack = (nb - 1.0) / nb;
    // The ridge's own error about the true map (MSE, not the posterior): its variance
    // σ² M⁻¹ G M⁻¹ and its shrinkage bias λ² τ² M⁻², `M = G + λI`, with the coefficients'
    // prior variance τ² estimated from the data (empirical Bayes, [`prior_variance`]). When
    // λ = σ²/τ² this is the posterior σ² M⁻¹; a ridge the gap rule chose far heavier than the
    // data's own τ² says is biased toward zero, and the bias counts.
    let tau2 = prior_variance(&sys.g, &sys.b, sigma2);
    let ig = &inv * &sys.g;
    let var = (&ig * &inv) * faer::Scale(sigma2);
    let ii = &inv * &inv;
    let cov = Mat::from_fn(k, k, |a, b| {
        let j: f64 = loo
            .iter()
            .map(|v| (v[(a, 0)] - mean[(a, 0)]) * (v[(b, 0)] - mean[(b, 0)]))
            .sum();
        var[(a, b)] + lambda * lambda * tau2 * ii[(a, b)] + jack * j
    });
    tracing::debug!(
        "transmission map: joints {:?}, {} harmonics, ridge {:e}, σ² {sigma2:e}, {} jackknife blocks",
        chosen.joints,
        chosen.harmonics,
        chosen.ridge,
        loo.len()
    );
    let hc = chosen.harmonics as usize;
    let range = JointRange::of(train)?;
    let effects = subset
        .iter()
        .enumerate()
        .map(|(si, &ji)| {
            let j = joints[ji];
            let (lo, hi) = (range.lo[j], range.hi[j]);
            let own = si * 2 * hc..(si + 1) * 2 * hc;
            Effect {
                block: Block::TransmissionMap(TransmissionMap {
                    joint: j + 1,
                    harmonics: chosen.harmonics,
                    lo,
                    hi,
                }),
                coefs: own.clone().map(|i| x[(i, 0)]).collect(),
                std: own.map(|i| cov[(i, i)].max(0.0).sqrt()).collect(),
                tau_std: f64::NAN,
            }
        })
        .collect();
    Some(MapChoice {
        chosen,
        cv_rms_before,
        grid,
        effects,
        cov,
    })
}

/// The coefficients' prior variance τ² that maximises the marginal likelihood of the
/// residual under `r = A x + e`, `x ~ N(0, τ² I)`, `e ~ N(0, σ² I)`, from the normal equations
/// `G = AᵀA`, `b = Aᵀr`: along each eigenvector `v` of `G` (eigenvalue `g`),
/// `z = vᵀb / √g ~ N(0, σ² + τ² g)`. Golden-section search on `ln τ²`; 0 when no prior
/// variance beats none.
fn prior_variance(g: &Mat<f64>, b: &Mat<f64>, sigma2: f64) -> f64 {
    let k = g.nrows();
    if k == 0 || sigma2.is_nan() || sigma2 <= 0.0 {
        return 0.0;
    }
    let gm = nalgebra::DMatrix::from_fn(k, k, |i, j| g[(i, j)]);
    let eig = nalgebra::SymmetricEigen::new(gm);
    let gmax = eig.eigenvalues.max();
    let terms: Vec<(f64, f64)> = (0..k)
        .filter(|&i| eig.eigenvalues[i] > 1e-12 * gmax.max(0.0))
        .map(|i| {
            let gi = eig.eigenvalues[i];
            let vb: f64 = (0..k).map(|r| eig.eigenvectors[(r, i)] * b[(r, 0)]).sum();
            (gi, vb * vb / gi)
        })
        .collect();
    if terms.is_empty() {
        return 0.0;
    }
    let nll = |t2: f64| -> f64 {
        terms
            .iter()
            .map(|(gi, z2)| {
                let v = sigma2 + t2 * gi;
                v.ln() + z2 / v
            })
            .sum()
    };
    // τ² between σ²/g_max · 1e-6 and σ²/g_min · 1e6 (log scale).
    let gmin = terms.iter().map(|t| t.0).fold(f64::INFINITY, f64::min);
    let (mut lo, mut hi) = ((sigma2 / gmax * 1e-6).ln(), (sigma2 / gmin * 1e6).ln());
    let phi = (5f64.sqrt() - 1.0) / 2.0;
    for _ in 0..100 {
        let (a, c) = (hi - phi * (hi - lo), lo + phi * (hi - lo));
        if nll(a.exp()) < nll(c.exp()) {
            hi = c;
        } else {
            lo = a;
        }
    }
    let t2 = ((lo + hi) / 2.0).exp();
    if nll(t2) < nll(0.0) {
        t2
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::effects::apply_effects;
    use crate::diagnose::fit::{fit, rms3};
    use crate::diagnose::{lcg_noise as noise, test_joints};
    use crate::model::KinematicModel;
    use nalgebra::Point3;

    /// A gear error of joint 2 with ten harmonics (3…12, none a library ripple the test
    /// adds) in the world, `None` for a world without one.
    fn world(with_error: bool, seed: u64) -> (KinematicModel, Vec<PoseObs>, Vec<Effect>) {
        let mut model = KinematicModel::preset("denso-vs060").unwrap();
        model.fix_point_redundancies();
        let coefs: Vec<f64> = (1..=12)
            .flat_map(|h| {
                let a = if h >= 3 && with_error {
                    (0.004 / h as f64 * 3.0).to_radians()
                } else {
                    0.0
                };
                [a * (h as f64).cos(), a * (1.3 * h as f64).sin()]
            })
            .collect();
        let truth = vec![Effect {
            block: Block::TransmissionMap(TransmissionMap {
                joint: 2,
                harmonics: 12,
                lo: -3.0,
                hi: 3.0,
            }),
            coefs,
            std: vec![f64::NAN; 24],
            tau_std: f64::NAN,
        }];
        let mut e = noise(seed, 0.01);
        let obs = (0..600u64)
            .map(|k| {
                let f = k as f64;
                let mut o = PoseObs::at(k, 20.0 * f, test_joints(f, 3.0, 1.37), Point3::origin());
                o.p = apply_effects(&model, &truth, &o.ctx) + Vector3::new(e(), e(), e());
                o
            })
            .collect();
        (model, obs, truth)
    }

    fn geometric(model: &KinematicModel, train: &[PoseObs]) -> State {
        let mut st = State {
            prior: None,
            model: model.clone(),
            effects: vec![],
        };
        fit(&mut st, train, 50);
        st
    }

    /// Time-blocked folds of `n` poses.
    fn five_folds(n: usize) -> Vec<usize> {
        (0..n).map(|i| i * 5 / n).collect()
    }

    /// The map recovers a ten-harmonic gear error of joint 2 (shape and size; the geometric
    /// fit takes nothing of harmonics ≥ 3) and predicts poses it was not fitted on to near
    /// the noise; its stated σ covers the difference from the truth.
    #[test]
    fn a_many_harmonic_gear_error_is_mapped() {
        let (model, obs, truth) = world(true, 3);
        let (train, held) = obs.split_at(480);
        let st = geometric(&model, train);
        let before = rms3(&residuals(&st, held));
        let m = fit_map(&st, train, &five_folds(train.len()), &Options::default())
            .expect("a map is kept");
        assert!(m.chosen.harmonics >= 12, "{:?}", m.chosen);
        assert_eq!(
            m.chosen.joints,
            vec![2],
            "only the joint with the error is mapped"
        );
        let mut after_st = st.clone();
        after_st.effects.extend(m.effects.iter().cloned());
        let after = rms3(&residuals(&after_st, held));
        println!("held-out {before:.4} → {after:.4} mm; {:?}", m.chosen);
        assert!(before > 0.025, "the world's error is visible: {before}");
        // Noise: ±0.01 mm uniform per axis = 0.01 mm 3-D RMS.
        assert!(after < 0.02, "{after}");
        // Joint 2's curve against the truth at the training angles.
        let (mut d2, mut t2, mut within) = (0.0, 0.0, 0usize);
        for o in train {
            let q = o.ctx.q[1];
            let t = TransmissionMap::value(&truth[0].coefs, q);
            let (v, s) = m.curve(2, q).unwrap();
            d2 += (v - t).powi(2);
            t2 += t * t;
            within += usize::from((v - t).abs() <= 3.0 * s.max(1e-12));
        }
        assert!(
            d2.sqrt() < 0.1 * t2.sqrt(),
            "{} vs {}",
            d2.sqrt(),
            t2.sqrt()
        );
        assert!(
            within * 10 >= train.len() * 8,
            "{within} of {}",
            train.len()
        );
        // The other joints have no gear error: their maps are consistent with zero (within
        // 3 stated σ at nearly every training angle; the wrist joints' short lever arms make
        // their σ large).
        for e in &m.effects {
            let j = e.block.joint().unwrap();
            if j != 2 {
                let zero = train
                    .iter()
                    .filter(|o| {
                        let (v, s) = m.curve(j, o.ctx.q[j - 1]).unwrap();
                        v.abs() <= 3.0 * s
                    })
                    .count();
                assert!(
                    zero * 10 >= train.len() * 9,
                    "joint {j}: {zero} of {}",
                    train.len()
                );
            }
        }
    }

    /// The empirical-Bayes prior variance recovers the coefficients' spread: 60 coefficients
    /// drawn with τ = 0.3 behind 400 noisy rows (σ = 0.5) give τ² within 25 % of their mean
    /// square; without any signal τ² is (nearly) zero. And the ridge's stated MSE covers its
    /// shrinkage: with a ridge 100× heavier than σ²/τ², the coefficients' errors have a mean
    /// z² below 3 under the MSE, where under the posterior σ²(G + λI)⁻¹ alone it is above 10.
    #[test]
    fn prior_variance_recovers_the_coefficients_spread() {
        let (m, k) = (400, 60);
        let (tau, sigma) = (0.3, 0.5);
        let mut u = noise(11, 0.5);
        let mut gauss = || {
            // Box–Muller on the LCG.
            let u1 = (u() + 0.5).clamp(1e-12, 1.0);
            let u2 = u() + 0.5;
            (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
        };
        let a = Mat::<f64>::from_fn(m, k, |_, _| gauss());
        let x = Mat::<f64>::from_fn(k, 1, |_, _| tau * gauss());
        let e = Mat::<f64>::from_fn(m, 1, |_, _| sigma * gauss());
        let g = a.transpose() * &a;
        // The drawn coefficients' own mean square (what the data can tell).
        let drawn = (0..k).map(|i| x[(i, 0)].powi(2)).sum::<f64>() / k as f64;
        for (signal, want) in [(true, drawn), (false, 0.0)] {
            let y = if signal { &a * &x + &e } else { e.clone() };
            let b = a.transpose() * &y;
            let t2 = prior_variance(&g, &b, sigma * sigma);
            if signal {
                assert!((t2 / want - 1.0).abs() < 0.25, "τ² {t2} vs {want}");
            } else {
                assert!(t2 < 0.1 * tau * tau, "τ² {t2} without signal");
            }
        }
        // A ridge far heavier than the data's σ²/τ².
        let y = &a * &x + &e;
        let b = a.transpose() * &y;
        let lambda = 100.0 * sigma * sigma / (tau * tau);
        let mut mm = g.clone();
        for i in 0..k {
            mm[(i, i)] += lambda;
        }
        let inv = mm.llt(Side::Lower).unwrap().inverse();
        let xr = &inv * &b;
        let t2 = prior_variance(&g, &b, sigma * sigma);
        let mse = (&inv * &g * &inv) * faer::Scale(sigma * sigma)
            + (&inv * &inv) * faer::Scale(lambda * lambda * t2);
        let post = &inv * faer::Scale(sigma * sigma);
        let z = |c: &Mat<f64>| {
            (0..k)
                .map(|i| (xr[(i, 0)] - x[(i, 0)]).powi(2) / c[(i, i)])
                .sum::<f64>()
                / k as f64
        };
        assert!(z(&mse) < 3.0, "mean squared z under the MSE: {}", z(&mse));
        assert!(z(&post) > 10.0, "the posterior alone: {}", z(&post));
    }

    /// Geometric errors and noise only: no setting predicts the folds 5 % better than zero,
    /// so no map (the diagnosis' control worlds stay clean).
    #[test]
    fn noise_alone_gets_no_map() {
        for seed in [1, 2, 3] {
            let (model, obs, _) = world(false, seed);
            let st = geometric(&model, &obs);
            let m = fit_map(&st, &obs, &five_folds(obs.len()), &Options::default());
            assert!(m.is_none(), "seed {seed}: {:?}", m.map(|m| m.chosen));
        }
    }

    /// Too few poses, or a joint that never moves: nothing to map there.
    #[test]
    fn few_poses_or_still_joints_get_no_map() {
        let (model, obs, _) = world(true, 4);
        let st = geometric(&model, &obs[..30]);
        assert!(fit_map(&st, &obs[..30], &five_folds(30), &Options::default()).is_none());
        let mut still = obs.clone();
        for o in still.iter_mut() {
            o.ctx.q[1] = 0.3;
        }
        let st = geometric(&model, &still);
        assert!(!mapped_joints(&st, &still).contains(&1));
    }
}
