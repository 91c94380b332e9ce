//! Residual diagnosis: find the residual a geometric calibration leaves, trace it to a
//! physical effect the model lacks, add that effect, refit, and report the held-out error
//! before and after (`robocal diagnose`).
//!
//! Method (`docs/effects.md` §5.2 / §7): after the geometric fit, every
//! candidate effect of the library ([`effects::Block`], through the [`effects::EffectModel`]
//! trait) gives a block `G` of columns: its columns of the Jacobian of the very problem the
//! refit solves ([`fit::DiagnoseProblem`], candidate appended at zero coefficients). Each
//! block is orthogonalised against the current model Jacobian `J` (`G̃ = (I − P_J) G`) and
//! scored by the nested-model F test, ΔBIC and the
//! time-blocked cross-validated RMS gain; a block that the model absorbs (small
//! [`stats::independence`]) is "not identifiable", never an effect. The best significant
//! block (Bonferroni over the number of tests) is added, all parameters are refitted
//! jointly, and the loop repeats until nothing significant remains. Only then, if a kernel
//! regression of the residual on joint space still predicts held-out folds clearly better
//! than zero, a `nonparametric` correction is added and the report says that no physical
//! effect of the library explained that part.
//!
//! Units inside: mm, rad, s. Files: mm, degrees, seconds.
use crate::schema::{self, fin};
use nalgebra::{DMatrix, DVector, Vector3};

pub mod camera;
pub mod camera_stage;
pub mod changepoint;
pub mod colcache;
pub mod determined;
pub mod effects;
pub mod error;
pub mod extrapolation;
pub mod fit;
pub mod foldchol;
pub mod heap;
pub mod inner_cv;
pub mod nonparam;
pub mod plot;
pub mod pooled;
pub mod region;
pub mod stage;
pub mod transfer;
pub mod transmap;
pub use crate::solve::inference as stats;

/// Six joint angles (rad) of synthetic test pose `f` (`amp · sin((f + 1)(i + phase))` for joint
/// `i`): the unit tests' spread of poses.
#[cfg(test)]
pub(crate) fn test_joints(f: f64, amp: f64, phase: f64) -> Vec<f64> {
    (0..6)
        .map(|i| amp * ((f + 1.0) * (i as f64 + phase)).sin())
        .collect()
}

/// Uniform noise in ±`amp` from a 64-bit LCG seeded with `seed` (reproducible test data).
#[cfg(test)]
pub(crate) fn lcg_noise(mut seed: u64, amp: f64) -> impl FnMut() -> f64 {
    move || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        amp * (((seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0)
    }
}

/// Approach directions of synthetic test pose `k`: ±1 alternating over the joints and poses.
#[cfg(test)]
pub(crate) fn test_approach(k: u64) -> Vec<f64> {
    (0..6)
        .map(|i| {
            if (k as usize + i).is_multiple_of(2) {
                1.0
            } else {
                -1.0
            }
        })
        .collect()
}

/// `n` synthetic poses of `model` ([`test_joints`], 300 s apart) with every context the
/// candidates read (approach directions alternating per joint, a temperature ramp, joint
/// velocities): the unit tests' observations of the candidate columns.
#[cfg(test)]
pub(crate) fn test_obs(model: &KinematicModel, n: u64) -> Vec<PoseObs> {
    (0..n)
        .map(|k| {
            let f = k as f64;
            let q = test_joints(f, 0.7, 1.3);
            let mut o = PoseObs::at(k, 300.0 * f, q.clone(), model.measured_point(&q));
            o.ctx.approach = test_approach(k);
            o.ctx.temp_c = Some(20.0 + 0.3 * f);
            o.ctx.qd = Some(vec![0.05; 6]);
            o
        })
        .collect()
}

use crate::solve::obs::PoseObs;
use effects::{Block, Driver, Effect, EffectModel};
use fit::{fit, fit_nominal, residuals, rms3, stack, State};
use stats::{f_sf, independence, orth_basis, project_out, project_out_t, CvBase};

use crate::model::KinematicModel;

/// Tuning of the selection (defaults are the documented ones).
#[derive(Debug, Clone)]
pub struct Options {
    /// Family-wise false-positive level of one selection round (Bonferroni-divided by the
    /// number of tests).
    pub alpha: f64,
    /// Minimum ΔBIC of an accepted effect (10 = "strong").
    pub min_delta_bic: f64,
    /// Minimum relative gain of the time-blocked cross-validated RMS.
    pub min_cv_gain: f64,
    /// Minimum independence of a block from the current model (0..1).
    pub min_independence: f64,
    /// At most this many physical effects.
    pub max_effects: usize,
    /// Number of contiguous time blocks for cross-validation.
    pub n_folds: usize,
    /// Minimum relative CV gain of the nonparametric correction.
    pub nonparam_min_gain: f64,
    /// Whether a nonparametric correction may be added.
    pub allow_nonparametric: bool,
    /// When a kernel regression on joint space explains more than `np_benchmark_gain` of
    /// the residual variance (cross-validated), a physical candidate must explain at least
    /// this fraction of what the kernel regression explains (effects.md §5.5: a physics
    /// block that does not reach the black box's held-out error has not explained the data).
    pub min_np_ratio: f64,
    /// See `min_np_ratio`.
    pub np_benchmark_gain: f64,
    /// Harmonic-drive gear ratio assumed for the `wave_generator` candidates (the wave
    /// generator turns this many times per output turn; 0 = no such candidates). The
    /// default 101 is an assumption (a common harmonic-drive ratio, e.g. in UR arms), not
    /// read from the data: set the arm's ratio when it is known.
    pub wave_gear_ratio: f64,
    /// Effect kinds left out of the candidate library (e.g. to test the fallback on an
    /// effect the library does not contain).
    pub exclude_kinds: Vec<String>,
    /// Harmonics `k` of the `transmission_ripple` candidates `a sin kq + b cos kq` (one
    /// group per joint; every harmonic counts as a test; after one is accepted the other
    /// harmonics of that joint stay candidates, so a joint can carry several).
    pub ripple_harmonics: Vec<u32>,
    /// How the chain of effects is chosen (see [`Policy`]).
    pub policy: Policy,
    /// Under [`Policy::Best`]: at most this many physical effects in the physics-first chain.
    pub physics_first_max_effects: usize,
    /// The physics-first chain (under [`Policy::Best`], or the single chain of a policy
    /// without the kernel-benchmark rule) also stops when the next effect no longer lowers
    /// the time-blocked CV error of the training poses by more than its standard error
    /// ([`inner_cv`]); `None`: only the cap stops it.
    pub physics_first_stop: Option<inner_cv::CvStop>,
    /// Under [`Policy::Best`]: the physics-first chain is kept only when its time-blocked CV
    /// RMS is at least this fraction below the kernel-benchmark chain's.
    pub policy_margin: f64,
    /// The nonparametric correction's length scale and ridge are the best cross-validated
    /// ones whose CV RMS exceeds their own in-fold training RMS by at most this fraction
    /// (or by at most [`OVERFIT_MIN_MM`]): a correction that fits its training poses far
    /// better than unseen ones has learned the poses ([`OVERFIT_GAP`] is what the report
    /// flags).
    pub correction_max_gap: f64,
    /// A physical effect is left out when, refitted, the largest displacement it predicts at
    /// poses inside the training poses' joint ranges exceeds this many times the largest it
    /// predicts at a training pose ([`extrapolation::ratio`]): its coefficients cancel on
    /// the training poses and not elsewhere. Infinite = no such check.
    pub max_extrapolation: f64,
    /// Whether the transmission error maps may be added after the chain ([`transmap`]).
    pub transmission_map: bool,
    /// Minimum relative CV gain of the transmission error maps over the chain's residual.
    pub transmission_map_min_gain: f64,
    /// Standard deviations of the prior that holds the geometric parameters near their
    /// nominal values in every fit ([`determined`]; the parameters the training poses
    /// determine worse than this are named); `None` fits every free parameter without one.
    pub geometric_tolerance: Option<determined::GeometricTolerance>,
}

/// How [`diagnose`] chooses its chain of effects.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Policy {
    /// One chain under the options' rules.
    Single,
    /// Two chains from the same geometric fit, both selected on training data only: the
    /// kernel-benchmark chain (the options' rules: a physical effect must explain
    /// `min_np_ratio` of what a kernel regression explains) and the physics-first chain (no
    /// such rule, up to `physics_first_max_effects` effects), each followed by its
    /// correction. The physics-first chain is kept when its final model predicts
    /// time-blocked folds of the training data better by `policy_margin`; otherwise the
    /// kernel-benchmark chain. (Real arms: transmission ripple that a kernel on joint space
    /// cannot represent extrapolates; an effect outside the library that a library effect
    /// only resembles is predicted as well by the correction alone.)
    Best,
}

impl Options {
    /// Physics first (`robocal diagnose --physics-first`): the same tests (F, ΔBIC,
    /// time-blocked CV gain, independence) without the rule that a physical effect must
    /// explain half of what the kernel benchmark explains; up to 6 effects, then the
    /// correction for what remains.
    pub fn physics_first() -> Options {
        Options {
            min_np_ratio: 0.0,
            max_effects: 6,
            policy: Policy::Single,
            ..Options::default()
        }
    }

    /// The kernel-benchmark chain alone (the former default policy; `robocal
    /// diagnose --kernel-benchmark`): a physical effect must explain half of what a kernel
    /// regression on joint space explains.
    pub fn kernel_benchmark() -> Options {
        Options {
            policy: Policy::Single,
            ..Options::default()
        }
    }
}

impl Default for Options {
    fn default() -> Self {
        Options {
            alpha: 0.01,
            min_delta_bic: 10.0,
            min_cv_gain: 0.01,
            min_independence: 0.1,
            max_effects: 4,
            n_folds: 5,
            nonparam_min_gain: 0.10,
            allow_nonparametric: true,
            min_np_ratio: 0.5,
            np_benchmark_gain: 0.2,
            wave_gear_ratio: DEFAULT_WAVE_GEAR_RATIO,
            exclude_kinds: Vec::new(),
            ripple_harmonics: RIPPLE_HARMONICS.collect(),
            policy: Policy::Best,
            physics_first_max_effects: 6,
            physics_first_stop: None,
            policy_margin: 0.05,
            correction_max_gap: 0.10,
            max_extrapolation: MAX_EXTRAPOLATION,
            transmission_map: true,
            transmission_map_min_gain: TRANSMISSION_MAP_MIN_GAIN,
            geometric_tolerance: Some(determined::DEFAULT_GEOMETRIC_TOLERANCE),
        }
    }
}

/// Evidence for one candidate in one round.
#[derive(Debug, Clone)]
pub struct Score {
    pub label: String,
    pub block: Block,
    pub df: usize,
    pub f: f64,
    pub p_value: f64,
    pub delta_bic: f64,
    /// `1 − cv_with/cv_without` (time-blocked CV of the linearised augmented fit).
    pub cv_gain: f64,
    pub independence: f64,
    /// Number of tests this candidate stands for (change-point grids count every point).
    pub tests: usize,
    /// Cross-validated variance explained by the candidate divided by that explained by a
    /// kernel regression of the residual on joint space (NaN when the kernel regression
    /// explains too little to be a benchmark).
    pub np_ratio: f64,
}

/// One accepted step of the chain.
#[derive(Debug, Clone)]
pub struct Step {
    pub effect: Effect,
    pub evidence: Score,
    pub train_rms_before: f64,
    pub train_rms_after: f64,
    pub heldout_rms_before: Option<f64>,
    pub heldout_rms_after: Option<f64>,
    /// The model and effects after this step (for per-pose statistics and transfer).
    pub state_after: State,
}

/// Default of [`Options::max_extrapolation`]: an effect whose refitted prediction inside the
/// training poses' joint ranges exceeds 10× its largest at a training pose is left out.
/// Measured (docs/findings.md): the real UR10 Series D time-blocked 1.7468 → 0.3848 mm,
/// Series B / C / D every other split unchanged, `examples/diagnose_table` 19 / 19, 0 / 20
/// (`examples/real_policy --max-extrapolation inf` and `DIAG_MAX_EXTRAP=inf` with
/// `examples/diagnose_table` run without the check).
pub const MAX_EXTRAPOLATION: f64 = 10.0;

