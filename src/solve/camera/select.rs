//! Which hand-eye estimate is written: every candidate — the closed forms, the
//! joint ML with free intrinsics, the ML with the board-only intrinsics held, and the fit with
//! the robot's pose noise modelled ([`super::posenoise`], [`super::viewcorr`]) — is scored by
//! internal cross-validation on the training views (5 folds by view: fit on four, predict the
//! fifth's corners from its flange pose), and the lowest predicted-pixel error is written —
//! unless simpler candidates tie with it within the CV's standard error ([`choose`]). On simulated
//! cells, where the flange poses are exact, the joint ML wins; on real arms, whose poses are
//! wrong by about a millimetre, the robot-noise fit or a closed form may.
//!
//! The written estimate's 1σ is the larger, per coordinate, of its model covariance and the
//! view jackknife (every view left out once), which holds when the errors of one view's
//! corners are correlated (a wrong flange pose moves them all) and the model covariance, which
//! treats every corner as independent, is far too small.
use nalgebra::Isometry3;
use rayon::prelude::*;

pub use crate::diagnose::camera::ROBOT_DOMINATES_RATIO;

use super::geom::{Intrinsics, N_INTR};
use super::handeye::{self, Method};
use super::problem::BoardModel;
use super::{
    ml_fit, obs_of, posenoise, predict_residuals, target_from, viewcorr, CameraData, View,
};

/// A candidate estimator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Candidate {
    Closed(Method),
    /// Joint ML: intrinsics, X and target on every corner.
    Ml,
    /// ML with the board-only intrinsics held.
    MlBoardIntrinsics,
    /// X and target with the robot's pose noise estimated ([`super::posenoise`]).
    PoseNoise,
    /// As [`Candidate::PoseNoise`] with the full 6×6 pose-noise covariance
    /// ([`posenoise::fit_full`]).
    PoseNoiseFull,
    /// [`Candidate::MlBoardIntrinsics`] refitted without the views whose reprojection RMS is
    /// beyond 2.5× the median (a flange pose wrong far beyond the arm's usual error).
    MlTrimmed,
    /// X and target with one flange correction per view fitted to the corners under a
    /// pose-noise prior ([`super::viewcorr`]), started from [`Candidate::PoseNoise`].
    ViewCorrections,
    /// As [`Candidate::ViewCorrections`] with the prior held at `10^e` times the pose noise
    /// the data imply ([`posenoise::fit`]) and the pixel noise at the board-only RMS: between
    /// the fit that treats the flange poses as exact and the one that explains every view's
    /// residual by its flange (on a real UR3e the implied noise itself lets the corrections
    /// take what the hand-eye should explain; the exponent is chosen by the CV).
    ViewCorrectionsScaled(i32),
}

