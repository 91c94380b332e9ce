//! Parameter averaging over random subsets (seed 001 §4.3 / §4.5): fit `K` random subsets of
//! `M` training poses (seed: 10 000 × 200 of 551; on site 100 × 75 %), in parallel (rayon),
//! then per parameter: mean, std, 95 % interval and a Jarque–Bera normality check.
//!
//! Each subset fit keeps the free-parameter set of the full fit (the identifiability
//! decision is made once, on all data) and starts from the full-data solution, so a fit is
//! a few Gauss–Newton steps.
//!
//! **Which model is final.** The seed takes the subset mean. For a least-squares problem
//! that is close to linear at the solution (ours: residual ≈ noise, relative parameter
//! changes ≪ 1) the mean of subset estimates converges to the full-data estimate, while the
//! full-data fit uses every pose with its proper weight and is deterministic. We therefore
//! keep the **full-data fit** as the final model and use the bootstrap for uncertainty and
//! as a check: [`BootstrapResult::max_mean_shift_sigma`] reports how far (in bootstrap σ)
//! the subset mean is from the full fit; a large shift means non-linearity or outliers and
//! is reported. The held-out error of the mean model is also computed so the choice can be
//! verified on data.
use std::sync::Arc;
use std::time::Instant;

use nalgebra::DVector;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use super::kinematics::{Effect, IdentResult, KinProblem};
use super::lm::{self, LmOptions};
use super::obs::PoseObs;
use super::stats::Summary;
use super::SolveError;
use crate::model::KinematicModel;

/// Subset size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SubsetSize {
    /// A fixed number of poses.
    Count(usize),
    /// A fraction of the training poses (0 < f ≤ 1).
    Fraction(f64),
}

impl SubsetSize {
    /// Parse `200`, `0.75` or `75%`.
    pub fn parse(s: &str) -> Result<SubsetSize, SolveError> {
        let s = s.trim();
        let bad = || SolveError::Invalid(format!("bad subset size `{s}` (use 200, 0.75 or 75%)"));
        if let Some(p) = s.strip_suffix('%') {
            let v: f64 = p.trim().parse().map_err(|_| bad())?;
            if !(v > 0.0 && v <= 100.0) {
                return Err(bad());
            }
            return Ok(SubsetSize::Fraction(v / 100.0));
        }
        if let Ok(n) = s.parse::<usize>() {
            return if n > 0 {
                Ok(SubsetSize::Count(n))
            } else {
                Err(bad())
            };
        }
        let v: f64 = s.parse().map_err(|_| bad())?;
        if v > 0.0 && v <= 1.0 {
            Ok(SubsetSize::Fraction(v))
        } else {
            Err(bad())
        }
    }
    fn count(&self, n: usize) -> usize {
        match *self {
            SubsetSize::Count(c) => c.min(n),
            SubsetSize::Fraction(f) => ((n as f64 * f).round() as usize).clamp(1, n),
        }
    }
}

/// Bootstrap settings.
#[derive(Debug, Clone)]
pub struct BootstrapOptions {
    pub k: usize,
    pub subset: SubsetSize,
    pub seed: u64,
    pub lm: LmOptions,
}

impl Default for BootstrapOptions {
    fn default() -> Self {
        BootstrapOptions {
            k: 100,
            subset: SubsetSize::Fraction(0.75),
            seed: 1,
            lm: LmOptions {
                max_iter: 30,
                // Warm start at the full-data solution: a relative cost change of 1e-8
                // moves parameters by ≪ 1 % of their bootstrap spread.
                ftol: 1e-8,
                xtol: 1e-9,
                gtol: 1e-9,
                lambda0: 1e-6,
            },
        }
    }
}

/// Per-parameter distribution over the subset fits.
#[derive(Debug, Clone)]
pub struct BootstrapResult {
    /// Names of `x` (free model parameters, then effect parameters).
    pub names: Vec<String>,
    /// Full-data estimate of each entry.
    pub full: Vec<f64>,
    /// One summary per entry (internal units).
    pub summaries: Vec<Summary>,
    /// All samples: `samples[k][i]` = entry `i` of fit `k` (converged fits only).
    pub samples: Vec<Vec<f64>>,
    pub subset_size: usize,
    pub n_requested: usize,
    pub n_failed: usize,
    pub elapsed_s: f64,
    /// Model with the subset means of the free parameters.
    pub mean_model: KinematicModel,
    /// Largest `|mean − full| / std` over the parameters.
    pub max_mean_shift_sigma: f64,
    /// Parameters whose distribution fails the normality check at 1 %.
    pub non_normal: Vec<String>,
}