/// Default of [`Options::transmission_map_min_gain`]: the maps are kept when they predict the
/// chain's residual on time-blocked folds of the training poses at least 5 % better than zero.
pub const TRANSMISSION_MAP_MIN_GAIN: f64 = 0.05;

/// Held-out RMS more than this fraction above the training RMS flags overfitting.
pub const OVERFIT_GAP: f64 = 0.15;

/// ... and more than this much (mm): a gap below it is within measurement noise.
pub const OVERFIT_MIN_MM: f64 = 0.01;

/// The result of a diagnosis.
#[derive(Debug, Clone)]
pub struct Diagnosis {
    /// Geometric parameters the training poses do not determine to the prior's tolerance
    /// (held near nominal by the prior; [`determined`]).
    pub undetermined: Vec<determined::Undetermined>,
    /// Held-out poses outside the training poses' joint ranges (predicted with the effects
    /// held at the edge).
    pub outside: Option<effects::Outside>,
    pub nominal: State,
    pub geometric: State,
    pub state: State,
    pub steps: Vec<Step>,
    /// All candidate scores per round (round 0 = after the geometric fit).
    pub rounds: Vec<Vec<Score>>,
    /// Candidates that were significant but absorbed by the model (not identifiable).
    pub not_identifiable: Vec<Score>,
    /// Nonparametric correction, when one was needed: (CV RMS before, after).
    pub nonparametric: Option<(f64, f64)>,
    /// The transmission error maps, when they were added: the setting, the CV RMS of the
    /// chain's residual before them, the grid and the coefficients' posterior covariance.
    pub transmission_map: Option<transmap::MapChoice>,
    /// Residuals of the training data before the first effect (for plots).
    pub train_rms_nominal: f64,
    pub train_rms_geometric: f64,
    pub train_rms_final: f64,
    pub heldout_rms_nominal: Option<f64>,
    pub heldout_rms_geometric: Option<f64>,
    pub heldout_rms_final: Option<f64>,
    pub n_train: usize,
    pub n_heldout: usize,
    /// Effects considered but not testable on this data, with the reason.
    pub untestable: Vec<(String, String)>,
    /// Held-out poses inside the uncertainty window of an accepted change point.
    pub ambiguous_heldout: Vec<schema::AmbiguousPose>,
    /// Held-out poses left out of every held-out RMS (the ambiguous ones: which side of a
    /// change point they are on is unknown, so their error would score a guess).
    pub n_heldout_excluded: usize,
    /// Warnings of the diagnosis (for `diagnosis.json`).
    pub warnings: Vec<String>,
    /// Under [`Policy::Best`]: which chain was kept and why.
    pub policy_choice: Option<PolicyChoice>,
    /// The training RMS near the held-out poses ([`region`]; None without held-out poses).
    pub near_heldout: Option<region::NearHeldout>,
}

impl Diagnosis {
    /// One sentence on the training RMS where the held-out poses are and the gap against it
    /// (None without held-out poses).
    pub fn near_heldout_line(&self) -> Option<String> {
        let n = self.near_heldout?;
        let (g, f) = (self.heldout_rms_geometric?, self.heldout_rms_final?);
        Some(format!(
            "Where the held-out poses are: the {} training poses nearest each one (joint space; the nearest {:.1}° away, median, against {:.1}° between neighbouring training poses) have RMS {:.4} mm (geometric) → {:.4} mm (final); the held-out RMS is {:+.1} % / {:+.1} % from them (against all training poses {:+.1} % / {:+.1} %).",
            n.neighbours,
            n.heldout_spacing_deg,
            n.train_spacing_deg,
            n.geometric_mm,
            n.final_mm,
            100.0 * (g / n.geometric_mm - 1.0),
            100.0 * (f / n.final_mm - 1.0),
            100.0 * (g / self.train_rms_geometric - 1.0),
            100.0 * (f / self.train_rms_final - 1.0),
        ))
    }

    /// One sentence on the chain the [`Policy::Best`] policy kept (None under another policy).
    pub fn policy_line(&self) -> Option<String> {
        let c = self.policy_choice.as_ref()?;
        let other = if c.other_chain.is_empty() {
            "none".to_string()
        } else {
            c.other_chain.join(", ")
        };
        let stop = c
            .physics_first_stopped
            .as_ref()
            .map(|s| format!("; the physics-first chain {s}"))
            .unwrap_or_default();
        if let Some(g) = c.cv_rms_geometric {
            return Some(format!(
                "policy: kept the geometric fit alone: neither chain predicts the training poses' time blocks better than it (time-blocked CV RMS: geometric {g:.4} mm, kernel benchmark {:.4} mm, physics first {:.4} mm); the chains were: {}; {other}{stop}",
                c.cv_rms_kernel_benchmark,
                c.cv_rms_physics_first,
                if c.dropped_chain.is_empty() {
                    "none".to_string()
                } else {
                    c.dropped_chain.join(", ")
                }
            ));
        }
        Some(format!(
            "policy: kept the {} chain (time-blocked CV RMS on the training poses: kernel benchmark {:.4} mm, physics first {:.4} mm; physics first is kept when ≥ {:.0} % lower); the other chain was: {other}{stop}",
            c.chosen,
            c.cv_rms_kernel_benchmark,
            c.cv_rms_physics_first,
            100.0 * c.margin
        ))
    }

    /// Whether the chain found a physical effect.
    pub fn found_physical(&self) -> bool {
        self.steps
            .iter()
            .any(|s| !matches!(s.effect.block, Block::Nonparametric(_)))
    }
}

/// Time-block fold of every observation (obs sorted by time).
fn folds(obs: &[PoseObs], k: usize) -> Vec<usize> {
    let n = obs.len().max(1);
    (0..obs.len()).map(|i| (i * k / n).min(k - 1)).collect()
}

fn row_folds(obs_fold: &[usize]) -> Vec<usize> {
    obs_fold.iter().flat_map(|f| [*f, *f, *f]).collect()
}

/// Time-blocked CV RMS (per residual row, mm) of `state`'s model: every parameter refitted
/// linearly on each fold's training poses (the prior's rows, when there is one, in every
/// fold's training rows), the fold's poses predicted.
fn model_cv_rms(state: &State, train: &[PoseObs], n_folds: usize) -> f64 {
    let (r, j) = fit::stack_prior(state, train);
    let mut rf = row_folds(&folds(train, n_folds));
    // Fold `n_folds` is never a test fold: the prior's rows train every fold.
    rf.resize(r.len(), n_folds);
    CvBase::new(&j, &r, &rf, n_folds).rms(&j, &DMatrix::zeros(r.len(), 0), &r)
}

/// Default harmonic-drive gear ratio of the `wave_generator` candidates (see
/// [`Options::wave_gear_ratio`]).
pub const DEFAULT_WAVE_GEAR_RATIO: f64 = 101.0;

/// Harmonics of the wave-generator rotation tried (1: eccentricity of the wave generator,
/// 2: the two lobes of the elliptical flexspline).
pub const WAVE_HARMONICS: [u32; 2] = [1, 2];

/// Harmonics of a joint's rotation tried as transmission ripple (the default of
/// [`Options::ripple_harmonics`]): 3 to 40 cycles per output turn. The periodogram of the
/// real UR10's residual (`examples/real_ipa_why.rs`) has its strongest lines at 14–20 cycles
/// per turn on joints 1–3 and 5 and at 31–36 on joint 4 (output-side encoder or bearing
/// ripple), none at the harmonic-drive wave-generator lines (100, 101, 200, 202).
pub const RIPPLE_HARMONICS: std::ops::RangeInclusive<u32> = 3..=40;

/// The candidate library for this data (and the effects it cannot test, with reasons):
/// every effect of the library in groups (one group per kind and joint; a group's variants
/// — warm-up time constants, change points, ripple harmonics — count as separate tests),
/// each block kept only if the data can identify it ([`EffectModel::check_identifiable`]).
pub fn candidates(
    model: &KinematicModel,
    train: &[PoseObs],
) -> (Vec<Vec<Block>>, Vec<(String, String)>) {
    candidates_with(model, train, &Options::default())
}

/// [`candidates`] with the options' library settings (the wave-generator gear ratio).
pub fn candidates_with(
    model: &KinematicModel,
    train: &[PoseObs],
    opt: &Options,
) -> (Vec<Vec<Block>>, Vec<(String, String)>) {
    // Every family's candidates, registry order (per joint, then the global groups).
    let mut groups = effects::registry_candidates(model, train, opt);
    groups.retain(|g| {
        g.first()
            .is_none_or(|b| !opt.exclude_kinds.iter().any(|k| k == b.kind()))
    });
    let mut out = Vec::new();
    let mut untestable: Vec<(String, String)> = Vec::new();
    for g in groups {
        let mut reason = None;
        let kept: Vec<Block> = g
            .into_iter()
            .filter(|b| match b.check_identifiable(model, train) {
                Ok(()) => true,
                Err(e) => {
                    let name = match b {
                        Block::Compliance(_) | Block::Backlash(_) => b.label(),
                        _ => b.kind().to_string(),
                    };
                    reason.get_or_insert((name, e));
                    false
                }
            })
            .collect();
        if !kept.is_empty() {
            out.push(kept);
        } else if let Some(r) = reason {
            if !untestable.iter().any(|u| u.1 == r.1) {
                untestable.push(r);
            }
        }
    }
    (out, untestable)
}

/// Warm-up time constants tried (s): a log grid from a twentieth of the session span to
/// twice the span (12 points).
pub fn tau_grid(span_s: f64) -> Vec<f64> {
    let (lo, hi) = ((span_s / 20.0).max(60.0), (2.0 * span_s).max(120.0));
    (0..12)
        .map(|k| lo * (hi / lo).powf(k as f64 / 11.0))
        .collect()
}

fn set_tau(e: &mut Effect, tau: f64) {
    match &mut e.block {
        Block::JointDrift(effects::JointDrift { driver, .. })
        | Block::LengthDrift(effects::LengthDrift { driver }) => *driver = driver.with_tau(tau),
        _ => {}
    }
}

fn warm_up_tau(e: &Effect) -> Option<f64> {
    match &e.block {
        Block::JointDrift(effects::JointDrift {
            driver: Driver::WarmUp { tau_s, .. },
            ..
        })
        | Block::LengthDrift(effects::LengthDrift {
            driver: Driver::WarmUp { tau_s, .. },
        }) => Some(*tau_s),
        _ => None,
    }
}

/// Refine the time constant of the warm-up effect `k` of `state` (golden-section search on
/// ln τ within a factor 2 of the grid value, every evaluation a joint refit) and set its
/// standard deviation from the curvature of the residual sum of squares over τ.
pub fn refine_tau(state: &mut State, train: &[PoseObs], k: usize) {
    let Some(tau0) = state.effects.get(k).and_then(warm_up_tau) else {
        return;
    };
    let base = state.clone();
    let eval = |tau: f64| -> (f64, State) {
        let mut st = base.clone();
        set_tau(&mut st.effects[k], tau);
        let rep = fit(&mut st, train, 30);
        (rep.rss, st)
    };
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut a, mut b) = ((tau0 / 2.0).ln(), (tau0 * 2.0).ln());
    let mut c = b - g * (b - a);
    let mut d = a + g * (b - a);
    let (mut fc, mut fd) = (eval(c.exp()).0, eval(d.exp()).0);
    for _ in 0..14 {
        if fc < fd {
            b = d;
            d = c;
            fd = fc;
            c = b - g * (b - a);
            fc = eval(c.exp()).0;
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + g * (b - a);
            fd = eval(d.exp()).0;
        }
    }
    let tau = (0.5 * (a + b)).exp();
    let (rss, best) = eval(tau);
    let rss_here = residuals(state, train).norm_squared();
    if rss <= rss_here {
        *state = best;
    }
    // Profile standard deviation: var(τ) = 2 σ² / RSS''(τ).
    let tau = warm_up_tau(&state.effects[k]).unwrap_or(tau);
    let h = 0.05 * tau;
    let (rp, rm) = (eval(tau + h).0, eval(tau - h).0);
    let curv = (rp - 2.0 * rss.min(rss_here) + rm) / (h * h);
    let dof = (3 * train.len())
        .saturating_sub(state.model.free_count() + 1)
        .max(1) as f64;
    let sigma2 = rss.min(rss_here) / dof;
    state.effects[k].tau_std = if curv > 0.0 {
        (2.0 * sigma2 / curv).sqrt()
    } else {
        f64::NAN
    };
}