impl Candidate {
    pub fn all() -> Vec<Candidate> {
        let mut v: Vec<Candidate> = Method::ALL.iter().map(|m| Candidate::Closed(*m)).collect();
        v.extend([
            Candidate::Ml,
            Candidate::MlBoardIntrinsics,
            Candidate::PoseNoise,
            Candidate::PoseNoiseFull,
            Candidate::MlTrimmed,
            Candidate::ViewCorrections,
            Candidate::ViewCorrectionsScaled(-4),
            Candidate::ViewCorrectionsScaled(-3),
            Candidate::ViewCorrectionsScaled(-2),
        ]);
        v
    }
    /// Preference among candidates the cross-validation cannot tell apart ([`choose`]): the
    /// closed forms first (no noise model, no iteration; Park–Martin, the one OpenCV users
    /// reach for, first), then the ML fits from the fewest modelling choices to the most.
    ///
    /// When the robot's pose error dominates the residual (`robot_dominates`: the best closed
    /// form's training residual is more than [`ROBOT_DOMINATES_RATIO`]× what the board alone
    /// leaves, the diagnosis' threshold; the real KUKA and UR3e sets are at 11–35×), the ML
    /// fits that treat every flange pose as exact are a model the data already contradict: the
    /// fits that model the pose error come before them, the per-view corrections from the
    /// tightest prior (the fewest effective parameters: 10⁻⁴ × the implied noise) to the
    /// implied noise itself. On a real UR3e the exact-pose ML and the corrections with the
    /// 10⁻⁴ prior tie in the CV on the training views and on both halves, but the exact-pose
    /// ML's X moves 2.28 mm between the halves and the corrections' 0.86 mm.
    pub fn preference(&self, robot_dominates: bool) -> usize {
        match (self, robot_dominates) {
            (Candidate::Closed(Method::ParkMartin), _) => 0,
            (Candidate::Closed(Method::TsaiLenz), _) => 1,
            (Candidate::Closed(Method::Horaud), _) => 2,
            (Candidate::Closed(Method::Daniilidis), _) => 3,
            (Candidate::Closed(Method::Andreff), _) => 4,
            (Candidate::MlBoardIntrinsics, false) => 5,
            (Candidate::Ml, false) => 6,
            (Candidate::PoseNoise, false) => 7,
            (Candidate::ViewCorrections, false) => 8,
            (Candidate::ViewCorrectionsScaled(e), false) => 9 + (-e).clamp(0, 9) as usize,
            (Candidate::ViewCorrectionsScaled(e), true) => 5 + (e + 4).clamp(0, 9) as usize,
            (Candidate::ViewCorrections, true) => 15,
            (Candidate::PoseNoise, true) => 16,
            (Candidate::MlBoardIntrinsics, true) => 17,
            (Candidate::Ml, true) => 18,
            (Candidate::PoseNoiseFull, _) => 19,
            (Candidate::MlTrimmed, _) => 20,
        }
    }
    pub fn name(&self) -> String {
        match self {
            Candidate::Closed(m) => m.name().to_string(),
            Candidate::Ml => "ml".into(),
            Candidate::MlBoardIntrinsics => "ml (board-only intrinsics)".into(),
            Candidate::PoseNoise => "ml (robot pose noise)".into(),
            Candidate::PoseNoiseFull => "ml (robot pose noise, full covariance)".into(),
            Candidate::MlTrimmed => "ml (board-only intrinsics, outlier poses out)".into(),
            Candidate::ViewCorrections => "ml (per-view pose corrections)".into(),
            Candidate::ViewCorrectionsScaled(e) => {
                format!("ml (per-view pose corrections, prior 1e{e} x implied)")
            }
        }
    }
}

/// What every candidate fit needs.
pub(super) struct Ctx<'a> {
    pub data: &'a CameraData,
    /// Board-in-camera pose of every view (board-only intrinsics).
    pub t_list: &'a [Isometry3<f64>],
    pub g: &'a [Isometry3<f64>],
    pub k1: Intrinsics,
    pub mask: [bool; N_INTR],
    /// Pixel noise per image coordinate from the board alone (px).
    pub sigma_px: f64,
    /// Start of the iterative fits.
    pub x0: Isometry3<f64>,
    pub b0: Isometry3<f64>,
}

/// One candidate's fit.
#[derive(Debug, Clone)]
pub(super) struct Fit {
    pub k: Intrinsics,
    pub x: Isometry3<f64>,
    pub target: Isometry3<f64>,
    /// Model 1σ of X: translation mm, rotation deg (0 for the closed forms).
    pub sd_mm: [f64; 3],
    pub sd_deg: [f64; 3],
    /// Robot pose noise (deg, mm), for [`Candidate::PoseNoise`].
    pub pose_noise: Option<(f64, f64)>,
}

impl<'a> Ctx<'a> {
    /// The same context with other board-only intrinsics and the board poses under them.
    pub fn with_intrinsics<'b>(&'b self, k1: Intrinsics, t_list: &'b [Isometry3<f64>]) -> Ctx<'b>
    where
        'a: 'b,
    {
        Ctx {
            data: self.data,
            t_list,
            g: self.g,
            k1,
            mask: self.mask,
            sigma_px: self.sigma_px,
            x0: self.x0,
            b0: self.b0,
        }
    }

    fn views(&self, idx: &[usize]) -> Vec<View> {
        idx.iter().map(|&i| self.data.views[i].clone()).collect()
    }