/// Random subset of `m` distinct indices out of `n` (partial Fisher–Yates).
fn subset(rng: &mut ChaCha8Rng, n: usize, m: usize) -> Vec<usize> {
    use rand::Rng;
    let mut idx: Vec<usize> = (0..n).collect();
    for i in 0..m {
        let j = rng.random_range(i..n);
        idx.swap(i, j);
    }
    idx.truncate(m);
    idx
}

/// Run the bootstrap around a full identification result.
pub fn bootstrap(
    full: &IdentResult,
    effects: &[Arc<dyn Effect>],
    opts: &BootstrapOptions,
) -> Result<BootstrapResult, SolveError> {
    bootstrap_obs(
        &full.model,
        &full.x,
        &full.train_obs,
        effects,
        full.orientation,
        opts,
    )
}

/// Bootstrap on explicit inputs: `model` carries the free set, `x_full` the full-data
/// solution (free values then effect values).
pub fn bootstrap_obs(
    model: &KinematicModel,
    x_full: &DVector<f64>,
    train: &[PoseObs],
    effects: &[Arc<dyn Effect>],
    orientation: Option<f64>,
    opts: &BootstrapOptions,
) -> Result<BootstrapResult, SolveError> {
    let n = train.len();
    let m = opts.subset.count(n);
    let probe = KinProblem::new(model.clone(), train, effects);
    let nx = x_full.len();
    if m * probe.rows_per_obs() <= nx + 1 {
        return Err(SolveError::TooFewData {
            what: "bootstrap subset".into(),
            need: nx / probe.rows_per_obs() + 2,
            got: m,
        });
    }
    if opts.k == 0 {
        return Err(SolveError::Invalid("bootstrap: K must be ≥ 1".into()));
    }
    let t0 = Instant::now();
    let results: Vec<Option<Vec<f64>>> = (0..opts.k)
        .into_par_iter()
        .map(|k| {
            let mut rng =
                ChaCha8Rng::seed_from_u64(opts.seed.wrapping_mul(1_000_003).wrapping_add(k as u64));
            let idx = subset(&mut rng, n, m);
            let sub: Vec<PoseObs> = idx.iter().map(|&i| train[i].clone()).collect();
            let mut p = KinProblem::new(model.clone(), &sub, effects);
            p.orientation = orientation;
            let rep = lm::minimize(&p, x_full.clone(), &opts.lm);
            (rep.termination.converged() && rep.x.iter().all(|v| v.is_finite()))
                .then(|| rep.x.as_slice().to_vec())
        })
        .collect();
    let elapsed_s = t0.elapsed().as_secs_f64();
    let samples: Vec<Vec<f64>> = results.iter().flatten().cloned().collect();
    let n_failed = opts.k - samples.len();
    if samples.is_empty() {
        return Err(SolveError::Solver(
            "bootstrap: no subset fit converged".into(),
        ));
    }
    let names = probe.x_names();
    let summaries: Vec<Summary> = (0..nx)
        .map(|i| Summary::of(&samples.iter().map(|s| s[i]).collect::<Vec<_>>()))
        .collect();
    let means = DVector::from_iterator(nx, summaries.iter().map(|s| s.mean));
    let mean_model = probe.model_at(&means);
    let max_mean_shift_sigma = summaries
        .iter()
        .zip(x_full.iter())
        .map(|(s, f)| {
            if s.std > 0.0 {
                (s.mean - f).abs() / s.std
            } else {
                0.0
            }
        })
        .fold(0.0, f64::max);
    let non_normal = summaries
        .iter()
        .zip(&names)
        .filter(|(s, _)| s.n >= 8 && !s.looks_normal())
        .map(|(_, n)| n.clone())
        .collect();
    Ok(BootstrapResult {
        names,
        full: x_full.iter().cloned().collect(),
        summaries,
        samples,
        subset_size: m,
        n_requested: opts.k,
        n_failed,
        elapsed_s,
        mean_model,
        max_mean_shift_sigma,
        non_normal,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn subset_size_parsing() {
        assert_eq!(SubsetSize::parse("200").unwrap(), SubsetSize::Count(200));
        assert_eq!(
            SubsetSize::parse("75%").unwrap(),
            SubsetSize::Fraction(0.75)
        );
        assert_eq!(SubsetSize::parse("0.5").unwrap(), SubsetSize::Fraction(0.5));
        assert!(SubsetSize::parse("0").is_err());
        assert!(SubsetSize::parse("150%").is_err());
        assert!(SubsetSize::parse("abc").is_err());
        assert_eq!(SubsetSize::Fraction(0.75).count(300), 225);
        assert_eq!(SubsetSize::Count(900).count(300), 300);
    }

    #[test]
    fn subsets_are_distinct_indices() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let s = subset(&mut rng, 50, 20);
        let mut t = s.clone();
        t.sort();
        t.dedup();
        assert_eq!(t.len(), 20);
        assert!(s.iter().all(|&i| i < 50));
    }
}