/// Score every candidate against the residual of `state` on `train`.
pub fn score_round(
    state: &State,
    train: &[PoseObs],
    cands: &[Vec<Block>],
    opt: &Options,
) -> Vec<Score> {
    let (r, j) = stack(state, train);
    let nrow = r.len();
    let q = orth_basis(&j);
    // `Qᵀ` once for every candidate's projection (the same products as `project_out`).
    let qt = q.transpose();
    let rank_j = q.ncols();
    let rss0 = r.norm_squared();
    let rf = row_folds(&folds(train, opt.n_folds));
    let cvb = CvBase::new(&j, &r, &rf, opt.n_folds);
    let cv0 = cvb.rms(&j, &DMatrix::zeros(nrow, 0), &r);
    // Candidate columns come from the Jacobian of the same problem the refit solves
    // ([`fit::DiagnoseProblem`]): every candidate of the round appended to the state at zero
    // coefficients (which leaves the prediction and the other columns unchanged).
    let all: Vec<Block> = cands.iter().flatten().cloned().collect();
    let mut cols = candidate_columns(state, train, &all).into_iter();
    let eval_block = |b: &Block, g: DMatrix<f64>, tests: usize| -> Option<(Score, DMatrix<f64>)> {
        if g.iter().all(|v| v.abs() < 1e-15) {
            return None;
        }
        let gp = project_out_t(&q, &qt, &g);
        let indep = independence(&g, &gp);
        let qg = orth_basis(&gp);
        let df = qg.ncols();
        if df == 0 {
            return None;
        }
        let ess = (qg.transpose() * &r).norm_squared().min(rss0);
        let rss1 = (rss0 - ess).max(1e-300);
        let df2 = nrow.saturating_sub(rank_j + df).max(1) as f64;
        let f = (ess / df as f64) / (rss1 / df2);
        let p = f_sf(f, df as f64, df2);
        let dbic = nrow as f64 * (rss0 / rss1).ln() - df as f64 * (nrow as f64).ln();
        Some((
            Score {
                label: b.label(),
                block: b.clone(),
                df,
                f,
                p_value: p,
                delta_bic: dbic,
                cv_gain: f64::NAN,
                independence: indep,
                tests,
                np_ratio: f64::NAN,
            },
            g,
        ))
    };
    let mut times: Vec<f64> = train.iter().map(|o| o.ctx.t).collect();
    times.sort_by(|a, b| a.total_cmp(b));
    // Every group is scored on its own (its best block, change-point refinement, CV gain):
    // the groups in parallel and each group's blocks in parallel, then taken in order (the
    // same numbers and the same choices as one at a time).
    use rayon::prelude::*;
    let group_cols: Vec<Vec<DMatrix<f64>>> = cands
        .iter()
        .map(|g| cols.by_ref().take(g.len()).collect())
        .collect();
    let score_group = |group: &Vec<Block>, gcols: Vec<DMatrix<f64>>| -> Option<Score> {
        let mut best: Option<(Score, DMatrix<f64>)> = None;
        let consider = |cand: Option<(Score, DMatrix<f64>)>,
                        best: &mut Option<(Score, DMatrix<f64>)>| {
            if let Some(c) = cand {
                if best
                    .as_ref()
                    .is_none_or(|(bs, _)| c.0.delta_bic > bs.delta_bic)
                {
                    *best = Some(c);
                }
            }
        };
        let scored: Vec<_> = group
            .par_iter()
            .zip(gcols)
            .map(|(b, g)| eval_block(b, g, group.len()))
            .collect();
        for c in scored {
            consider(c, &mut best);
        }
        // Refine a change point between its coarse neighbours: every mid-point between two
        // consecutive poses (each one counts as a test).
        if let Some((
            Score {
                block: Block::BaseShift(effects::BaseShift { t_change }),
                ..
            },
            _,
        )) = &best
        {
            let tc = *t_change;
            let grid: Vec<f64> = group
                .iter()
                .filter_map(|b| match b {
                    Block::BaseShift(b) => Some(b.t_change),
                    _ => None,
                })
                .collect();
            let lo = grid
                .iter()
                .copied()
                .filter(|t| *t < tc)
                .fold(f64::NEG_INFINITY, f64::max);
            let hi = grid
                .iter()
                .copied()
                .filter(|t| *t > tc)
                .fold(f64::INFINITY, f64::min);
            let nt = times.len();
            let lo = lo.max(times[nt / 20]);
            let hi = hi.min(times[(19 * nt / 20).min(nt - 1)]);
            let fine: Vec<f64> = times
                .windows(2)
                .map(|w| 0.5 * (w[0] + w[1]))
                .filter(|t| *t > lo && *t < hi && (*t - tc).abs() > 1e-9)
                .collect();
            let tests = group.len() + fine.len();
            // Columns from one shift before every pose, masked per change point
            // ([`changepoint::ShiftColumns`]: the same numbers), scored a chunk at a time
            // in parallel and taken in order (the same choice as one at a time). Above
            // [`changepoint::TWO_LEVEL_ABOVE`] mid-points: every k-th first, then every one
            // within k of the best (each mid-point still counts as a test).
            let sc = changepoint::ShiftColumns::new(state, train);
            let score = |idx: &[usize], best: &mut Option<(Score, DMatrix<f64>)>| {
                for chunk in idx.chunks(64) {
                    let scored: Vec<_> = chunk
                        .par_iter()
                        .map(|&i| {
                            let b: Block = effects::BaseShift { t_change: fine[i] }.into();
                            let g = sc.at(fine[i]);
                            eval_block(&b, g, tests)
                        })
                        .collect();
                    for c in scored {
                        consider(c, best);
                    }
                }
            };
            let (first, stride) = changepoint::first_level(fine.len());
            score(&first, &mut best);
            let t_best = match &best {
                Some((
                    Score {
                        block: Block::BaseShift(s),
                        ..
                    },
                    _,
                )) => s.t_change,
                _ => tc,
            };
            let pos = fine.partition_point(|t| *t < t_best);
            score(
                &changepoint::second_level(fine.len(), stride, pos),
                &mut best,
            );
            if let Some((s, _)) = &mut best {
                s.tests = tests;
            }
        }
        best.map(|(mut s, g)| {
            let cv1 = cvb.rms(&j, &g, &r);
            s.cv_gain = 1.0 - cv1 / cv0;
            s
        })
    };
    let mut out: Vec<Score> = cands
        .par_iter()
        .zip(group_cols)
        .filter_map(|(group, gcols)| score_group(group, gcols))
        .collect();
    out.sort_by(|a, b| b.delta_bic.total_cmp(&a.delta_bic));
    out
}

/// Columns (d prediction / d coefficient, 3 rows per pose) of each block of `blocks` at
/// the current state: the trailing columns of the [`fit::DiagnoseProblem`] Jacobian of the
/// state with the blocks appended at zero coefficients.
pub fn candidate_columns(state: &State, train: &[PoseObs], blocks: &[Block]) -> Vec<DMatrix<f64>> {
    if colcache::StateColumns::applies(blocks) {
        return colcache::StateColumns::new(state, train).columns(train, blocks);
    }
    let mut st = state.clone();
    let mut off = st.model.free_count() + st.effects.iter().map(|e| e.coefs.len()).sum::<usize>();
    st.effects.extend(blocks.iter().cloned().map(Effect::zero));
    let prob = fit::DiagnoseProblem {
        state: &st,
        obs: train,
    };
    let (_, j) = crate::solve::lm::LsqProblem::residuals_jacobian(&prob, &fit::params_of(&st));
    blocks
        .iter()
        .map(|b| {
            let n = b.n_params();
            let g = j.columns(off, n).into_owned();
            off += n;
            g
        })
        .collect()
}

/// Smallest over largest singular value of the block's columns after the model's column
/// space is projected out (columns scaled to unit norm; 0 when a column vanishes).
fn block_conditioning(q: &DMatrix<f64>, g: &DMatrix<f64>) -> f64 {
    let mut gp = project_out(q, g);
    for mut c in gp.column_iter_mut() {
        let n = c.norm();
        if n <= 1e-12 {
            return 0.0;
        }
        c /= n;
    }
    let sv = gp.singular_values();
    let max = sv.max();
    if max > 0.0 {
        sv.min() / max
    } else {
        0.0
    }
}

/// The block with mass points `pts` (same kind and joint as `b`).
fn with_points(b: &Block, pts: Vec<effects::MassPoint>) -> Block {
    match b {
        Block::Compliance(c) => Block::Compliance(effects::Compliance {
            joint: c.joint,
            points: pts,
        }),
        Block::LinkDeflection(d) => Block::LinkDeflection(effects::LinkDeflection {
            joint: d.joint,
            points: pts,
            anisotropic: d.anisotropic,
        }),
        other => other.clone(),
    }
}

/// Compliance and link-deflection blocks keep only the mass points whose moments the
/// training poses tell apart: while the block's columns (the current model's column space
/// projected out) have a conditioning ([`block_conditioning`]) below
/// [`MIN_BLOCK_CONDITIONING`], the mass point whose removal conditions the rest best is
/// dropped. Otherwise the refit moves the coefficients freely along combinations the poses
/// do not determine, which cancel on the training poses and not elsewhere (real UR10
/// Series D, 474 poses in a small workspace: the six coefficients of `joint_compliance(j2)`
/// at 5× their standard deviations, 15.8 mm predicted at the one upright held-out pose).
fn prune_mass_points(state: &State, train: &[PoseObs], cands: &mut [Vec<Block>]) {
    let (_, j) = stack(state, train);
    let q = orth_basis(&j);
    // Every call below is at the same state: evaluate it once.
    let sc = colcache::StateColumns::new(state, train);
    let candidate_columns = |bs: &[Block]| {
        if colcache::StateColumns::applies(bs) {
            sc.columns(train, bs)
        } else {
            candidate_columns(state, train, bs)
        }
    };
    for b in cands.iter_mut().flatten() {
        let pts = match b {
            Block::Compliance(c) => c.points.clone(),
            Block::LinkDeflection(d) => d.points.clone(),
            _ => continue,
        };
        let mut pts = pts;
        let mut cond = candidate_columns(std::slice::from_ref(b))
            .pop()
            .map_or(0.0, |g| block_conditioning(&q, &g));
        while cond < MIN_BLOCK_CONDITIONING && pts.len() > 1 {
            let variants: Vec<Block> = (0..pts.len())
                .map(|k| {
                    let mut p = pts.clone();
                    p.remove(k);
                    with_points(b, p)
                })
                .collect();
            let conds: Vec<f64> = candidate_columns(&variants)
                .iter()
                .map(|g| block_conditioning(&q, g))
                .collect();
            let Some((k, &c)) = conds.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)) else {
                break;
            };
            tracing::debug!(
                "{}: conditioning {cond:.2e} → {c:.2e} without mass point {:?}",
                b.label(),
                pts[k]
            );
            pts.remove(k);
            cond = c;
        }
        *b = with_points(b, pts);
    }
}

/// See [`prune_mass_points`].
pub const MIN_BLOCK_CONDITIONING: f64 = 0.01;

fn accepted(s: &Score, m_tests: usize, opt: &Options) -> bool {
    s.p_value < opt.alpha / m_tests as f64
        && s.delta_bic > opt.min_delta_bic
        && s.cv_gain > opt.min_cv_gain
        && s.independence >= opt.min_independence
        && (s.np_ratio.is_nan() || s.np_ratio >= opt.min_np_ratio)
}

