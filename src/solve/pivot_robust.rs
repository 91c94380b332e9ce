//! Robust pivot calibration with uncertainty: least-median-of-squares random
//! sampling (RANSAC without a hand-picked threshold) over minimal 3-frame algebraic fits,
//! an inlier threshold from the robust scale of the 3-D tip residuals, re-weighted refits
//! until the inlier set is stable; then both the algebraic and the sphere-fit estimate on
//! the inliers, with 95 % percentile intervals by a moving-block bootstrap over frames
//! (tracker frames at 20–60 Hz are correlated: blocks keep that), and a verdict on which
//! estimate to trust when they disagree beyond their intervals. Lengths mm, angles deg.
use nalgebra::{Isometry3, Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::tool::{pivot_algebraic, pivot_sphere, PivotResult};
use super::{stats, SolveError};

/// Median of the chi distribution with 3 degrees of freedom: the median of `|e|` for an
/// isotropic Gaussian `e` with per-axis σ = 1 (scale of the 3-D residual norms).
const CHI3_MEDIAN: f64 = 1.538_172;
/// 0.99 quantile of chi with 3 dof: the inlier cut in robust σ.
const CHI3_Q99: f64 = 3.368_214;

/// Options of [`pivot_robust`].
#[derive(Debug, Clone)]
pub struct RobustOptions {
    /// Random 3-frame samples scored by the median residual.
    pub samples: usize,
    /// Bootstrap replicates (each method).
    pub bootstrap: usize,
    /// Block length of the moving-block bootstrap (frames; 1 = plain bootstrap; 0 = auto,
    /// `⌈n^(1/3)⌉`).
    pub block: usize,
    /// Fixed inlier threshold (mm) instead of the robust-scale cut.
    pub threshold_mm: Option<f64>,
    /// Seed of the sampling and the bootstrap (results are reproducible).
    pub seed: u64,
}

impl Default for RobustOptions {
    fn default() -> Self {
        RobustOptions {
            samples: 500,
            bootstrap: 500,
            block: 0,
            threshold_mm: None,
            seed: 30,
        }
    }
}

/// 95 % percentile interval per axis: `[lo, hi]` of x, y, z.
pub type Interval3 = [[f64; 2]; 3];

/// One method's estimate on the inliers with its bootstrap intervals.
#[derive(Debug, Clone)]
pub struct MethodEstimate {
    pub fit: PivotResult,
    /// Per-axis RMS of the residual components (`√(Σ|e_i|² / 3n)`): the convention of
    /// scikit-surgerycalibration's `residual_error`.
    pub rms_axis_mm: f64,
    pub tip_ci: Interval3,
    pub pivot_ci: Interval3,
    /// Blocked 5-fold cross-validation: RMS of the held-out frames' 3-D tip residual with
    /// tip and pivot fitted on the other folds (mm).
    pub cv_rms_mm: f64,
}

/// Result of [`pivot_robust`].
#[derive(Debug, Clone)]
pub struct RobustPivot {
    /// Algebraic fit on every frame (the non-robust reference).
    pub all_frames: PivotResult,
    pub all_rms_axis_mm: f64,
    /// Frames kept (`true`) in input order.
    pub inlier: Vec<bool>,
    /// Inlier cut on the 3-D tip residual (mm) and the robust σ per axis it came from.
    pub threshold_mm: f64,
    pub sigma_mm: f64,
    pub algebraic: MethodEstimate,
    pub sphere: MethodEstimate,
    /// Tip difference sphere − algebraic (mm).
    pub tip_difference_mm: f64,
    /// Whether the two tips differ beyond their combined 95 % intervals on some axis.
    pub disagree: bool,
    /// `algebraic` or `sphere`, and why, in a sentence.
    pub trust: &'static str,
    pub reason: String,
    /// Angular spread of the inlier frames: the largest angle (deg) between the probe
    /// axis (marker → tip) of a frame and the mean axis.
    pub spread_deg: f64,
    /// Block length used by the bootstrap.
    pub block: usize,
}

impl RobustPivot {
    /// Frames dropped as outliers.
    pub fn dropped(&self) -> usize {
        self.inlier.iter().filter(|k| !**k).count()
    }
}

fn residuals(frames: &[Isometry3<f64>], tip: &Vector3<f64>, piv: &Point3<f64>) -> Vec<f64> {
    frames
        .iter()
        .map(|f| (f * Point3::from(*tip) - piv).norm())
        .collect()
}

/// Per-axis RMS (`√(Σ|e|²/3n)`) from 3-D residual norms.
pub fn rms_axis(res3d: &[f64]) -> f64 {
    stats::rms(res3d) / 3f64.sqrt()
}

fn median(x: &[f64]) -> f64 {
    stats::quantile(x, 0.5)
}

fn pick(frames: &[Isometry3<f64>], keep: &[bool]) -> Vec<Isometry3<f64>> {
    frames
        .iter()
        .zip(keep)
        .filter(|(_, k)| **k)
        .map(|(f, _)| *f)
        .collect()
}

/// Largest angle (deg) between a frame's probe axis (the tip direction in the tracker) and
/// the mean axis: how far the operator tilted the probe.
pub fn angular_spread_deg(frames: &[Isometry3<f64>], tip: &Vector3<f64>) -> f64 {
    let Some(u) = tip.try_normalize(1e-9) else {
        return 0.0;
    };
    let axes: Vec<Vector3<f64>> = frames.iter().map(|f| f.rotation * u).collect();
    let Some(mean) = axes
        .iter()
        .fold(Vector3::zeros(), |s, a| s + a)
        .try_normalize(1e-12)
    else {
        return 0.0;
    };
    axes.iter()
        .map(|a| a.dot(&mean).clamp(-1.0, 1.0).acos().to_degrees())
        .fold(0.0, f64::max)
}

/// Moving-block bootstrap indices: `n` indices from random blocks of `block` consecutive
/// frames (circular).
fn block_sample(rng: &mut ChaCha8Rng, n: usize, block: usize) -> Vec<usize> {
    let mut idx = Vec::with_capacity(n + block);
    while idx.len() < n {
        let s = rng.random_range(0..n);
        idx.extend((0..block).map(|k| (s + k) % n));
    }
    idx.truncate(n);
    idx
}

fn interval(v: &[f64]) -> [f64; 2] {
    [stats::quantile(v, 0.025), stats::quantile(v, 0.975)]
}

fn bootstrap(
    frames: &[Isometry3<f64>],
    fit: fn(&[Isometry3<f64>]) -> Result<PivotResult, SolveError>,
    reps: usize,
    block: usize,
    seed: u64,
) -> (Interval3, Interval3) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut tips: [Vec<f64>; 3] = Default::default();
    let mut pivs: [Vec<f64>; 3] = Default::default();
    let mut sample = Vec::with_capacity(frames.len());
    for _ in 0..reps {
        sample.clear();
        sample.extend(
            block_sample(&mut rng, frames.len(), block)
                .into_iter()
                .map(|i| frames[i]),
        );
        if let Ok(r) = fit(&sample) {
            for a in 0..3 {
                tips[a].push(r.tip_in_marker[a]);
                pivs[a].push(r.pivot_point[a]);
            }
        }
    }
    let ci = |v: &[Vec<f64>; 3]| [interval(&v[0]), interval(&v[1]), interval(&v[2])];
    (ci(&tips), ci(&pivs))
}

