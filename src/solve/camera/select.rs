//! Which hand-eye estimate is written (issue 31 §3): every candidate — the closed forms, the
//! joint ML with free intrinsics, the ML with the board-only intrinsics held, and the fit with
//! the robot's pose noise modelled ([`super::posenoise`]) — is scored by internal
//! cross-validation on the training views (5 folds by view: fit on four, predict the fifth's
//! corners from its flange pose), and the lowest predicted-pixel error is written. On simulated
//! cells, where the flange poses are exact, the joint ML wins; on real arms, whose poses are
//! wrong by about a millimetre, the robot-noise fit or a closed form may.
//!
//! The written estimate's 1σ is the larger, per coordinate, of its model covariance and the
//! view jackknife (every view left out once), which holds when the errors of one view's
//! corners are correlated (a wrong flange pose moves them all) and the model covariance, which
//! treats every corner as independent, is far too small.
use nalgebra::Isometry3;

use super::geom::{Intrinsics, N_INTR};
use super::handeye::{self, Method};
use super::problem::BoardModel;
use super::{ml_fit, obs_of, posenoise, predict_residuals, target_from, CameraData, View};

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
        ]);
        v
    }
    pub fn name(&self) -> String {
        match self {
            Candidate::Closed(m) => m.name().to_string(),
            Candidate::Ml => "ml".into(),
            Candidate::MlBoardIntrinsics => "ml (board-only intrinsics)".into(),
            Candidate::PoseNoise => "ml (robot pose noise)".into(),
            Candidate::PoseNoiseFull => "ml (robot pose noise, full covariance)".into(),
            Candidate::MlTrimmed => "ml (board-only intrinsics, outlier poses out)".into(),
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

impl Ctx<'_> {
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
                let sd = |i: usize| f.cov[(i, i)].max(0.0).sqrt();
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

    /// Internal cross-validation RMS (px) of `c`: `folds` folds by view.
    pub fn cv_rms(&self, c: Candidate, folds: usize) -> f64 {
        let n = self.data.views.len();
        let (mut se, mut nc) = (0.0, 0usize);
        for f in 0..folds {
            let test: Vec<usize> = (0..n).filter(|i| i % folds == f).collect();
            let train: Vec<usize> = (0..n).filter(|i| i % folds != f).collect();
            let Some(fit) = self.fit(c, &train) else {
                return f64::INFINITY;
            };
            let (s, k) = self.score(&fit, &test);
            if !s.is_finite() {
                return f64::INFINITY;
            }
            se += s;
            nc += k;
        }
        (se / nc.max(1) as f64).sqrt()
    }

    /// View jackknife 1σ of X (translation mm, rotation deg about `centre`).
    pub fn jackknife(&self, c: Candidate) -> Option<([f64; 3], [f64; 3])> {
        let n = self.data.views.len();
        let xs: Vec<Isometry3<f64>> = (0..n)
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

/// Root mean square deviation (not unbiased) of X about `centre`: translation mm, rotation deg
/// (local, `centre⁻¹ x`).
pub(super) fn spread(xs: &[Isometry3<f64>], centre: &Isometry3<f64>) -> ([f64; 3], [f64; 3]) {
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