/// Inputs and residual targets of the kernel regression (arm-frame representation).
fn np_data(state: &State, train: &[PoseObs]) -> (Vec<Vec<f64>>, Vec<Vector3<f64>>) {
    let rv = residual_vectors(state, train);
    let qs: Vec<Vec<f64>> = train.iter().map(|o| o.ctx.q.clone()).collect();
    nonparam::arm_frame_data(&state.model, &qs, &rv)
}

/// Cross-validated variance fraction of the residual that a kernel regression on joint
/// space explains, with fixed hyper-parameters; NaN if it cannot be computed.
fn np_gain(state: &State, train: &[PoseObs], hp: Option<(f64, f64)>, opt: &Options) -> f64 {
    let Some((ell, lam)) = hp else {
        return f64::NAN;
    };
    let (qs, rv) = np_data(state, train);
    match nonparam::cv_fixed(&qs, &rv, &folds(train, opt.n_folds), opt.n_folds, ell, lam) {
        Some((b, a)) if b > 0.0 => 1.0 - (a / b).powi(2),
        _ => f64::NAN,
    }
}

/// Held-out RMS with the effects of the joint angles held at the edge of the training poses'
/// joint ranges ([`effects::apply_effects_held`]): a held-out pose outside them is not
/// predicted by extrapolating a fitted effect.
fn heldout_rms(state: &State, heldout: &[PoseObs], train: &[PoseObs]) -> Option<f64> {
    let range = effects::JointRange::of(train);
    (!heldout.is_empty()).then(|| rms3(&fit::residuals_held(state, heldout, range.as_ref())))
}

/// Whether `o` is one of the ambiguous held-out poses.
fn is_ambiguous(amb: &[schema::AmbiguousPose], o: &PoseObs) -> bool {
    amb.iter().any(|a| a.id == o.id && a.t_s == o.t)
}

/// Held-out poses inside the uncertainty window of an accepted change point: strictly
/// between the last training pose before the step and the first one after it.
fn ambiguous(
    steps: &[Step],
    train: &[PoseObs],
    heldout: &[PoseObs],
) -> (Vec<schema::AmbiguousPose>, Vec<String>) {
    let mut out = Vec::new();
    for st in steps {
        let Block::BaseShift(effects::BaseShift { t_change }) = st.effect.block else {
            continue;
        };
        let lo = train
            .iter()
            .map(|o| o.ctx.t)
            .filter(|t| *t < t_change)
            .fold(f64::NEG_INFINITY, f64::max);
        let hi = train
            .iter()
            .map(|o| o.ctx.t)
            .filter(|t| *t >= t_change)
            .fold(f64::INFINITY, f64::min);
        for o in heldout {
            if o.ctx.t > lo && o.ctx.t < hi {
                out.push(schema::AmbiguousPose {
                    id: o.ctx.id,
                    t_s: o.ctx.t,
                    effect: st.evidence.label.clone(),
                    after_s: lo,
                    before_s: hi,
                });
            }
        }
    }
    (out, Vec::new())
}

/// One chain of accepted effects (and, when one was added, the nonparametric correction).
struct Chain {
    state: State,
    steps: Vec<Step>,
    rounds: Vec<Vec<Score>>,
    not_identifiable: Vec<Score>,
    nonparametric: Option<(f64, f64)>,
    transmission_map: Option<transmap::MapChoice>,
    /// Time-blocked cross-validated RMS (per axis, mm) of the final model: the linearised
    /// refit of the physical chain on each fold's complement, times the correction's
    /// out-of-fold ratio when a correction was added ([`chain_cv`]).
    cv_rms: f64,
    /// The correction chosen by cross-validation and not fitted yet ([`add_correction`]):
    /// under [`Policy::Best`] only the kept chain's is fitted ([`fit_correction`]).
    pending: Option<nonparam::RbfCv>,
    /// Effects left out because their prediction grows outside the training poses (one
    /// sentence each, for the warnings).
    extrapolating: Vec<String>,
    /// Why the chain stopped before its cap, when the inner CV stopped it ([`inner_cv`]).
    stopped: Option<String>,
}

/// Select effects one at a time from `start` under the rules of `opt` (see the module doc).
fn select_chain(
    start: &State,
    train: &[PoseObs],
    heldout: &[PoseObs],
    cands: Vec<Vec<Block>>,
    np_hp: Option<(f64, f64)>,
    opt: &Options,
    round0: Option<&[Score]>,
) -> Chain {
    let mut state = start.clone();
    // The scores of the first round when already computed (on `start` with `cands`).
    let mut round0 = round0.map(<[Score]>::to_vec);
    let mut remaining = cands;
    let mut steps = Vec::new();
    let mut rounds = Vec::new();
    let mut not_identifiable: Vec<Score> = Vec::new();
    // The kernel benchmark only matters to the rule that uses it.
    let use_np = opt.min_np_ratio > 0.0;
    let mut extrapolating = Vec::new();
    // The held-out-free stop of a chain without the kernel-benchmark rule ([`inner_cv`]).
    let stop = opt.physics_first_stop.filter(|_| !use_np);
    let cv_folds = folds(train, opt.n_folds);
    let mut cv_prev = stop.map(|s| {
        inner_cv::pose_cv_of(
            &state,
            train,
            &cv_folds,
            opt.n_folds,
            s.effects_only,
            s.forward,
        )
    });
    let mut stopped = None;
    // Each pass accepts an effect, leaves one out (its group dropped) or stops.
    while steps.len() < opt.max_effects {
        let t_round = std::time::Instant::now();
        // The candidate scores and the kernel benchmark are independent: both at once.
        let first = round0.take();
        let (mut scores, npg) = rayon::join(
            || first.unwrap_or_else(|| score_round(&state, train, &remaining, opt)),
            || {
                if use_np {
                    np_gain(&state, train, np_hp, opt)
                } else {
                    f64::NAN
                }
            },
        );
        if npg > opt.np_benchmark_gain {
            for s in &mut scores {
                s.np_ratio = (1.0 - (1.0 - s.cv_gain).powi(2)) / npg;
            }
        }
        tracing::debug!(
            "kernel benchmark explains {:.1} % of the residual variance",
            100.0 * npg
        );
        tracing::debug!(
            "scored {} candidates in {:?}",
            scores.len(),
            t_round.elapsed()
        );
        // Bonferroni: every test of the round (change-point refinements included).
        let m_tests: usize = remaining
            .iter()
            .map(|g| {
                scores
                    .iter()
                    .find(|s| {
                        g.iter().any(|b| b.label() == s.label)
                            || (matches!(s.block, Block::BaseShift(_))
                                && matches!(g[0], Block::BaseShift(_)))
                    })
                    .map(|s| s.tests)
                    .unwrap_or(g.len())
            })
            .sum::<usize>()
            .max(1);
        for s in &scores {
            let signif = s.p_value < opt.alpha / m_tests as f64 && s.delta_bic > opt.min_delta_bic;
            if signif
                && s.independence < opt.min_independence
                && !not_identifiable.iter().any(|x| x.label == s.label)
            {
                not_identifiable.push(s.clone());
            }
        }
        let pick = scores.iter().find(|s| accepted(s, m_tests, opt)).cloned();
        rounds.push(scores);
        let Some(best) = pick else {
            break;
        };
        let before_train = rms3(&residuals(&state, train));
        let before_held = heldout_rms(&state, heldout, train);
        let before_state = state.clone();
        state.effects.push(Effect::zero(best.block.clone()));
        let t_fit = std::time::Instant::now();
        let rep = fit(&mut state, train, 50);
        tracing::debug!(
            "refit with {}: {} iterations in {:?}",
            best.label,
            rep.iterations,
            t_fit.elapsed()
        );
        let k_new = state.effects.len() - 1;
        refine_tau(&mut state, train, k_new);
        if let Some((ratio, on_train, on_probes)) = (opt.max_extrapolation.is_finite())
            .then(|| extrapolation::ratio(&state, train, k_new))
            .flatten()
        {
            tracing::debug!(
                "{}: largest displacement {on_probes:.4} mm inside the training joint ranges, {on_train:.4} mm at a training pose ({ratio:.1}×)",
                best.label
            );
            if ratio > opt.max_extrapolation {
                extrapolating.push(format!(
                    "{} left out: refitted, it predicts up to {on_probes:.3} mm inside the training poses' joint ranges but at most {on_train:.3} mm at a training pose ({ratio:.0}×, limit {:.0}×): its coefficients cancel on the training poses only",
                    best.label, opt.max_extrapolation
                ));
                state = before_state;
                remaining.retain(|g| !g.iter().any(|b| b.label() == best.block.label()));
                continue;
            }
        }
        if let (Some(rule), Some(prev)) = (stop, cv_prev.as_ref()) {
            let now = inner_cv::pose_cv_of(
                &state,
                train,
                &cv_folds,
                opt.n_folds,
                rule.effects_only,
                rule.forward,
            );
            let (keep, g, se) = inner_cv::keeps(prev, &now, &rule);
            tracing::debug!(
                "{}: inner CV RMS {:.4} -> {:.4} mm, gain {g:.3e} mm² (standard error {se:.3e})",
                best.label,
                prev.rms(),
                now.rms()
            );
            if !keep {
                stopped = Some(format!(
                    "stopped before {}: refitted, it lowers the time-blocked CV error of the training poses by {g:.2e} mm² per pose, not more than {} standard error(s) ({se:.2e})",
                    best.label, rule.k_se
                ));
                state = before_state;
                break;
            }
            cv_prev = Some(now);
        }
        let effect = state.effects.last().cloned().expect("just pushed");
        steps.push(Step {
            effect,
            evidence: best.clone(),
            train_rms_before: before_train,
            train_rms_after: rms3(&residuals(&state, train)),
            heldout_rms_before: before_held,
            heldout_rms_after: heldout_rms(&state, heldout, train),
            state_after: state.clone(),
        });
        // Drop the group the accepted block came from (one base shift, one per kind+joint);
        // of a ripple group only the accepted harmonic (a joint may carry several).
        if matches!(best.block, Block::Ripple(_)) {
            for g in remaining.iter_mut() {
                g.retain(|b| b.label() != best.block.label());
            }
            remaining.retain(|g| !g.is_empty());
        }
        remaining.retain(|g| {
            !g.iter().any(|b| {
                b.label() == best.block.label()
                    || (matches!(b, Block::BaseShift(_))
                        && matches!(best.block, Block::BaseShift(_)))
            })
        });
    }
    let cv_rms = model_cv_rms(&state, train, opt.n_folds);
    Chain {
        state,
        steps,
        rounds,
        not_identifiable,
        nonparametric: None,
        transmission_map: None,
        cv_rms,
        pending: None,
        extrapolating,
        stopped,
    }
}

/// Add the transmission error maps of what `chain` leaves ([`transmap`]), one step per
/// mapped joint, when they predict time-blocked folds of the training poses better than
/// zero by [`Options::transmission_map_min_gain`]. Runs on the kept chain only, after the
/// policy's choice (which therefore compares the chains as before; measured on the real
/// UR10 series, adding the maps to both chains before the choice was no better and cost a
/// second kernel cross-validation). Whether the maps were added.
fn add_transmission_map(
    chain: &mut Chain,
    train: &[PoseObs],
    heldout: &[PoseObs],
    opt: &Options,
) -> bool {
    if !opt.transmission_map || opt.max_effects == 0 {
        return false;
    }
    let fo = folds(train, opt.n_folds);
    let Some(m) = transmap::fit_map(&chain.state, train, &fo, opt) else {
        return false;
    };
    tracing::debug!(
        "transmission map: {} harmonics, ridge {:e}: CV {:.4} -> {:.4} mm",
        m.chosen.harmonics,
        m.chosen.ridge,
        m.cv_rms_before,
        m.chosen.cv_rms
    );
    let gain = 1.0 - m.chosen.cv_rms / m.cv_rms_before;
    for e in m.effects.iter().cloned() {
        let before_train = rms3(&residuals(&chain.state, train));
        let before_held = heldout_rms(&chain.state, heldout, train);
        chain.state.effects.push(e.clone());
        let ev = Score {
            label: e.block.label(),
            block: e.block.clone(),
            df: e.coefs.len(),
            f: f64::NAN,
            p_value: f64::NAN,
            delta_bic: f64::NAN,
            cv_gain: gain,
            independence: f64::NAN,
            tests: transmap::MAP_HARMONICS.len() * transmap::MAP_RIDGE.len(),
            np_ratio: f64::NAN,
        };
        chain.steps.push(Step {
            effect: e,
            evidence: ev,
            train_rms_before: before_train,
            train_rms_after: rms3(&residuals(&chain.state, train)),
            heldout_rms_before: before_held,
            heldout_rms_after: heldout_rms(&chain.state, heldout, train),
            state_after: chain.state.clone(),
        });
    }
    if m.cv_rms_before > 0.0 {
        chain.cv_rms *= m.chosen.cv_rms / m.cv_rms_before;
    }
    chain.transmission_map = Some(m);
    true
}