fn estimate(
    frames: &[Isometry3<f64>],
    fit: fn(&[Isometry3<f64>]) -> Result<PivotResult, SolveError>,
    opt: &RobustOptions,
    block: usize,
) -> Result<MethodEstimate, SolveError> {
    let r = fit(frames)?;
    let res = residuals(frames, &r.tip_in_marker, &r.pivot_point);
    let (tip_ci, pivot_ci) = bootstrap(frames, fit, opt.bootstrap, block, opt.seed ^ 0x5eed);
    Ok(MethodEstimate {
        fit: r,
        rms_axis_mm: rms_axis(&res),
        tip_ci,
        pivot_ci,
        cv_rms_mm: cross_validated(frames, fit, 5),
    })
}

/// Blocked `k`-fold cross-validation (contiguous folds in time, so neighbouring frames do
/// not leak): RMS of the held-out 3-D tip residuals (mm); NaN when a fold cannot be fitted.
fn cross_validated(
    frames: &[Isometry3<f64>],
    fit: fn(&[Isometry3<f64>]) -> Result<PivotResult, SolveError>,
    k: usize,
) -> f64 {
    let n = frames.len();
    let mut held = Vec::with_capacity(n);
    for f in 0..k {
        let (lo, hi) = (f * n / k, (f + 1) * n / k);
        let train: Vec<Isometry3<f64>> =
            frames[..lo].iter().chain(&frames[hi..]).copied().collect();
        let Ok(r) = fit(&train) else {
            return f64::NAN;
        };
        held.extend(residuals(&frames[lo..hi], &r.tip_in_marker, &r.pivot_point));
    }
    stats::rms(&held)
}

