//! Parameter averaging over random subsets (seed 001 §4.3 / §4.5): fit `K` random subsets of
//! `M` training poses (seed: 10 000 × 200 of 551; on site 100 × 75 %), in parallel (rayon),
//! then per parameter: mean, std, 95 % interval and a Jarque–Bera normality check.
//!
//! Each subset fit keeps the free-parameter set of the full fit (the identifiability
//! decision is made once, on all data) and starts from the full-data solution.
//!
//! **Fast path** ([`BootstrapMethod::Fast`], the default, for speed). The 10 000 subsets share
//! one geometry, so the per-pose normal-equation blocks `Aᵢ = JᵢᵀJᵢ`, `bᵢ = Jᵢᵀrᵢ` are computed
//! once at the full-data solution `x̂` and a subset's normal equations are the sum of its
//! poses' blocks (`A_S = Σ Aᵢ`, one Cholesky). Its fit is the Gauss–Newton step
//! `x₁ = x̂ − A_S⁻¹ b_S` followed by chord corrections `δ = −A_S⁻¹ Σ Jᵢᵀ rᵢ(x)` with the
//! *actual* residuals of the subset at the new point (one forward-kinematics pass per
//! correction, no Jacobian). **Exactness check:** a subset is accepted when the last
//! correction is below [`EXACT_TOL_SIGMA`] of its own 1σ uncertainty in every direction
//! (`‖δ‖_{A_S} / σ`, which bounds `|cᵀδ| / sd(cᵀx)` for every linear combination `c`);
//! otherwise (or when `A_S` is not positive definite) the subset falls back to the full
//! Levenberg–Marquardt refit. The chord iteration stops where `Jᵀ(x̂) r(x) = 0` instead of
//! `Jᵀ(x) r(x) = 0`; an **audit** evaluates the exact gradient at every
//! [`AUDIT_EVERY`]-th accepted subset and, if any is further than [`AUDIT_TOL_SIGMA`] from
//! stationary, the whole bootstrap is redone with exact refits
//! ([`BootstrapResult::audit_max_sigma`] reports the largest). [`BootstrapMethod::Exact`]
//! refits every subset with LM (what `tests/solve.rs` compares the fast path against).
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

use nalgebra::{DMatrix, DVector};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use super::kinematics::{Effect, IdentResult, KinProblem};
use super::lm::{self, LmOptions, LsqProblem};
use super::obs::PoseObs;
use super::stats::Summary;
use super::SolveError;
use crate::model::point_fk::{joint_trig, JointTrig};
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

/// How each subset is fitted (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum BootstrapMethod {
    /// Gauss–Newton on reused per-pose normal blocks, checked, LM where the check fails.
    #[default]
    Fast,
    /// A full LM refit of every subset.
    Exact,
}

/// Accept a fast subset fit when its last correction is below this fraction of its 1σ.
pub const EXACT_TOL_SIGMA: f64 = 1e-3;
/// Chord corrections tried before a subset falls back to LM.
pub const MAX_CHORD: usize = 4;
/// Every this-many-th accepted fast fit gets its exact gradient evaluated.
pub const AUDIT_EVERY: usize = 50;
/// Largest exact-gradient step (in 1σ of the subset) the audit tolerates.
pub const AUDIT_TOL_SIGMA: f64 = 0.02;