/// Add the nonparametric correction of what `chain` leaves, only if it predicts held-out
/// (time-blocked) folds clearly better than zero.
/// `geometric_cv` is the kernel cross-validation of the geometric residual when it was
/// already run (the kernel benchmark): reused when the chain added no effect.
fn add_correction(
    chain: &mut Chain,
    train: &[PoseObs],
    opt: &Options,
    geometric_cv: Option<&nonparam::RbfCv>,
) {
    if !opt.allow_nonparametric || train.len() < 40 {
        return;
    }
    let (qs, rv) = np_data(&chain.state, train);
    let fo = folds(train, opt.n_folds);
    let cv = match geometric_cv {
        Some(c) if chain.steps.is_empty() => Some(c.clone()),
        _ => nonparam::cross_validate(&qs, &rv, &fo, opt.n_folds),
    };
    if let Some(c) = &cv {
        for g in &c.grid {
            tracing::debug!(
                "correction grid: ell {} lambda {}: CV {:.4} fit {:.4} gap {:.1} %",
                g.length_scale,
                g.lambda,
                g.cv_rms,
                g.fit_rms,
                100.0 * g.gap()
            );
        }
    }
    let Some(cv) = cv.and_then(|c| c.within_gap(opt.correction_max_gap, OVERFIT_MIN_MM)) else {
        return;
    };
    if cv.cv_rms_after >= (1.0 - opt.nonparam_min_gain) * cv.cv_rms_before {
        return;
    }
    if cv.cv_rms_before > 0.0 {
        chain.cv_rms *= cv.cv_rms_after / cv.cv_rms_before;
    }
    chain.pending = Some(cv);
}

/// Fit the correction [`add_correction`] chose for `chain` (the kernel system of every
/// training pose: the costliest single solve of a diagnosis, so under [`Policy::Best`] only
/// for the chain that is kept) and append it as the chain's last step. A system that cannot
/// be solved leaves the chain without a correction.
fn fit_correction(chain: &mut Chain, train: &[PoseObs], heldout: &[PoseObs]) {
    let Some(cv) = chain.pending.take() else {
        return;
    };
    let state = &mut chain.state;
    let r = residuals(state, train);
    let (qs, rv) = np_data(state, train);
    let Some(mut rbf) = nonparam::Rbf::fit(&qs, &rv, cv.length_scale, cv.lambda) else {
        if cv.cv_rms_after > 0.0 {
            chain.cv_rms *= cv.cv_rms_before / cv.cv_rms_after;
        }
        return;
    };
    rbf.arm_frame = true;
    let before_train = rms3(&r);
    let before_held = heldout_rms(state, heldout, train);
    let e = Effect {
        block: Block::Nonparametric(Box::new(rbf)),
        coefs: vec![],
        std: vec![],
        tau_std: f64::NAN,
    };
    state.effects.push(e.clone());
    let ev = Score {
        label: "nonparametric".into(),
        block: e.block.clone(),
        df: train.len() * 3,
        f: f64::NAN,
        p_value: f64::NAN,
        delta_bic: f64::NAN,
        cv_gain: 1.0 - cv.cv_rms_after / cv.cv_rms_before,
        independence: f64::NAN,
        tests: 9,
        np_ratio: f64::NAN,
    };
    chain.steps.push(Step {
        effect: e,
        evidence: ev,
        train_rms_before: before_train,
        train_rms_after: rms3(&residuals(state, train)),
        heldout_rms_before: before_held,
        heldout_rms_after: heldout_rms(state, heldout, train),
        state_after: state.clone(),
    });
    chain.nonparametric = Some((cv.cv_rms_before, cv.cv_rms_after));
}

/// Which chain the [`Policy::Best`] policy kept, and the evidence (time-blocked CV RMS of
/// both final models, training data only).
#[derive(Debug, Clone)]
pub struct PolicyChoice {
    /// `"kernel benchmark"` or `"physics first"`.
    pub chosen: &'static str,
    pub cv_rms_kernel_benchmark: f64,
    pub cv_rms_physics_first: f64,
    /// The physics-first chain is kept when its CV RMS is at least this fraction below the
    /// kernel-benchmark chain's.
    pub margin: f64,
    /// Effects of the chain that was not kept.
    pub other_chain: Vec<String>,
    /// Why the physics-first chain stopped before its cap ([`inner_cv`]), when it did.
    pub physics_first_stopped: Option<String>,
    /// The geometric fit's own time-blocked CV RMS, when neither chain beat it and the
    /// geometric fit was kept alone (`chosen` is then `"geometric fit alone"`).
    pub cv_rms_geometric: Option<f64>,
    /// Effects of the chosen chain when the geometric fit was kept in its place.
    pub dropped_chain: Vec<String>,
}

/// Run the whole diagnosis. `model` is the nominal model (its free flags are used for the
/// geometric fit after [`KinematicModel::fix_point_redundancies`]).
pub fn diagnose(
    model: &KinematicModel,
    train: &[PoseObs],
    heldout: &[PoseObs],
    opt: &Options,
) -> anyhow::Result<Diagnosis> {
    let mut model = model.clone();
    model.fix_point_redundancies();
    fit_nominal(&mut model, train)?;
    let mut nominal = State {
        prior: None,
        model: model.clone(),
        effects: vec![],
    };
    let train_rms_nominal = rms3(&residuals(&nominal, train));
    let mut state = nominal.clone();
    let mut rep = fit(&mut state, train, 50);
    // The geometry under a prior centred on the nominal values: a direction the poses
    // hardly see stays near nominal ([`determined`]). Every later fit carries it.
    let mut undetermined = Vec::new();
    if let Some(tol) = opt.geometric_tolerance {
        undetermined = determined::undetermined(&state, train, tol);
        nominal.prior = Some(std::sync::Arc::new(determined::prior(
            &nominal, &state, train, tol,
        )));
        state = nominal.clone();
        rep = fit(&mut state, train, 50);
    }
    if rep.rank < rep.n_params {
        tracing::warn!(
            "geometric identification Jacobian has rank {} < {} parameters",
            rep.rank,
            rep.n_params
        );
    }
    tracing::debug!(
        "geometric fit: {} iterations, rank {}",
        rep.iterations,
        rep.rank
    );
    let geometric = state.clone();
    let train_rms_geometric = rms3(&residuals(&geometric, train));
    let (mut cands, untestable) = candidates_with(&state.model, train, opt);
    // Hyper-parameters of the kernel benchmark, chosen once on the geometric residual (only
    // the kernel-benchmark rule uses them); independent of the candidates' pruning and
    // first round, so computed beside them.
    let (np_cv, round0) = rayon::join(
        || {
            (train.len() >= 40 && opt.min_np_ratio > 0.0)
                .then(|| {
                    let (qs, rv) = np_data(&state, train);
                    nonparam::cross_validate(&qs, &rv, &folds(train, opt.n_folds), opt.n_folds)
                })
                .flatten()
        },
        || {
            prune_mass_points(&geometric, train, &mut cands);
            // Both chains of [`Policy::Best`] start with the same round: score it once.
            (opt.policy == Policy::Best && opt.max_effects > 0)
                .then(|| score_round(&geometric, train, &cands, opt))
        },
    );
    let np_hp = np_cv.as_ref().map(|c| (c.length_scale, c.lambda));
    let single = |o: &Options| {
        let mut c = select_chain(
            &geometric,
            train,
            heldout,
            cands.clone(),
            np_hp,
            o,
            round0.as_deref(),
        );
        add_correction(&mut c, train, o, np_cv.as_ref());
        c
    };
    // No effect asked for (a geometric fit only): nothing to choose between.
    let policy = if opt.max_effects == 0 {
        Policy::Single
    } else {
        opt.policy
    };
    let (mut chain, policy_choice) = match policy {
        Policy::Single => (single(opt), None),
        Policy::Best => {
            let pf = Options {
                min_np_ratio: 0.0,
                max_effects: opt.physics_first_max_effects,
                ..opt.clone()
            };
            let (kb, pf) = rayon::join(|| single(opt), || single(&pf));
            let label = |c: &Chain| c.steps.iter().map(|s| s.evidence.label.clone()).collect();
            let use_pf = pf.cv_rms < (1.0 - opt.policy_margin) * kb.cv_rms;
            tracing::debug!(
                "policy: CV RMS kernel benchmark {:.4}, physics first {:.4}",
                kb.cv_rms,
                pf.cv_rms
            );
            let mut choice = PolicyChoice {
                chosen: if use_pf {
                    "physics first"
                } else {
                    "kernel benchmark"
                },
                cv_rms_kernel_benchmark: kb.cv_rms,
                cv_rms_physics_first: pf.cv_rms,
                margin: opt.policy_margin,
                other_chain: Vec::new(),
                physics_first_stopped: pf.stopped.clone(),
                cv_rms_geometric: None,
                dropped_chain: Vec::new(),
            };
            let (keep, other) = if use_pf { (pf, kb) } else { (kb, pf) };
            choice.other_chain = label(&other);
            if other.pending.is_some() {
                choice.other_chain.push("nonparametric".into());
            }
            // Neither chain predicts the training poses' time blocks better than the
            // geometric fit alone (e.g. poses in separate regions of the workspace, each
            // block outside the others' ranges): keep the geometric fit, with its
            // correction if one passes.
            let cv_geometric = model_cv_rms(&geometric, train, opt.n_folds);
            let beats = keep.cv_rms.partial_cmp(&cv_geometric) == Some(std::cmp::Ordering::Less);
            if !keep.steps.is_empty() && !beats {
                let alone = single(&Options {
                    max_effects: 0,
                    ..opt.clone()
                });
                choice.dropped_chain = label(&keep);
                choice.other_chain = label(&other);
                choice.chosen = "geometric fit alone";
                choice.cv_rms_geometric = Some(cv_geometric);
                (alone, Some(choice))
            } else {
                (keep, Some(choice))
            }
        }
    };
    // The kept chain's transmission error maps, then its correction re-validated on what
    // the maps leave (at the setting chosen before them: one kernel system per fold instead
    // of the whole grid).
    if add_transmission_map(&mut chain, train, heldout, opt) {
        if let Some(p) = chain.pending.take() {
            let (qs, rv) = np_data(&chain.state, train);
            let fo = folds(train, opt.n_folds);
            let kept = nonparam::cv_fixed(&qs, &rv, &fo, opt.n_folds, p.length_scale, p.lambda)
                .filter(|&(b, a)| a < (1.0 - opt.nonparam_min_gain) * b);
            chain.pending = kept.map(|(b, a)| nonparam::RbfCv {
                cv_rms_before: b,
                cv_rms_after: a,
                ..p
            });
        }
    }
    fit_correction(&mut chain, train, heldout);
    let Chain {
        state,
        mut steps,
        rounds,
        not_identifiable,
        nonparametric,
        transmission_map,
        extrapolating,
        ..
    } = chain;
    let (ambiguous_heldout, mut warnings) = ambiguous(&steps, train, heldout);
    warnings.extend(extrapolating);
    if !undetermined.is_empty() {
        warnings.push(format!(
            "{} geometric parameter(s) held near their nominal values by the prior (±{} mm, ±{}°): the training poses alone do not determine them ({}). Poses that move these joints independently of the others, over more of the workspace, would determine them",
            undetermined.len(),
            opt.geometric_tolerance.map_or(f64::NAN, |t| t.mm),
            opt.geometric_tolerance.map_or(f64::NAN, |t| t.deg),
            undetermined
                .iter()
                .map(|u| format!("{}: {}", u.name, u.reason))
                .collect::<Vec<_>>()
                .join("; ")
        ));
    }
    let outside = effects::JointRange::of(train)
        .and_then(|r| effects::Outside::count(&r, heldout.iter().map(|o| &o.ctx)));
    warnings.extend(outside.as_ref().map(effects::Outside::warning));
    // Held-out RMS never counts an ambiguous pose: recompute every held-out figure on the
    // poses whose side of each change point is known.
    let scored: Vec<PoseObs> = heldout
        .iter()
        .filter(|o| !is_ambiguous(&ambiguous_heldout, o))
        .cloned()
        .collect();
    let n_heldout_excluded = heldout.len() - scored.len();
    let heldout = &scored[..];
    if n_heldout_excluded > 0 {
        let mut prev = &geometric;
        for st in steps.iter_mut() {
            st.heldout_rms_before = heldout_rms(prev, heldout, train);
            st.heldout_rms_after = heldout_rms(&st.state_after, heldout, train);
            prev = &st.state_after;
        }
    }
    let train_rms_final = rms3(&residuals(&state, train));
    let heldout_rms_geometric = heldout_rms(&geometric, heldout, train);
    let heldout_rms_final = heldout_rms(&state, heldout, train);
    let neighbours = region::Neighbours::new(train, heldout, region::NEIGHBOURS);
    let near = |st: &State| {
        neighbours
            .as_ref()
            .and_then(|n| n.rms(&region::per_pose_err2(&residuals(st, train))))
    };
    let near_heldout = match (near(&geometric), near(&state)) {
        (Some(g), Some(f)) => neighbours.as_ref().map(|n| region::NearHeldout {
            neighbours: region::NEIGHBOURS,
            geometric_mm: g,
            final_mm: f,
            heldout_spacing_deg: n.heldout_spacing.to_degrees(),
            train_spacing_deg: n.train_spacing.to_degrees(),
        }),
        _ => None,
    };
    let overfit = overfit_warnings(&steps, near);
    let final_gap = heldout_rms_final.is_some_and(|h| {
        gap_beyond(h, train_rms_final) || near_heldout.is_some_and(|n| gap_beyond(h, n.final_mm))
    });
    let gap_note = match (&near_heldout, heldout_rms_geometric, heldout_rms_final) {
        (Some(n), Some(g), Some(f)) if final_gap || !overfit.is_empty() => {
            Some(n.sentence(g, f, OVERFIT_GAP))
        }
        _ => None,
    };
    warnings.extend(overfit);
    warnings.extend(gap_note);
    if !ambiguous_heldout.is_empty() {
        warnings.push(format!(
            "{} held-out pose(s) lie between the last training pose before and the first after a base shift: which side of the step they are on is unknown (listed in ambiguous_heldout, predicted with the step placed half-way, and left out of the held-out RMS)",
            ambiguous_heldout.len()
        ));
    }
    Ok(Diagnosis {
        ambiguous_heldout,
        warnings,
        outside,
        undetermined,
        heldout_rms_nominal: heldout_rms(&nominal, heldout, train),
        heldout_rms_geometric,
        heldout_rms_final,
        near_heldout,
        train_rms_nominal,
        train_rms_geometric,
        train_rms_final,
        n_train: train.len(),
        n_heldout: heldout.len(),
        n_heldout_excluded,
        nominal,
        geometric,
        state,
        steps,
        rounds,
        not_identifiable,
        nonparametric,
        transmission_map,
        untestable,
        policy_choice,
    })
}