fn half_width(ci: &Interval3) -> Vector3<f64> {
    Vector3::new(
        0.5 * (ci[0][1] - ci[0][0]),
        0.5 * (ci[1][1] - ci[1][0]),
        0.5 * (ci[2][1] - ci[2][0]),
    )
}

/// Robust pivot calibration: see the module docs. Needs at least 6 frames with rotation
/// about two axes; fails (never panics) on degenerate or non-finite input.
pub fn pivot_robust(
    frames: &[Isometry3<f64>],
    opt: &RobustOptions,
) -> Result<RobustPivot, SolveError> {
    if frames.len() < 6 {
        return Err(SolveError::TooFewData {
            what: "robust pivot calibration".into(),
            need: 6,
            got: frames.len(),
        });
    }
    if let Some(t) = opt.threshold_mm {
        if !(t.is_finite() && t > 0.0) {
            return Err(SolveError::Invalid(format!(
                "pivot inlier threshold must be a positive number of mm, got {t}"
            )));
        }
    }
    let all = pivot_algebraic(frames)?;
    let all_res = residuals(frames, &all.tip_in_marker, &all.pivot_point);
    // Least median of squares over minimal samples (3 frames: 9 equations, 6 unknowns).
    let mut rng = ChaCha8Rng::seed_from_u64(opt.seed);
    let n = frames.len();
    let mut best = (median(&all_res), all.tip_in_marker, all.pivot_point);
    for _ in 0..opt.samples {
        let idx: [usize; 3] = std::array::from_fn(|_| rng.random_range(0..n));
        if idx[0] == idx[1] || idx[1] == idx[2] || idx[0] == idx[2] {
            continue;
        }
        let s: Vec<Isometry3<f64>> = idx.iter().map(|&i| frames[i]).collect();
        let Ok(r) = pivot_algebraic(&s) else { continue };
        let m = median(&residuals(frames, &r.tip_in_marker, &r.pivot_point));
        if m.is_finite() && m < best.0 {
            best = (m, r.tip_in_marker, r.pivot_point);
        }
    }
    // Re-weighted refits: cut at the 99 % chi-3 point of the robust σ, refit on the
    // inliers, re-estimate σ from the inliers' median, until the set is stable.
    let (mut tip, mut piv) = (best.1, best.2);
    let mut keep = vec![true; n];
    let mut sigma = f64::NAN;
    let mut cut = f64::NAN;
    for _ in 0..20 {
        let res = residuals(frames, &tip, &piv);
        sigma = median(&res) / CHI3_MEDIAN;
        cut = opt.threshold_mm.unwrap_or(CHI3_Q99 * sigma);
        let next: Vec<bool> = res.iter().map(|r| *r <= cut).collect();
        let kept = next.iter().filter(|k| **k).count();
        if kept < 6 {
            return Err(SolveError::Degenerate(format!(
                "robust pivot: only {kept} of {n} frames within {cut:.3} mm of a common pivot \
                 (two tools mixed, or a divot that moved?)"
            )));
        }
        let stable = next == keep;
        keep = next;
        let r = pivot_algebraic(&pick(frames, &keep))?;
        tip = r.tip_in_marker;
        piv = r.pivot_point;
        if stable {
            break;
        }
    }
    let inl = pick(frames, &keep);
    let block = if opt.block == 0 {
        (inl.len() as f64).cbrt().ceil() as usize
    } else {
        opt.block
    }
    .clamp(1, inl.len());
    let algebraic = estimate(&inl, pivot_algebraic, opt, block)?;
    let sphere = estimate(&inl, pivot_sphere, opt, block)?;
    let d = sphere.fit.tip_in_marker - algebraic.fit.tip_in_marker;
    let (ha, hs) = (half_width(&algebraic.tip_ci), half_width(&sphere.tip_ci));
    let disagree = (0..3).any(|a| d[a].abs() > (ha[a] * ha[a] + hs[a] * hs[a]).sqrt());
    let spread = angular_spread_deg(&inl, &algebraic.fit.tip_in_marker);
    let (a_cv, s_cv) = (algebraic.cv_rms_mm, sphere.cv_rms_mm);
    // Beyond their intervals the two differ by bias, not noise: the narrower interval does
    // not say which is right. What the pivot physically requires is that the tip stays put:
    // the estimate whose tip stays stiller on frames it was not fitted to wins. Within their
    // intervals either will do; take the more precise one.
    let alg_wins = if disagree {
        // A NaN score (a fold that could not be fitted) never wins.
        s_cv.partial_cmp(&a_cv) != Some(std::cmp::Ordering::Less)
    } else {
        ha.norm() <= hs.norm()
    };
    let why_alg = "the algebraic fit uses every frame's orientation as well as its position \
                   (3 equations per frame); the sphere fit sees only the marker origins' \
                   distance to the centre (1 per frame), on a cap where centre and radius trade \
                   off along the probe axis";
    let reason = if disagree {
        format!(
            "they differ by {:.2} mm, beyond both 95 % intervals (a bias, not noise), so the \
             tie is broken by what a pivot requires, a tip that stays put: on frames held out \
             of the fit (5 blocked folds) the {} tip scatters {:.3} mm RMS, the {} tip {:.3} mm; \
             {}",
            d.norm(),
            if alg_wins { "algebraic" } else { "sphere" },
            if alg_wins { a_cv } else { s_cv },
            if alg_wins { "sphere" } else { "algebraic" },
            if alg_wins { s_cv } else { a_cv },
            if alg_wins {
                why_alg.to_string()
            } else {
                format!("the orientations are noisier than the positions here (probe tilt up to {spread:.1}°)")
            }
        )
    } else {
        format!(
            "they agree within their 95 % intervals ({:.2} mm apart); the {} one is the more \
             precise (interval {:.2} mm against {:.2} mm)",
            d.norm(),
            if alg_wins { "algebraic" } else { "sphere-fit" },
            2.0 * ha.norm().min(hs.norm()),
            2.0 * ha.norm().max(hs.norm())
        )
    };
    let trust = if alg_wins { "algebraic" } else { "sphere" };
    Ok(RobustPivot {
        all_rms_axis_mm: rms_axis(&all_res),
        all_frames: all,
        inlier: keep,
        threshold_mm: cut,
        sigma_mm: sigma,
        tip_difference_mm: d.norm(),
        disagree,
        trust,
        reason,
        spread_deg: spread,
        block,
        algebraic,
        sphere,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand_distr::{Distribution, Normal};

    /// `n` frames pivoting about `piv` with tip `tip`, ±`tilt` rad about x and y, position
    /// noise `noise` mm per axis; every `every`-th frame (if > 0) displaced by 15–40 mm.
    fn frames(n: usize, tilt: f64, noise: f64, every: usize, seed: u64) -> Vec<Isometry3<f64>> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let tip = Vector3::new(-14.0, 395.0, -7.0);
        let piv = Point3::new(-805.0, -85.0, -2112.0);
        let nz = Normal::new(0.0, noise).unwrap();
        (0..n)
            .map(|i| {
                let t = i as f64 / n as f64 * std::f64::consts::TAU * 3.0;
                let r = nalgebra::UnitQuaternion::from_scaled_axis(Vector3::new(
                    tilt * t.sin(),
                    0.3 * t.cos() * tilt / 0.5,
                    rng.random_range(-0.5..0.5),
                ));
                let mut p = piv.coords - r * tip;
                p += Vector3::new(
                    nz.sample(&mut rng),
                    nz.sample(&mut rng),
                    nz.sample(&mut rng),
                );
                if every > 0 && i % every == 3 {
                    let dir = Vector3::new(
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                    )
                    .normalize();
                    p += dir * rng.random_range(15.0..40.0);
                }
                Isometry3::from_parts(nalgebra::Translation3::from(p), r)
            })
            .collect()
    }

    #[test]
    fn outliers_are_dropped_and_the_tip_is_recovered_within_its_interval() {
        let f = frames(600, 0.5, 0.25, 10, 7);
        let opt = RobustOptions {
            bootstrap: 200,
            ..Default::default()
        };
        let r = pivot_robust(&f, &opt).unwrap();
        let tip = Vector3::new(-14.0, 395.0, -7.0);
        // 60 displaced frames; the cut may also take a few genuine tail frames.
        assert!(r.dropped() >= 60 && r.dropped() <= 75, "{}", r.dropped());
        for (i, k) in r.inlier.iter().enumerate() {
            if i % 10 == 3 {
                assert!(!k, "displaced frame {i} kept");
            }
        }
        let e = r.algebraic.fit.tip_in_marker - tip;
        assert!(e.norm() < 0.5, "robust tip error {e}");
        // The plain fit on every frame is pulled off by the outliers.
        assert!((r.all_frames.tip_in_marker - tip).norm() > e.norm());
        for a in 0..3 {
            let ci = r.algebraic.tip_ci[a];
            assert!(ci[0] <= tip[a] && tip[a] <= ci[1], "axis {a}: {ci:?}");
        }
        // σ per axis from the robust scale ≈ the simulated 0.25 mm.
        assert!((r.sigma_mm - 0.25).abs() < 0.05, "{}", r.sigma_mm);
        assert!(r.algebraic.rms_axis_mm < r.all_rms_axis_mm);
    }

    #[test]
    fn clean_data_keeps_nearly_everything_and_methods_agree() {
        let f = frames(300, 0.6, 0.1, 0, 8);
        let r = pivot_robust(
            &f,
            &RobustOptions {
                bootstrap: 100,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(r.dropped() <= 6, "{}", r.dropped());
        assert!(r.tip_difference_mm < 1.0, "{}", r.tip_difference_mm);
        assert!(
            r.spread_deg > 20.0 && r.spread_deg < 60.0,
            "{}",
            r.spread_deg
        );
    }

    #[test]
    fn degenerate_and_bad_options_fail_cleanly() {
        let f = vec![Isometry3::translation(1.0, 2.0, 3.0); 20];
        assert!(pivot_robust(&f, &RobustOptions::default()).is_err());
        let g = frames(50, 0.5, 0.1, 0, 9);
        let bad = RobustOptions {
            threshold_mm: Some(f64::NAN),
            ..Default::default()
        };
        assert!(matches!(
            pivot_robust(&g, &bad),
            Err(SolveError::Invalid(_))
        ));
        assert!(pivot_robust(&g[..4], &RobustOptions::default()).is_err());
    }
}