/// Bootstrap settings.
#[derive(Debug, Clone)]
pub struct BootstrapOptions {
    pub k: usize,
    pub subset: SubsetSize,
    pub seed: u64,
    pub lm: LmOptions,
    pub method: BootstrapMethod,
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
            method: BootstrapMethod::Fast,
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
    /// The method that produced the samples (`Exact` when the fast path's audit failed).
    pub method: BootstrapMethod,
    /// Fast path: subsets whose check failed and that were refitted by LM.
    pub n_fallback: usize,
    /// Fast path: largest exact-gradient step (in the subset's 1σ) over the audited fits.
    pub audit_max_sigma: Option<f64>,
    /// Fast path: forward-kinematics passes (chord corrections) over the accepted subsets.
    pub n_chord_passes: usize,
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
    let subset_of = |k: usize| {
        let mut rng =
            ChaCha8Rng::seed_from_u64(opts.seed.wrapping_mul(1_000_003).wrapping_add(k as u64));
        subset(&mut rng, n, m)
    };
    let exact = |idx: &[usize]| -> Option<Vec<f64>> {
        let sub: Vec<PoseObs> = idx.iter().map(|&i| train[i].clone()).collect();
        let mut p = KinProblem::new(model.clone(), &sub, effects);
        p.orientation = orientation;
        let rep = lm::minimize(&p, x_full.clone(), &opts.lm);
        (rep.termination.converged() && rep.x.iter().all(|v| v.is_finite()))
            .then(|| rep.x.as_slice().to_vec())
    };
    let mut method = opts.method;
    let mut n_fallback = 0;
    let mut audit_max_sigma = None;
    let mut n_chord_passes = 0;
    let mut results: Option<Vec<Option<Vec<f64>>>> = None;
    if method == BootstrapMethod::Fast {
        let mut full_p = KinProblem::new(model.clone(), train, effects);
        full_p.orientation = orientation;
        match NormalBlocks::at(&full_p, x_full) {
            Some(blocks) => {
                type Fit = (Option<Vec<f64>>, bool, Option<f64>, usize);
                let fits: Vec<Fit> = (0..opts.k)
                    .into_par_iter()
                    .map(|k| {
                        let idx = subset_of(k);
                        match blocks.fit(&full_p, x_full, &idx) {
                            Some((x, a, passes)) => {
                                let audit = (k % AUDIT_EVERY == 0)
                                    .then(|| blocks.exact_step_sigma(&full_p, &x, &idx, &a));
                                (Some(x.as_slice().to_vec()), false, audit, passes)
                            }
                            None => (exact(&idx), true, None, 0),
                        }
                    })
                    .collect();
                n_fallback = fits.iter().filter(|f| f.1).count();
                n_chord_passes = fits.iter().map(|f| f.3).sum();
                let worst = fits.iter().filter_map(|f| f.2).fold(0.0, |a: f64, b| {
                    if b.is_nan() {
                        f64::INFINITY
                    } else {
                        a.max(b)
                    }
                });
                audit_max_sigma = Some(worst);
                if worst <= AUDIT_TOL_SIGMA {
                    results = Some(fits.into_iter().map(|f| f.0).collect());
                } else {
                    tracing::warn!(
                        "bootstrap: fast path audit {worst:.3} σ > {AUDIT_TOL_SIGMA} σ: exact refits"
                    );
                    method = BootstrapMethod::Exact;
                }
            }
            None => method = BootstrapMethod::Exact,
        }
    }
    let results = results.unwrap_or_else(|| {
        (0..opts.k)
            .into_par_iter()
            .map(|k| exact(&subset_of(k)))
            .collect()
    });
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
        method,
        n_fallback,
        audit_max_sigma,
        n_chord_passes,
    })
}

/// Per-pose normal-equation blocks at the full-data solution (see the module docs).
struct NormalBlocks {
    nx: usize,
    rpo: usize,
    /// Per pose: the upper triangle of `JᵢᵀJᵢ`, packed column by column (`nx(nx+1)/2`).
    ata: Vec<f64>,
    /// Per pose: `Jᵢᵀrᵢ` (`nx`).
    atr: Vec<f64>,
    /// Per pose: `Jᵢ`, row-major (`rpo × nx`).
    jac: Vec<f64>,
    /// Residual standard deviation of the full fit (per residual row).
    sigma: f64,
    /// Per pose: the sines and cosines of its joints, when the residual is the plain marker
    /// point (no effects, no orientation rows): the check then uses [`PointFk`].
    trig: Option<Vec<JointTrig>>,
}

impl NormalBlocks {
    fn packed_len(nx: usize) -> usize {
        nx * (nx + 1) / 2
    }

    /// `None` when the full-data residuals or Jacobian are not finite or σ is zero.
    fn at(p: &KinProblem, x: &DVector<f64>) -> Option<NormalBlocks> {
        let (r, j) = p.residuals_jacobian(x);
        let (rpo, nx, n) = (p.rows_per_obs(), x.len(), p.obs.len());
        if j.ncols() != nx || j.nrows() != rpo * n || r.len() != rpo * n {
            return None;
        }
        if !r.iter().chain(j.iter()).all(|v| v.is_finite()) {
            return None;
        }
        let dof = r.len().saturating_sub(nx).max(1);
        let sigma = (r.norm_squared() / dof as f64).sqrt();
        if !(sigma > 0.0 && sigma.is_finite()) {
            return None;
        }
        let pl = Self::packed_len(nx);
        let mut ata = vec![0.0; n * pl];
        let mut atr = vec![0.0; n * nx];
        let mut jac = vec![0.0; n * rpo * nx];
        for i in 0..n {
            let rows = rpo * i..rpo * (i + 1);
            for (a, row) in rows.clone().enumerate() {
                for c in 0..nx {
                    jac[(i * rpo + a) * nx + c] = j[(row, c)];
                }
            }
            let blk = &mut ata[i * pl..(i + 1) * pl];
            let mut t = 0;
            for c in 0..nx {
                for r0 in 0..=c {
                    blk[t] = rows.clone().map(|row| j[(row, r0)] * j[(row, c)]).sum();
                    t += 1;
                }
                atr[i * nx + c] = rows.clone().map(|row| j[(row, c)] * r[row]).sum();
            }
        }
        let plain = p.effects.is_empty() && p.orientation.is_none() && p.weights.is_none();
        let dof = p.model.dof();
        let trig = plain.then(|| p.obs.iter().map(|o| joint_trig(&o.q, dof)).collect());
        Some(NormalBlocks {
            nx,
            rpo,
            ata,
            atr,
            jac,
            sigma,
            trig,
        })
    }