/// Whether held-out RMS `h` is beyond the overfitting limit above the reference RMS `t`
/// (more than [`OVERFIT_GAP`] and more than [`OVERFIT_MIN_MM`] above it).
fn gap_beyond(h: f64, t: f64) -> bool {
    h > (1.0 + OVERFIT_GAP) * t && h - t > OVERFIT_MIN_MM
}

/// Steps whose held-out RMS exceeds their training RMS by more than [`OVERFIT_GAP`] (and by
/// more than 0.01 mm): the fit learned the training poses, not the robot. With `near` (the
/// training RMS near the held-out poses of a model, [`region`]), the held-out RMS is judged
/// against it instead: a step whose held-out poses are only as far above the training poses
/// beside them is not flagged (one line names those steps: the held-out poses lie where the
/// model is less accurate), and a step whose held-out poses are beyond the limit above their
/// neighbours is, whatever its plain gap.
pub fn overfit_warnings(steps: &[Step], near: impl Fn(&State) -> Option<f64>) -> Vec<String> {
    let mut out = Vec::new();
    let mut region_only: Vec<(String, f64, f64)> = Vec::new();
    for s in steps {
        let Some(h) = s.heldout_rms_after else {
            continue;
        };
        let t = s.train_rms_after;
        let m = near(&s.state_after);
        let plain = gap_beyond(h, t);
        let flagged = m.map_or(plain, |m| gap_beyond(h, m));
        let label = s.effect.block.label();
        if flagged {
            let near_part = m
                .map(|m| {
                    format!(
                        " and {:.0} % above the training poses nearest the held-out ones ({m:.4} mm)",
                        100.0 * (h / m - 1.0)
                    )
                })
                .unwrap_or_default();
            out.push(format!(
                "overfitting: after {label} the held-out RMS {h:.4} mm is {:.0} % above the training RMS {t:.4} mm{near_part} (limit {:.0} %): trust the held-out figure",
                100.0 * (h / t - 1.0),
                100.0 * OVERFIT_GAP
            ));
        } else if plain {
            region_only.push((
                label,
                100.0 * (h / t - 1.0),
                100.0 * (h / m.unwrap_or(t) - 1.0),
            ));
        }
    }
    if !region_only.is_empty() {
        let list: Vec<String> = region_only
            .iter()
            .map(|(l, a, b)| format!("{l} ({a:+.0} % / {b:+.0} %)"))
            .collect();
        out.push(format!(
            "not overfitting: after {} the held-out RMS is more than {:.0} % above the training RMS, but not that far above the training poses nearest the held-out ones (gap against all training poses / against the nearest ones): the held-out poses lie where the model is less accurate than on average",
            list.join(", "),
            100.0 * OVERFIT_GAP
        ));
    }
    out
}

/// The evidence of one score in file form.
pub fn evidence(s: &Score) -> schema::Evidence {
    schema::Evidence {
        candidate: s.label.clone(),
        kind: s.block.kind().into(),
        joint: s.block.joint(),
        df: Some(s.df),
        f: fin(s.f),
        p_value: fin(s.p_value),
        tests: Some(s.tests),
        delta_bic: fin(s.delta_bic),
        cv_gain: fin(s.cv_gain),
        independence: fin(s.independence),
        np_ratio: fin(s.np_ratio),
    }
}

fn ofin(v: Option<f64>) -> Option<f64> {
    v.and_then(fin)
}

impl Diagnosis {
    /// `diagnosis.json` content ([`schema::DiagnosisFile`]).
    pub fn to_file(&self) -> schema::DiagnosisFile {
        let effects = self
            .steps
            .iter()
            .map(|s| schema::DiagnosedEffect {
                kind: s.effect.block.kind().into(),
                joint: s.effect.block.joint(),
                label: s.evidence.label.clone(),
                parameters: s.effect.parameters(),
                evidence: evidence(&s.evidence),
                train_rms_mm_before: fin(s.train_rms_before),
                train_rms_mm_after: fin(s.train_rms_after),
                heldout_rms_mm_before: ofin(s.heldout_rms_before),
                heldout_rms_mm_after: ofin(s.heldout_rms_after),
                train_rms_px_before: None,
                train_rms_px_after: None,
                heldout_rms_px_before: None,
                heldout_rms_px_after: None,
                hand_eye_change_mm: None,
                hand_eye_change_deg: None,
                calibration: s.effect.to_cal(),
            })
            .collect();
        schema::DiagnosisFile {
            format: schema::DIAGNOSIS_FORMAT.into(),
            sensor: schema::DiagnosisSensor::Kinematic,
            residual: "3-D marker point error (mm)".into(),
            n_train: self.n_train,
            n_heldout: self.n_heldout,
            n_heldout_excluded: self.n_heldout_excluded,
            train_rms: schema::StageRms {
                nominal_mm: fin(self.train_rms_nominal),
                base_model_mm: fin(self.train_rms_geometric),
                final_mm: fin(self.train_rms_final),
                ..Default::default()
            },
            heldout_rms: schema::StageRms {
                nominal_mm: ofin(self.heldout_rms_nominal),
                base_model_mm: ofin(self.heldout_rms_geometric),
                final_mm: ofin(self.heldout_rms_final),
                ..Default::default()
            },
            train_rms_near_heldout: self.near_heldout.map(|n| schema::NearHeldoutRms {
                neighbours: n.neighbours,
                heldout_spacing_deg: fin(n.heldout_spacing_deg),
                train_spacing_deg: fin(n.train_spacing_deg),
                base_model_mm: fin(n.geometric_mm),
                final_mm: fin(n.final_mm),
            }),
            effects,
            nonparametric_used: self.nonparametric.is_some(),
            rounds: self
                .rounds
                .iter()
                .map(|r| r.iter().map(evidence).collect())
                .collect(),
            not_identifiable: self.not_identifiable.iter().map(evidence).collect(),
            untestable: self
                .untestable
                .iter()
                .map(|(a, b)| schema::Untestable {
                    effect: a.clone(),
                    reason: b.clone(),
                })
                .collect(),
            ambiguous_heldout: self.ambiguous_heldout.clone(),
            warnings: self.warnings.clone(),
            hand_eye_before: None,
            hand_eye_after: None,
        }
    }

    /// Effects in calibration-file form.
    pub fn cal_effects(&self) -> Vec<crate::dataset::CalEffect> {
        self.state.effects.iter().map(Effect::to_cal).collect()
    }