    /// Fit `c` on the views `idx` (repeats allowed: the bootstrap).
    pub fn fit(&self, c: Candidate, idx: &[usize]) -> Option<Fit> {
        let g: Vec<Isometry3<f64>> = idx.iter().map(|&i| self.g[i]).collect();
        let t: Vec<Isometry3<f64>> = idx.iter().map(|&i| self.t_list[i]).collect();
        let plain = |k: Intrinsics, x: Isometry3<f64>, target: Isometry3<f64>| Fit {
            k,
            x,
            target,
            sd_mm: [0.0; 3],
            sd_deg: [0.0; 3],
            pose_noise: None,
        };
        match c {
            Candidate::Closed(m) => {
                let x = handeye::solve(m, &handeye::motion_pairs(&g, &t, 2.0))?;
                Some(plain(self.k1, x, target_from(&g, &x, &t)))
            }
            Candidate::Ml | Candidate::MlBoardIntrinsics => {
                let mask = if c == Candidate::Ml {
                    self.mask
                } else {
                    [false; N_INTR]
                };
                let obs = obs_of(&self.views(idx), &self.data.board);
                let (k, x, target, _, _, rep) = ml_fit(
                    &obs,
                    &g,
                    &self.k1,
                    mask,
                    &self.x0,
                    &self.b0,
                    BoardModel::default(),
                    1.0,
                    [0.0; 2],
                );
                if rep.termination == crate::solve::lm::Termination::NonFinite {
                    return None;
                }
                let u = super::covariance(&rep, &mask, BoardModel::default());
                Some(Fit {
                    sd_mm: u.x_mm,
                    sd_deg: u.x_deg,
                    ..plain(k, x, target)
                })
            }
            Candidate::MlTrimmed => {
                let f = self.fit(Candidate::MlBoardIntrinsics, idx)?;
                let per: Vec<f64> = idx
                    .iter()
                    .map(|&i| {
                        let (s, k) = self.score(&f, &[i]);
                        (s / k.max(1) as f64).sqrt()
                    })
                    .collect();
                let mut sorted = per.clone();
                sorted.sort_by(f64::total_cmp);
                let cut = 2.5 * sorted[sorted.len() / 2];
                let keep: Vec<usize> = idx
                    .iter()
                    .zip(&per)
                    .filter(|(_, r)| **r <= cut)
                    .map(|(i, _)| *i)
                    .collect();
                if keep.len() == idx.len() || keep.len() < 4 {
                    return Some(f);
                }
                self.fit(Candidate::MlBoardIntrinsics, &keep)
            }
            Candidate::PoseNoise | Candidate::PoseNoiseFull => {
                let f = if c == Candidate::PoseNoise {
                    posenoise::fit(&g, &t, &self.x0, &self.b0)?
                } else {
                    posenoise::fit_full(&g, &t, &self.x0, &self.b0)?
                };
                // Rotations about X's and the target's own axes.
                let cov = super::geom::cov_rotations_local(
                    &f.cov,
                    &[
                        (0, f.x.rotation.scaled_axis()),
                        (6, f.target.rotation.scaled_axis()),
                    ],
                );
                let sd = |i: usize| cov[(i, i)].max(0.0).sqrt();
                Some(Fit {
                    sd_mm: [sd(3), sd(4), sd(5)],
                    sd_deg: [sd(0), sd(1), sd(2)].map(f64::to_degrees),
                    pose_noise: Some((f.sigma_deg, f.sigma_mm)),
                    ..plain(self.k1, f.x, f.target)
                })
            }
            Candidate::ViewCorrections | Candidate::ViewCorrectionsScaled(_) => {
                let start = posenoise::fit(&g, &t, &self.x0, &self.b0)?;
                let obs = obs_of(&self.views(idx), &self.data.board);
                let mut views: Vec<viewcorr::ViewObs> = g
                    .iter()
                    .map(|g| viewcorr::ViewObs {
                        flange: *g,
                        pts: vec![],
                    })
                    .collect();
                for o in &obs {
                    views[o.view].pts.push((o.pt, o.uv));
                }
                let f = match c {
                    Candidate::ViewCorrectionsScaled(e) => viewcorr::fit_fixed(
                        &self.k1,
                        &views,
                        &self.x0,
                        &self.b0,
                        &(start.noise_cov * 10f64.powi(e)),
                        self.sigma_px,
                    )?,
                    _ => viewcorr::fit(
                        &self.k1,
                        &views,
                        &start.x,
                        &start.target,
                        (start.sigma_deg.to_radians(), start.sigma_mm),
                        self.sigma_px,
                    )?,
                };
                // Rotations about X's and the target's own axes.
                let cov = super::geom::cov_rotations_local(
                    &f.cov,
                    &[
                        (0, f.x.rotation.scaled_axis()),
                        (6, f.target.rotation.scaled_axis()),
                    ],
                );
                let sd = |i: usize| cov[(i, i)].max(0.0).sqrt();
                Some(Fit {
                    sd_mm: [sd(3), sd(4), sd(5)],
                    sd_deg: [sd(0), sd(1), sd(2)].map(f64::to_degrees),
                    pose_noise: Some((f.sigma_deg, f.sigma_mm)),
                    ..plain(self.k1, f.x, f.target)
                })
            }
        }
    }