    /// `Σ Jᵢᵀ vᵢ` over the subset, `v` holding the subset's residual rows in `idx` order.
    fn jt_times(&self, idx: &[usize], v: &DVector<f64>) -> DVector<f64> {
        let mut g = DVector::zeros(self.nx);
        for (k, &i) in idx.iter().enumerate() {
            for a in 0..self.rpo {
                let rv = v[k * self.rpo + a];
                let row = &self.jac[(i * self.rpo + a) * self.nx..(i * self.rpo + a + 1) * self.nx];
                for (gc, jc) in g.iter_mut().zip(row) {
                    *gc += jc * rv;
                }
            }
        }
        g
    }

    /// The fast fit of subset `idx`: `(x, A_S, chord passes)`, or `None` when it must fall
    /// back to LM.
    fn fit(
        &self,
        p: &KinProblem,
        x_full: &DVector<f64>,
        idx: &[usize],
    ) -> Option<(DVector<f64>, DMatrix<f64>, usize)> {
        let (nx, pl) = (self.nx, Self::packed_len(self.nx));
        let mut acc = vec![0.0; pl];
        let mut b = DVector::zeros(nx);
        for &i in idx {
            for (s, v) in acc.iter_mut().zip(&self.ata[i * pl..(i + 1) * pl]) {
                *s += v;
            }
            for (s, v) in b.iter_mut().zip(&self.atr[i * nx..(i + 1) * nx]) {
                *s += v;
            }
        }
        let mut a = DMatrix::zeros(nx, nx);
        let mut t = 0;
        for c in 0..nx {
            for r0 in 0..=c {
                a[(r0, c)] = acc[t];
                a[(c, r0)] = acc[t];
                t += 1;
            }
        }
        let ch = a.clone().cholesky()?;
        let mut x = x_full - ch.solve(&b);
        for pass in 1..=MAX_CHORD {
            let r = match &self.trig {
                Some(trig) => {
                    let fk = p.model_at(&x).point_fk();
                    let mut r = DVector::zeros(3 * idx.len());
                    for (k, &i) in idx.iter().enumerate() {
                        let e = fk.point(&trig[i]) - p.obs[i].p;
                        r.fixed_rows_mut::<3>(3 * k).copy_from(&e);
                    }
                    r
                }
                None => p.residuals_sel(&x, idx),
            };
            if !r.iter().all(|v| v.is_finite()) {
                return None;
            }
            let g = self.jt_times(idx, &r);
            let d = ch.solve(&g);
            let step_sigma = g.dot(&d).max(0.0).sqrt() / self.sigma;
            x -= d;
            if !x.iter().all(|v| v.is_finite()) {
                return None;
            }
            if step_sigma <= EXACT_TOL_SIGMA {
                return Some((x, a, pass));
            }
        }
        None
    }

    /// The Gauss–Newton step of the exact problem at `x` (its own Jacobian), in the
    /// subset's 1σ: `‖A_S⁻¹ J(x)ᵀ r(x)‖_{A_S} / σ`. NaN when it cannot be evaluated.
    fn exact_step_sigma(
        &self,
        p: &KinProblem,
        x: &DVector<f64>,
        idx: &[usize],
        a: &DMatrix<f64>,
    ) -> f64 {
        let (r, j) = p.residuals_jacobian_sel(x, idx);
        let g = j.tr_mul(&r);
        match a.clone().cholesky() {
            Some(ch) => g.dot(&ch.solve(&g)).max(0.0).sqrt() / self.sigma,
            None => f64::NAN,
        }
    }
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