    /// Human report (Markdown).
    pub fn report_md(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let f = |v: Option<f64>| v.map(|x| format!("{x:.4}")).unwrap_or_else(|| "—".into());
        let _ = writeln!(s, "# Residual diagnosis\n");
        let _ = writeln!(
            s,
            "{} training poses, {} held-out poses. RMS = 3-D point error (mm).\n",
            self.n_train, self.n_heldout
        );
        if self.n_heldout_excluded > 0 {
            let _ = writeln!(
                s,
                "{} held-out pose(s) between the training poses around a base shift are left out of the held-out RMS (listed in diagnosis.json `ambiguous_heldout`).\n",
                self.n_heldout_excluded
            );
        }
        if let Some(o) = &self.outside {
            let _ = writeln!(s, "{}.\n", o.warning());
        }
        if !self.undetermined.is_empty() {
            let _ = writeln!(
                s,
                "Geometric parameters the training poses do not determine, held near their nominal values by the prior (add poses that move these joints independently, over more of the workspace):\n"
            );
            for u in &self.undetermined {
                let _ = writeln!(s, "- {}: {}", u.name, u.reason);
            }
            let _ = writeln!(s);
        }
        let _ = writeln!(s, "| model | train RMS | held-out RMS |\n|---|---|---|");
        let _ = writeln!(
            s,
            "| nominal (base + tool fitted) | {:.4} | {} |",
            self.train_rms_nominal,
            f(self.heldout_rms_nominal)
        );
        let _ = writeln!(
            s,
            "| geometric (all identifiable kinematic parameters) | {:.4} | {} |",
            self.train_rms_geometric,
            f(self.heldout_rms_geometric)
        );
        let _ = writeln!(
            s,
            "| final (geometric + effects) | {:.4} | {} |\n",
            self.train_rms_final,
            f(self.heldout_rms_final)
        );
        if let Some(line) = self.near_heldout_line() {
            let _ = writeln!(s, "{line}\n");
        }
        let _ = writeln!(s, "## Chain\n");
        if let Some(line) = self.policy_line() {
            let _ = writeln!(s, "{}\n", line.replacen("policy: k", "K", 1));
        }
        if self.steps.is_empty() {
            let _ = writeln!(s, "No effect was added: no candidate explained a significant part of the residual (Bonferroni α over the candidate count, ΔBIC, cross-validated gain).\n");
        }
        for (i, st) in self.steps.iter().enumerate() {
            let e = &st.evidence;
            let _ = writeln!(
                s,
                "{}. train RMS {:.4} mm → **{}** → {:.4} mm; held-out {} → {} mm",
                i + 1,
                st.train_rms_before,
                e.label,
                st.train_rms_after,
                f(st.heldout_rms_before),
                f(st.heldout_rms_after)
            );
            if matches!(st.effect.block, Block::Nonparametric(_)) {
                let _ = writeln!(s, "   - evidence: kernel regression on joint space, CV gain {:.1} % (time-blocked folds)", 100.0 * e.cv_gain);
            } else if matches!(st.effect.block, Block::TransmissionMap(_)) {
                let _ = writeln!(s, "   - {}", st.effect.sentence());
                if let (Some(m), Block::TransmissionMap(b)) =
                    (&self.transmission_map, &st.effect.block)
                {
                    let sd: Vec<f64> = (0..=100)
                        .filter_map(|i| {
                            m.curve(b.joint, b.lo + (b.hi - b.lo) * f64::from(i) / 100.0)
                        })
                        .map(|(_, sd)| sd)
                        .collect();
                    let rms_sd =
                        (sd.iter().map(|x| x * x).sum::<f64>() / sd.len().max(1) as f64).sqrt();
                    let _ = writeln!(s, "   - stated uncertainty of this curve: σ {:.1} arcsec RMS over its range (joints that move together in the poses trade their maps: a large σ says the poses do not tell them apart)", rms_sd.to_degrees() * 3600.0);
                }
                if let Some(m) = &self.transmission_map {
                    let _ = writeln!(s, "   - evidence (the maps of joints {:?} together): ridge regression through the joint-angle columns, joints added while they lower the cross-validated error, {} harmonics and ridge {:.0e} chosen by time-blocked cross-validation over {} settings; CV RMS of the chain's residual {:.4} → {:.4} mm (gain {:.1} %), in-fold {:.4} mm; the {} coefficients and their standard deviations are in calibration.json", m.chosen.joints, m.chosen.harmonics, m.chosen.ridge, m.grid.len(), m.cv_rms_before, m.chosen.cv_rms, 100.0 * e.cv_gain, m.chosen.fit_rms, st.effect.coefs.len());
                }
            } else {
                let _ = writeln!(s, "   - evidence: F = {:.1} (df {}), p = {:.2e} over {} test(s), ΔBIC = {:.1}, CV gain {:.1} %, independence from the geometric model {:.2}", e.f, e.df, e.p_value, e.tests, e.delta_bic, 100.0 * e.cv_gain, e.independence);
                for ((n, v), sd) in st
                    .effect
                    .block
                    .param_names()
                    .iter()
                    .zip(&st.effect.coefs)
                    .zip(&st.effect.std)
                {
                    let _ = writeln!(
                        s,
                        "   - {n} = {v:.4e} ± {:.1e} (95 %: {:.4e} … {:.4e})",
                        1.96 * sd,
                        v - 1.96 * sd,
                        v + 1.96 * sd
                    );
                }
            }
        }
        let _ = writeln!(s);
        if !self.found_physical() && self.nonparametric.is_some() {
            let _ = writeln!(s, "**No physical effect was identified.** The residual is structured (a kernel regression on joint space predicts held-out folds {:.1} % better than zero), but no effect of the library explains it; a `nonparametric` correction was used instead. Inspect the data for an effect the library does not contain.\n", 100.0 * (1.0 - self.nonparametric.map(|(a, b)| b / a).unwrap_or(1.0)));
            if let Some(x) = self
                .rounds
                .last()
                .and_then(|r| r.iter().find(|x| x.np_ratio.is_finite()))
            {
                let _ = writeln!(s, "The best library candidate, {}, explains only {:.0} % of what the kernel regression explains (ΔBIC {:.1}): it correlates with the residual but does not account for it.\n", x.label, 100.0 * x.np_ratio, x.delta_bic);
            }
        } else if self.nonparametric.is_some() {
            let _ = writeln!(s, "Structured residual remained after the physical effects; no further library effect explained it, so a `nonparametric` correction was added.\n");
        }
        if !self.not_identifiable.is_empty() {
            let _ = writeln!(s, "## Significant but not identifiable with this data\n");
            for x in &self.not_identifiable {
                let _ = writeln!(s, "- {}: ΔBIC {:.1}, but independence from the geometric model only {:.3}: the geometric parameters absorb it. Excite it with more varied poses (see effects.md §5.3).", x.label, x.delta_bic, x.independence);
            }
            let _ = writeln!(s);
        }
        if let Some(r0) = self.rounds.first() {
            let absorbed: Vec<&Score> = r0.iter().filter(|x| x.independence < 0.1).collect();
            if !absorbed.is_empty() {
                let _ = writeln!(
                    s,
                    "## Absorbed by the geometric parameters (cannot be detected from this data)\n"
                );
                for x in absorbed {
                    let hint = if matches!(x.block, Block::TrackerScale(_)) {
                        " A tracker scale error is collinear with scaling every link length: the calibration reproduces the scaled readings and is wrong by the scale in absolute terms. Only an independent length standard (calibrated bar, CMM artefact) in the data can reveal it."
                    } else {
                        ""
                    };
                    let _ = writeln!(
                        s,
                        "- {}: independence {:.3}.{hint}",
                        x.label, x.independence
                    );
                }
                let _ = writeln!(s);
            }
        }
        if !self.untestable.is_empty() {
            let _ = writeln!(s, "## Not testable on this data\n");
            for (a, b) in &self.untestable {
                let _ = writeln!(s, "- {a}: {b}");
            }
            let _ = writeln!(s);
        }
        for (k, round) in self.rounds.iter().enumerate() {
            let _ = writeln!(
                s,
                "## Round {} candidates (top 8 by ΔBIC){}\n",
                k + 1,
                if k == 0 {
                    ", after the geometric fit"
                } else {
                    ""
                }
            );
            let _ = writeln!(s, "| candidate | df | F | p | tests | ΔBIC | CV gain | independence | vs kernel benchmark |\n|---|---|---|---|---|---|---|---|---|");
            for x in round.iter().take(8) {
                let _ = writeln!(
                    s,
                    "| {} | {} | {:.2} | {:.2e} | {} | {:.1} | {:.2} % | {:.3} | {} |",
                    x.label,
                    x.df,
                    x.f,
                    x.p_value,
                    x.tests,
                    x.delta_bic,
                    100.0 * x.cv_gain,
                    x.independence,
                    if x.np_ratio.is_finite() {
                        format!("{:.2}", x.np_ratio)
                    } else {
                        "—".into()
                    }
                );
            }
            let _ = writeln!(s);
        }
        s
    }
}