    /// Squared pixel errors of the views `idx` predicted by `f` (sum, corner count).
    fn score(&self, f: &Fit, idx: &[usize]) -> (f64, usize) {
        let d = CameraData {
            views: self.views(idx),
            ..self.data.clone()
        };
        let r = predict_residuals(&d, &f.k, &f.x, &f.target, 1.0, [0.0; 2]);
        (r.iter().map(|(_, _, a, b)| a * a + b * b).sum(), r.len())
    }

    /// Internal cross-validation of `c` (`folds` folds by view): every view's squared pixel
    /// error sum and corner count when predicted by the fit on the other folds; `None` when a
    /// fold's fit fails.
    pub fn cv_views(&self, c: Candidate, folds: usize) -> Option<Vec<(f64, usize)>> {
        let n = self.data.views.len();
        let mut out = vec![(0.0, 0usize); n];
        for f in 0..folds {
            let train: Vec<usize> = (0..n).filter(|i| i % folds != f).collect();
            let fit = self.fit(c, &train)?;
            for i in (0..n).filter(|i| i % folds == f) {
                out[i] = self.score(&fit, &[i]);
                if !out[i].0.is_finite() {
                    return None;
                }
            }
        }
        Some(out)
    }

    /// View jackknife 1σ of X (translation mm, rotation deg about `centre`).
    pub fn jackknife(&self, c: Candidate) -> Option<([f64; 3], [f64; 3])> {
        let n = self.data.views.len();
        // One refit per core; collected in view order.
        let xs: Vec<Isometry3<f64>> = (0..n)
            .into_par_iter()
            .filter_map(|i| {
                let idx: Vec<usize> = (0..n).filter(|&j| j != i).collect();
                self.fit(c, &idx).map(|f| f.x)
            })
            .collect();
        if xs.len() + 1 < n || xs.len() < 3 {
            return None;
        }
        let mean = super::geom::mean_pose(&xs);
        let (st, sr) = spread(&xs, &mean);
        // Jackknife variance (n−1)/n · Σ (θ_i − θ̄)² = (n−1) · the mean square deviation.
        let f = (xs.len() as f64 - 1.0).sqrt();
        Some((st.map(|v| v * f), sr.map(|v| v * f)))
    }
}