/// Stacked residual of `state` as 3-vectors per observation.
pub fn residual_vectors(state: &State, obs: &[PoseObs]) -> Vec<Vector3<f64>> {
    let r: DVector<f64> = residuals(state, obs);
    (0..obs.len())
        .map(|k| Vector3::new(r[3 * k], r[3 * k + 1], r[3 * k + 2]))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;
    use std::sync::Arc;

    /// The columns a candidate is scored with are the problem's own Jacobian: each matches
    /// the central finite difference of the prediction in that coefficient (at zero, on top
    /// of an already fitted effect), for a candidate of every kind.
    /// Joints 1 and 4–6 held still: every mass point of `joint_compliance(j2)` downstream of
    /// joint 3 rides one rigid body, so their moments span at most four functions of
    /// `q2, q3` (fewer once the model's joint offsets are projected out) and the block cannot
    /// tell its points apart: it is pruned to a conditioned subset. With every joint moving
    /// it keeps more points.
    #[test]
    fn compliance_keeps_only_mass_points_the_poses_tell_apart() {
        let mut model = KinematicModel::preset("ur5e").unwrap();
        model.fix_point_redundancies();
        let poses = |all: bool| -> Vec<PoseObs> {
            (0..150)
                .map(|k| {
                    let f = k as f64;
                    let q: Vec<f64> = (0..6)
                        .map(|i| {
                            if all || i == 1 || i == 2 {
                                1.2 * ((f + 1.0) * (i as f64 + 1.3)).sin()
                            } else {
                                0.3 * i as f64
                            }
                        })
                        .collect();
                    PoseObs::at(k, f, q.clone(), model.measured_point(&q))
                })
                .collect()
        };
        let state = State {
            prior: None,
            model: model.clone(),
            effects: vec![],
        };
        let full = effects::mass_points(&model, 2);
        assert!(full.len() > 2, "{full:?}");
        let n_kept = |obs: &[PoseObs]| {
            let mut c = vec![vec![Block::Compliance(effects::Compliance {
                joint: 2,
                points: full.clone(),
            })]];
            prune_mass_points(&state, obs, &mut c);
            let Block::Compliance(effects::Compliance { points, .. }) = &c[0][0] else {
                unreachable!()
            };
            assert!(points.iter().all(|p| full.contains(p)));
            let (_, j) = stack(&state, obs);
            let g = candidate_columns(&state, obs, &c[0]).pop().unwrap();
            let cond = block_conditioning(&orth_basis(&j), &g);
            assert!(
                points.len() == 1 || cond >= MIN_BLOCK_CONDITIONING,
                "{cond}"
            );
            points.len()
        };
        let narrow = n_kept(&poses(false));
        let wide = n_kept(&poses(true));
        println!(
            "mass points kept: {narrow} (joints 2, 3 move), {wide} (all move) of {}",
            full.len()
        );
        assert!(narrow < full.len(), "{narrow} of {}", full.len());
        assert!(wide > narrow, "wide {wide}, narrow {narrow}");
    }

    #[test]
    fn candidate_columns_are_the_problem_jacobian() {
        let mut model = KinematicModel::preset("denso-vs060").unwrap();
        model.fix_point_redundancies();
        let obs = test_obs(&model, 12);
        let mut fitted = Effect::zero(Block::Backlash(effects::Backlash { joint: 3 }));
        fitted.coefs = vec![2e-4];
        let state = State {
            prior: None,
            model: model.clone(),
            effects: vec![fitted],
        };
        let (mut blocks, _) = candidates(&model, &obs);
        let mut all: Vec<Block> = blocks.iter_mut().map(|g| g.remove(0)).collect();
        all.push(Block::Latency(effects::Latency));
        all.push(Block::BaseShift(effects::BaseShift { t_change: 1500.0 }));
        let cols = candidate_columns(&state, &obs, &all);
        let mut worst = 0.0f64;
        for (b, g) in all.iter().zip(&cols) {
            for c in 0..b.n_params() {
                // Central differences: truncation ~h², round-off ~1e-13·|p|/h (p ~ 1 m).
                let h = 1e-5;
                let at = |v: f64| {
                    let mut st = state.clone();
                    let mut e = Effect::zero(b.clone());
                    e.coefs[c] = v;
                    st.effects.push(e);
                    -fit::residuals(&st, &obs)
                };
                let fd = (at(h) - at(-h)) / (2.0 * h);
                // A joint whose axis passes through the marker has a zero column: compare
                // against 1e-6 mm there (round-off of the analytic column is ~1e-13 mm).
                let err = (&fd - g.column(c)).norm() / fd.norm().max(1e-6);
                assert!(
                    err < 1e-5,
                    "{} column {c}: relative error {err:.2e}",
                    b.label()
                );
                worst = worst.max(err);
            }
        }
        println!(
            "candidate columns of {} blocks vs finite differences: worst relative error {worst:.2e}",
            all.len()
        );
    }

    /// A library effect is refitted by the kinematic identification too (`solve::identify`,
    /// the `calibrate` path, on the same LM) through [`effects::LibraryEffect`]: its
    /// correction Jacobian matches finite differences for a block of every kind, and a
    /// backlash of 0.02° on joint 2 is recovered from data that carries it.
    #[test]
    fn library_effect_refits_in_the_kinematic_identification() {
        use crate::solve::kinematics::{identify_obs, Effect as KinEffect, IdentOptions};
        use effects::LibraryEffect;
        use nalgebra::Matrix3xX;
        let model = KinematicModel::preset("denso-vs060").unwrap();
        let truth_b = 0.02f64.to_radians();
        let mut truth = Effect::zero(Block::Backlash(effects::Backlash { joint: 2 }));
        truth.coefs = vec![truth_b];
        let mut noise = lcg_noise(11, 0.01);
        let mut pose = |k: u64| {
            let f = k as f64;
            let q = test_joints(f, 0.9, 1.7);
            let mut o = PoseObs::at(k, 30.0 * f, q, Point3::origin());
            o.ctx.approach = test_approach(k);
            o.ctx.temp_c = Some(20.0 + 0.05 * f);
            o.ctx.qd = Some(vec![0.05; 6]);
            let p = effects::apply_effects(&model, std::slice::from_ref(&truth), &o.ctx);
            o.p = p + Vector3::new(noise(), noise(), noise());
            o
        };
        let train: Vec<PoseObs> = (0..80).map(&mut pose).collect();
        let held: Vec<PoseObs> = (80..100).map(&mut pose).collect();
        // Jacobian of the correction for a block of every kind, at nonzero coefficients.
        let (groups, _) = candidates(&model, &train);
        let mut worst = 0.0f64;
        for b in groups
            .iter()
            .map(|g| g[0].clone())
            .chain([Block::Latency(effects::Latency)])
        {
            let le = LibraryEffect::new(b.clone());
            let th: Vec<f64> = (0..b.n_params()).map(|k| 1e-4 * (k as f64 + 1.0)).collect();
            let o = &train[5];
            let mut j = Matrix3xX::zeros(th.len());
            le.point_correction(&model, o, &th, Some(&mut j));
            for c in 0..th.len() {
                let h = 1e-6;
                let (mut tp, mut tm) = (th.clone(), th.clone());
                tp[c] += h;
                tm[c] -= h;
                let fd = (le.point_correction(&model, o, &tp, None)
                    - le.point_correction(&model, o, &tm, None))
                    / (2.0 * h);
                let err = (fd - j.column(c)).norm() / fd.norm().max(1e-3);
                assert!(err < 1e-4, "{} column {c}: {err:.2e}", b.label());
                worst = worst.max(err);
            }
        }
        let opts = IdentOptions {
            effects: vec![Arc::new(LibraryEffect::new(Block::Backlash(
                effects::Backlash { joint: 2 },
            )))],
            kfold: 0,
            ..Default::default()
        };
        let res = identify_obs(&model, train, held, None, vec![], &opts).unwrap();
        let b = res.effect_values[0][0];
        println!(
            "LibraryEffect: worst FD error {worst:.2e}; identify recovers backlash j2 {:.5}° (truth {:.5}°)",
            b.to_degrees(),
            truth_b.to_degrees()
        );
        assert!((b - truth_b).abs() < 0.05 * truth_b, "{b} vs {truth_b}");
    }

    /// One joint carrying transmission ripple at two harmonics (×5 and ×17, as the real
    /// UR10's joints show lines at 14–20 cycles per turn): both are found, one after the
    /// other, on the same joint, and the held-out error falls to the noise. The joints
    /// sweep ±170°: over a narrow range (±80° was tried) neighbouring harmonics are far from
    /// orthogonal and the greedy chain takes ×4 + eccentricity for the ×5.
    /// A true gear ripple of `joint` at `harmonic` cycles per turn, `sin_deg sin kq +
    /// cos_deg cos kq` (degrees).
    fn ripple(joint: usize, harmonic: u32, sin_deg: f64, cos_deg: f64) -> Effect {
        Effect {
            block: Block::Ripple(effects::Ripple { joint, harmonic }),
            coefs: vec![sin_deg.to_radians(), cos_deg.to_radians()],
            std: vec![f64::NAN; 2],
            tau_std: f64::NAN,
        }
    }

    #[test]
    fn several_ripple_harmonics_on_one_joint_are_found() {
        let mut model = KinematicModel::preset("denso-vs060").unwrap();
        model.fix_point_redundancies();
        let truth = [ripple(2, 5, 0.012, -0.006), ripple(2, 17, 0.004, 0.008)];
        let mut noise = lcg_noise(5, 0.01);
        let mut pose = |k: u64| {
            let f = k as f64;
            let q = test_joints(f, 3.0, 1.37);
            let mut o = PoseObs::at(k, 20.0 * f, q, Point3::origin());
            o.p = effects::apply_effects(&model, &truth, &o.ctx)
                + Vector3::new(noise(), noise(), noise());
            o
        };
        let train: Vec<PoseObs> = (0..400).map(&mut pose).collect();
        let held: Vec<PoseObs> = (400..500).map(&mut pose).collect();
        let d = diagnose(
            &model,
            &train,
            &held,
            &Options {
                allow_nonparametric: false,
                ..Options::default()
            },
        )
        .unwrap();
        let mut found: Vec<String> = d.steps.iter().map(|s| s.effect.block.label()).collect();
        found.sort();
        println!(
            "found {found:?}; held-out {:.4} → {:.4} mm",
            d.heldout_rms_geometric.unwrap(),
            d.heldout_rms_final.unwrap()
        );
        assert_eq!(
            found,
            vec![
                "transmission_ripple(j2, ×17)",
                "transmission_ripple(j2, ×5)"
            ],
            "{}",
            d.report_md()
        );
        assert!(d.heldout_rms_final.unwrap() < 0.015);
    }

    /// A gear ripple of joint 2 and noise of 0.01 mm where q1 < 0, 0.06 mm where q1 > 0; the
    /// held-out poses all have q1 > 0. Against all training poses the held-out RMS is far
    /// above the 15 % limit; against the training poses nearest them it is not: the ripple's
    /// step is named "not overfitting", never flagged, and the warning says the held-out poses
    /// lie where the model is less accurate.
    #[test]
    fn a_gap_from_where_the_heldout_poses_lie_is_told_apart_from_overfitting() {
        let mut model = KinematicModel::preset("denso-vs060").unwrap();
        model.fix_point_redundancies();
        // A gear ripple the chain finds, so that its step is judged as well.
        let truth = [ripple(2, 17, 0.01, 0.006)];
        let mut noise = lcg_noise(11, 1.0);
        let mut pose = |k: u64| {
            let f = k as f64;
            let q = test_joints(f, 1.2, 0.61);
            let amp = if q[0] < 0.0 { 0.01 } else { 0.06 } * 3f64.sqrt();
            let mut o = PoseObs::at(k, f, q, Point3::origin());
            o.p = effects::apply_effects(&model, &truth, &o.ctx)
                + amp * Vector3::new(noise(), noise(), noise());
            o
        };
        let train: Vec<PoseObs> = (0..600).map(&mut pose).collect();
        let held: Vec<PoseObs> = (600..1400)
            .map(&mut pose)
            .filter(|o| o.ctx.q[0] > 0.2)
            .take(150)
            .collect();
        assert!(held.len() >= 100, "{}", held.len());
        let d = diagnose(&model, &train, &held, &Options::default()).unwrap();
        let h = d.heldout_rms_final.unwrap();
        let n = d.near_heldout.expect("near_heldout");
        println!(
            "train {:.4}, held-out {h:.4}, near {:.4} mm; chain {:?}",
            d.train_rms_final,
            n.final_mm,
            d.steps
                .iter()
                .map(|s| s.evidence.label.clone())
                .collect::<Vec<_>>()
        );
        assert!(h > 1.3 * d.train_rms_final, "{h} vs {}", d.train_rms_final);
        assert!((h / n.final_mm - 1.0).abs() < 0.15, "{h} vs {}", n.final_mm);
        let w = d.warnings.join("\n");
        assert!(
            w.contains("as well as the training poses beside them"),
            "{w}"
        );
        // The ripple's step: beyond the limit against all training poses, not against the
        // nearest ones; named once as not overfitting, never flagged.
        assert!(
            d.steps
                .iter()
                .any(|s| s.effect.block.label() == "transmission_ripple(j2, ×17)"),
            "{}",
            d.report_md()
        );
        assert!(
            w.contains("not overfitting: after transmission_ripple(j2, ×17)"),
            "{w}"
        );
        assert!(
            !d.warnings.iter().any(|x| x.starts_with("overfitting")),
            "{w}"
        );
        let file = d.to_file();
        let near = file.train_rms_near_heldout.as_ref().unwrap();
        assert_eq!(near.neighbours, region::NEIGHBOURS);
        assert!((near.final_mm.unwrap() - n.final_mm).abs() < 1e-12);
        let text = serde_json::to_string(&file).unwrap();
        let back: schema::DiagnosisFile = serde_json::from_str(&text).unwrap();
        assert_eq!(back.train_rms_near_heldout, file.train_rms_near_heldout);
        assert!(d.report_md().contains("Where the held-out poses are"));
    }

    /// A base shift at t = 601 s; training poses every 10 s, held-out poses every 40 s plus
    /// two at 602 s and 608 s, between the training poses around the step (600 s, 610 s):
    /// which side of the step they are on cannot be known from the training data. They are
    /// listed, and every held-out RMS is computed without them.
    #[test]
    fn ambiguous_heldout_poses_are_listed_and_left_out_of_the_heldout_rms() {
        let mut model = KinematicModel::preset("denso-vs060").unwrap();
        model.fix_point_redundancies();
        let shift = Effect {
            block: Block::BaseShift(effects::BaseShift { t_change: 601.0 }),
            coefs: vec![0.4, -0.3, 0.35, 3e-4, -2e-4, 2.5e-4],
            std: vec![f64::NAN; 6],
            tau_std: f64::NAN,
        };
        let mut noise = lcg_noise(7, 0.02);
        let mut pose = |id: u64, t: f64| {
            let f = id as f64;
            let q = test_joints(f, 0.9, 1.7);
            let mut o = PoseObs::at(id, t, q, Point3::origin());
            let p = effects::apply_effects(&model, std::slice::from_ref(&shift), &o.ctx);
            o.p = p + Vector3::new(noise(), noise(), noise());
            o
        };
        let train: Vec<PoseObs> = (0..120).map(|k| pose(k, 10.0 * k as f64)).collect();
        let mut held: Vec<PoseObs> = (0..30)
            .map(|k| pose(1000 + k, 15.0 + 40.0 * k as f64))
            .collect();
        held.push(pose(2000, 602.0));
        held.push(pose(2001, 608.0));
        held.sort_by(|a, b| a.t.total_cmp(&b.t));
        let d = diagnose(&model, &train, &held, &Options::default()).unwrap();
        let kinds: Vec<&str> = d.steps.iter().map(|s| s.effect.block.kind()).collect();
        assert_eq!(kinds, vec!["base_shift"], "{}", d.report_md());
        let mut ids: Vec<u64> = d.ambiguous_heldout.iter().map(|a| a.id).collect();
        ids.sort();
        assert_eq!(ids, vec![2000, 2001]);
        assert_eq!((d.n_heldout, d.n_heldout_excluded), (30, 2));
        let scored: Vec<PoseObs> = held.iter().filter(|o| o.id < 2000).cloned().collect();
        let without = rms3(&residuals(&d.state, &scored));
        let with_all = rms3(&residuals(&d.state, &held));
        println!(
            "held-out RMS without the 2 ambiguous poses {without:.4} mm (reported {:.4}); with them {with_all:.4} mm",
            d.heldout_rms_final.unwrap()
        );
        assert!((d.heldout_rms_final.unwrap() - without).abs() < 1e-12);
        assert_eq!(d.steps[0].heldout_rms_after, d.heldout_rms_final);
        assert!(without < 0.05, "{without}");
        let f = d.to_file();
        assert_eq!((f.n_heldout, f.n_heldout_excluded), (30, 2));
        assert!(d.report_md().contains("2 held-out pose(s)"));
    }
}