/// RMS (px) of per-view CV errors ([`Ctx::cv_views`]); infinite when the CV failed.
pub fn cv_of(v: Option<&[(f64, usize)]>) -> f64 {
    let Some(v) = v else {
        return f64::INFINITY;
    };
    let (se, nc) = v.iter().fold((0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    (se / nc.max(1) as f64).sqrt()
}

/// A candidate's CV squared errors and corner counts, one entry per predicted view.
pub type PerView = Vec<(f64, usize)>;

/// The written candidate: the lowest CV error, unless candidates earlier in
/// [`Candidate::preference`] order (`robot_dominates` says which order) are within one
/// standard error of it (the difference of mean square errors, paired by view: the same views
/// predicted by both) — then the first of those. Candidates that tie within the CV's own noise are not told apart by it, and picking
/// among them by that noise makes the written estimate jump between estimators from one
/// subset of views to another (the split-half instability on a real KUKA: Horaud on one half,
/// the pose-noise fit on the other).
pub fn choose(scores: &[(Candidate, Option<PerView>)], robot_dominates: bool) -> Option<Candidate> {
    let (best, bv) = scores
        .iter()
        .filter_map(|(c, v)| v.as_ref().map(|v| (*c, v)))
        .min_by(|a, b| cv_of(Some(a.1)).total_cmp(&cv_of(Some(b.1))))?;
    let n_corners: usize = bv.iter().map(|v| v.1).sum();
    let within = |v: &[(f64, usize)]| {
        if v.len() != bv.len() || v.len() < 3 {
            return false;
        }
        let nv = v.len() as f64;
        let total = n_corners.max(1) as f64;
        let d: Vec<f64> = v.iter().zip(bv).map(|(a, b)| a.0 - b.0).collect();
        let delta = d.iter().sum::<f64>() / total;
        let var = d
            .iter()
            .zip(bv)
            .map(|(di, b)| (di - b.1 as f64 * delta).powi(2))
            .sum::<f64>()
            * nv
            / (nv - 1.0);
        delta <= var.sqrt() / total
    };
    let mut tied: Vec<Candidate> = scores
        .iter()
        .filter_map(|(c, v)| v.as_ref().filter(|v| within(v)).map(|_| *c))
        .collect();
    tied.sort_by_key(|c| c.preference(robot_dominates));
    Some(tied.first().copied().unwrap_or(best))
}

/// The CV errors of `scores` on the views `pick` (repeats allowed), paired by view as
/// [`choose`] pairs them.
pub fn resampled(
    scores: &[(Candidate, Option<PerView>)],
    pick: &[usize],
) -> Vec<(Candidate, Option<PerView>)> {
    scores
        .iter()
        .map(|(c, v)| {
            let v = v.as_ref().and_then(|v| {
                pick.iter()
                    .map(|&i| v.get(i).copied())
                    .collect::<Option<PerView>>()
            });
            (*c, v)
        })
        .collect()
}

/// How often each candidate is the one [`choose`] writes when the views are resampled
/// (`picks`, each a resample of the view indices): the same per-view CV errors, drawn with
/// the views. Candidates never chosen are left out; the shares add to 1 (empty when no
/// resample chooses). Halves of a real KUKA set (RWHE-Calib `kuka_2`, 21 training views) write
/// the joint ML, the ML with the board-only intrinsics or the per-view corrections, whose X
/// are millimetres apart: the written X carries that choice's uncertainty too.
pub fn choice_shares(
    scores: &[(Candidate, Option<PerView>)],
    robot_dominates: bool,
    picks: &[Vec<usize>],
) -> Vec<(Candidate, f64)> {
    let mut won: Vec<(Candidate, usize)> = vec![];
    for pick in picks {
        if let Some(c) = choose(&resampled(scores, pick), robot_dominates) {
            match won.iter_mut().find(|(a, _)| *a == c) {
                Some(w) => w.1 += 1,
                None => won.push((c, 1)),
            }
        }
    }
    let total: usize = won.iter().map(|w| w.1).sum();
    won.into_iter()
        .map(|(c, k)| (c, k as f64 / total as f64))
        .collect()
}

/// Root mean square deviation (not unbiased) of X about `centre`: translation mm, rotation deg
/// (local, `centre⁻¹ x`).
pub(crate) fn spread(xs: &[Isometry3<f64>], centre: &Isometry3<f64>) -> ([f64; 3], [f64; 3]) {
    let (mut st, mut sr) = ([0.0; 3], [0.0; 3]);
    for x in xs {
        let t = x.translation.vector - centre.translation.vector;
        let r = (centre.inverse() * x).rotation.scaled_axis();
        for a in 0..3 {
            st[a] += t[a] * t[a];
            sr[a] += r[a].to_degrees().powi(2);
        }
    }
    let n = xs.len().max(1) as f64;
    (st.map(|v| (v / n).sqrt()), sr.map(|v| (v / n).sqrt()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Per-view CV errors `(squared sum, corners)` with a per-view mean square `ms[v]`.
    fn views(ms: &[f64]) -> Option<Vec<(f64, usize)>> {
        Some(ms.iter().map(|m| (m * 100.0, 100)).collect())
    }

    /// A candidate whose CV error is lower only by the views' own scatter ties with a simpler
    /// one, which is written; a candidate lower by far more than that scatter wins.
    #[test]
    fn ties_within_one_standard_error_go_to_the_simpler_candidate() {
        let park = Candidate::Closed(Method::ParkMartin);
        // Pose noise: 1.5 % lower on average, but the per-view differences scatter ±15 %.
        let base = [4.0, 6.0, 5.0, 7.0, 3.0, 6.5, 5.5, 4.5];
        let noisy: Vec<f64> = base
            .iter()
            .enumerate()
            .map(|(i, b)| b * if i % 2 == 0 { 0.80 } else { 1.12 })
            .collect();
        let scores = vec![
            (park, views(&base)),
            (Candidate::PoseNoise, views(&noisy)),
            (Candidate::Ml, None),
        ];
        assert!(cv_of(scores[1].1.as_deref()) < cv_of(scores[0].1.as_deref()));
        assert_eq!(choose(&scores, false), Some(park));
        assert_eq!(choose(&scores, true), Some(park));
        // 30 % lower on every view: not a tie.
        let better: Vec<f64> = base.iter().map(|b| b * 0.7).collect();
        let scores = vec![(park, views(&base)), (Candidate::Ml, views(&better))];
        assert_eq!(choose(&scores, false), Some(Candidate::Ml));
        // Nothing scored: nothing chosen.
        assert_eq!(choose(&[(park, None)], true), None);
    }

    /// When the robot's pose error dominates, a tie between the exact-pose ML and the per-view
    /// corrections goes to the corrections (the tightest prior first); otherwise to the ML. A
    /// tied closed form still comes first, and a candidate better by far more than the views'
    /// scatter still wins.
    #[test]
    fn robot_noise_fits_come_before_the_exact_pose_ml_when_the_robot_dominates() {
        let base = [4.0, 6.0, 5.0, 7.0, 3.0, 6.5, 5.5, 4.5];
        let jitter = |f: f64| -> Vec<f64> {
            base.iter()
                .enumerate()
                .map(|(i, b)| b * f * if i % 2 == 0 { 0.85 } else { 1.14 })
                .collect()
        };
        let vc = |e| Candidate::ViewCorrectionsScaled(e);
        let scores = vec![
            (Candidate::Closed(Method::ParkMartin), views(&jitter(1.4))),
            (Candidate::MlBoardIntrinsics, views(&base)),
            (vc(-2), views(&jitter(1.0))),
            (vc(-4), views(&jitter(1.01))),
            (Candidate::ViewCorrections, views(&jitter(0.99))),
        ];
        assert_eq!(choose(&scores, false), Some(Candidate::MlBoardIntrinsics));
        assert_eq!(choose(&scores, true), Some(vc(-4)));
        // Park tied as well: still first.
        let mut with_park = scores.clone();
        with_park[0].1 = views(&jitter(1.0));
        let park = Candidate::Closed(Method::ParkMartin);
        assert_eq!(choose(&with_park, true), Some(park));
        // The ML better by 30 % on every view: not a tie, written whatever the order.
        let mut ml_far = scores.clone();
        ml_far[1].1 = views(&base.map(|b| b * 0.7));
        assert_eq!(choose(&ml_far, true), Some(Candidate::MlBoardIntrinsics));
        // Every preference is distinct within each order.
        for rd in [false, true] {
            let mut p: Vec<usize> = Candidate::all().iter().map(|c| c.preference(rd)).collect();
            p.sort();
            p.dedup();
            assert_eq!(p.len(), Candidate::all().len());
        }
    }

    /// Resamples of the views choose a candidate as often as its CV errors, redrawn with the
    /// views, make it the written one: a candidate better by far on every view wins every
    /// resample; one better on some views and worse on others shares them.
    #[test]
    fn choice_shares_follow_the_views_that_favour_each_candidate() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let n = 16;
        let picks: Vec<Vec<usize>> = (0..200)
            .map(|_| (0..n).map(|_| rng.random_range(0..n)).collect())
            .collect();
        let base: Vec<f64> = (0..n).map(|i| 4.0 + (i % 5) as f64).collect();
        let park = Candidate::Closed(Method::ParkMartin);
        // The ML 30 % lower on every view: always written.
        let far: Vec<f64> = base.iter().map(|b| b * 0.7).collect();
        let scores = vec![(park, views(&base)), (Candidate::Ml, views(&far))];
        let s = choice_shares(&scores, false, &picks);
        assert_eq!(s, vec![(Candidate::Ml, 1.0)]);
        // Lower by half on half of the views, higher by a third on the others: on the full set
        // it is 8 % lower, about one standard error; resamples go either way.
        let mixed: Vec<f64> = base
            .iter()
            .enumerate()
            .map(|(i, b)| b * if i % 2 == 0 { 0.5 } else { 1.34 })
            .collect();
        let scores = vec![(park, views(&base)), (Candidate::Ml, views(&mixed))];
        let s = choice_shares(&scores, false, &picks);
        let share = |c: Candidate| s.iter().find(|a| a.0 == c).map_or(0.0, |a| a.1);
        assert!(
            (share(park) + share(Candidate::Ml) - 1.0).abs() < 1e-12,
            "{s:?}"
        );
        assert!(share(park) > 0.2 && share(Candidate::Ml) > 0.2, "{s:?}");
        // Nothing scored: no shares.
        assert!(choice_shares(&[(park, None)], false, &picks).is_empty());
    }
}
