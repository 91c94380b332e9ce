//! Kinematic identification: arm (MDH + Hayati), base (tracker → robot base, 6) and tool
//! (flange → marker, 3 or 6) by Levenberg–Marquardt on the loop-closure equation of seed
//! 001 §2.2 (`P_measured = B · FK(q) · t`).
//!
//! - No user guess: base and tool are initialised in closed form from the nominal model
//!   ([`super::nominal`]).
//! - Identifiability is automatic ([`super::identifiability`]): parameters whose column
//!   of the column-scaled Jacobian is (numerically) a combination of columns kept before it
//!   are fixed, with the parameters they trade off with.
//! - Robust loss: Huber on the per-pose 3-D error (IRLS), the down-weighted poses are listed.
//! - Covariance `σ²(JᵀJ)⁻¹` of the free parameters gives each parameter's std.
//! - Extension point: an [`Effect`] contributes extra parameters and Jacobian columns
//!   (additive correction of the predicted marker point) — the diagnosis code adds
//!   compliance, backlash, … this way.
use std::sync::Arc;

use nalgebra::{DMatrix, DVector, Matrix3xX, Point3, UnitQuaternion, Vector3};

use super::identifiability::{self, Identifiability};
use super::lm::{self, LmOptions, LsqProblem, Termination};
use super::nominal;
use super::obs::{observations, PoseObs, Skipped, Split};
use super::{stats, SolveError};
use crate::dataset::Dataset;
use crate::model::{KinematicModel, ParamGroup, Unit};

/// A physical effect the geometric model lacks, contributing parameters and Jacobian
/// columns: the predicted marker point becomes `model.measured_point(q) + correction`.
pub trait Effect: Send + Sync + std::fmt::Debug {
    /// Effect kind (`joint_compliance`, `backlash`, ...).
    fn kind(&self) -> String;
    /// Names of its parameters (used in reports and the calibration file).
    fn param_names(&self) -> Vec<String>;
    /// Starting values (internal units).
    fn initial(&self) -> Vec<f64>;
    /// Additive correction (tracker frame, mm) of the predicted marker origin for `obs`,
    /// given the current kinematic `model` and effect parameters `theta`. When `jac` is
    /// given (3 × `theta.len()`), write `∂correction/∂theta` into it.
    fn point_correction(
        &self,
        model: &KinematicModel,
        obs: &PoseObs,
        theta: &[f64],
        jac: Option<&mut Matrix3xX<f64>>,
    ) -> Vector3<f64>;
}

/// Options of [`identify`].
#[derive(Debug, Clone)]
pub struct IdentOptions {
    /// Held-out dataset (all its usable pose records); default: the `validation` records
    /// of the training file, else k-fold cross-validation.
    pub heldout: Option<Dataset>,
    /// Huber threshold (mm) on the per-pose 3-D error; `None` = plain least squares.
    pub huber_mm: Option<f64>,
    /// Use marker orientations: tool gets 6 parameters and rotation residuals are added,
    /// weighted by `orientation_weight_mm_per_rad`.
    pub orientation: bool,
    pub orientation_weight_mm_per_rad: f64,
    /// Sine threshold of the identifiability test (see [`identifiability`]).
    pub identifiability_tol: f64,
    /// Parameter names to fix in addition to the automatic choice.
    pub fix: Vec<String>,
    /// Parameter names to free (if identifiable) in addition to the model defaults.
    pub free: Vec<String>,
    /// Number of folds when no held-out data exists (0 = no cross-validation).
    pub kfold: usize,
    pub lm: LmOptions,
    /// Extra effects (parameters + Jacobian columns).
    pub effects: Vec<Arc<dyn Effect>>,
}

impl Default for IdentOptions {
    fn default() -> Self {
        IdentOptions {
            heldout: None,
            huber_mm: None,
            orientation: false,
            orientation_weight_mm_per_rad: 50.0,
            identifiability_tol: identifiability::DEFAULT_TOL,
            fix: Vec::new(),
            free: Vec::new(),
            kfold: 5,
            lm: LmOptions::default(),
            effects: Vec::new(),
        }
    }
}

/// The identification problem: free model parameters (+ effect parameters) → residuals.
///
/// `x = [model values at free, effect params…]`; residuals per observation are
/// `√w_i · (predicted − measured)` (3 rows, mm), plus 3 rotation rows
/// `√w_i · s · log(R_pred R_measᵀ)` when `orientation` is `Some(s)`.
#[derive(Debug, Clone)]
pub struct KinProblem<'a> {
    pub model: KinematicModel,
    /// Indices (into `model.params()`) of the free parameters, in `x` order.
    pub free: Vec<usize>,
    pub obs: &'a [PoseObs],
    /// Per-observation weight (IRLS); `None` = all 1.
    pub weights: Option<Vec<f64>>,
    pub orientation: Option<f64>,
    pub effects: &'a [Arc<dyn Effect>],
}

impl<'a> KinProblem<'a> {
    /// A problem over the model's currently free parameters.
    pub fn new(model: KinematicModel, obs: &'a [PoseObs], effects: &'a [Arc<dyn Effect>]) -> Self {
        let free = model
            .params()
            .iter()
            .enumerate()
            .filter(|(_, p)| p.free)
            .map(|(i, _)| i)
            .collect();
        KinProblem {
            model,
            free,
            obs,
            weights: None,
            orientation: None,
            effects,
        }
    }

    fn n_effect(&self) -> usize {
        self.effects.iter().map(|e| e.param_names().len()).sum()
    }

    /// Rows per observation.
    pub fn rows_per_obs(&self) -> usize {
        if self.orientation.is_some() {
            6
        } else {
            3
        }
    }

    /// Current `x` (free model values, then effect initial values).
    pub fn x0(&self) -> DVector<f64> {
        let mut v: Vec<f64> = self
            .free
            .iter()
            .map(|&i| self.model.params()[i].value)
            .collect();
        for e in self.effects.iter() {
            v.extend(e.initial());
        }
        DVector::from_vec(v)
    }

    /// The model with `x` applied (effect parameters are not part of the model).
    pub fn model_at(&self, x: &DVector<f64>) -> KinematicModel {
        let mut m = self.model.clone();
        let mut all = m.param_values();
        for (k, &i) in self.free.iter().enumerate() {
            all[i] = x[k];
        }
        m.set_param_values(&all);
        m
    }

    /// Effect parameter slices of `x`.
    pub fn effect_params<'x>(&self, x: &'x DVector<f64>) -> Vec<&'x [f64]> {
        let mut off = self.free.len();
        self.effects
            .iter()
            .map(|e| {
                let n = e.param_names().len();
                let s = &x.as_slice()[off..off + n];
                off += n;
                s
            })
            .collect()
    }

    /// Predicted marker origin (with effects) for each observation.
    pub fn predict(&self, x: &DVector<f64>, obs: &[PoseObs]) -> Vec<Point3<f64>> {
        let m = self.model_at(x);
        let th = self.effect_params(x);
        obs.iter()
            .map(|o| {
                let mut p = m.measured_point(&o.q);
                for (e, t) in self.effects.iter().zip(&th) {
                    p += e.point_correction(&m, o, t, None);
                }
                p
            })
            .collect()
    }

    fn eval(&self, x: &DVector<f64>, want_j: bool) -> (DVector<f64>, Option<DMatrix<f64>>) {
        self.eval_sel(x, want_j, None)
    }

    /// Residuals of the observations `sel` (indices into `obs`, in that order; rows
    /// `rows_per_obs() · k` for the `k`-th index) at `x`, without building a sub-problem:
    /// the bootstrap's exactness check evaluates each subset this way.
    pub fn residuals_sel(&self, x: &DVector<f64>, sel: &[usize]) -> DVector<f64> {
        self.eval_sel(x, false, Some(sel)).0
    }

    /// As [`Self::residuals_sel`], with the Jacobian of those rows.
    pub fn residuals_jacobian_sel(
        &self,
        x: &DVector<f64>,
        sel: &[usize],
    ) -> (DVector<f64>, DMatrix<f64>) {
        let (r, j) = self.eval_sel(x, true, Some(sel));
        (r, j.unwrap_or_else(|| DMatrix::zeros(0, 0)))
    }

    fn eval_sel(
        &self,
        x: &DVector<f64>,
        want_j: bool,
        sel: Option<&[usize]>,
    ) -> (DVector<f64>, Option<DMatrix<f64>>) {
        let m = self.model_at(x);
        let th = self.effect_params(x);
        let rpo = self.rows_per_obs();
        let nx = self.free.len() + self.n_effect();
        let n_rows = sel.map_or(self.obs.len(), |s| s.len());
        let mut r = DVector::zeros(rpo * n_rows);
        let mut j = want_j.then(|| DMatrix::zeros(rpo * n_rows, nx));
        let np = m.params().len();
        let mut buf3 = Matrix3xX::zeros(np);
        for pos in 0..n_rows {
            let i = sel.map_or(pos, |s| s[pos]);
            let o = &self.obs[i];
            let w = self.weights.as_ref().map(|w| w[i].sqrt()).unwrap_or(1.0);
            let row = rpo * pos;
            let (p, rot_res) = match (self.orientation, want_j) {
                (Some(s), _) => {
                    let (pose, jp) = m.pose_param_jacobian(&o.q);
                    let meas = o.quat.unwrap_or_else(UnitQuaternion::identity);
                    let d = (pose.rotation * meas.inverse()).scaled_axis();
                    if let Some(j) = j.as_mut() {
                        for (k, &pi) in self.free.iter().enumerate() {
                            for a in 0..3 {
                                j[(row + a, k)] = w * jp[(a, pi)];
                                j[(row + 3 + a, k)] = w * s * jp[(3 + a, pi)];
                            }
                        }
                    }
                    (Point3::from(pose.translation.vector), Some(d * s))
                }
                (None, true) => {
                    let p = m
                        .point_param_jacobian_into(&o.q, &mut buf3)
                        .unwrap_or_else(|| m.measured_point(&o.q));
                    if let Some(j) = j.as_mut() {
                        for (k, &pi) in self.free.iter().enumerate() {
                            for a in 0..3 {
                                j[(row + a, k)] = w * buf3[(a, pi)];
                            }
                        }
                    }
                    (p, None)
                }
                (None, false) => (m.measured_point(&o.q), None),
            };
            let mut p = p.coords;
            let mut col = self.free.len();
            for (e, t) in self.effects.iter().zip(&th) {
                let ne = t.len();
                if let Some(j) = j.as_mut() {
                    let mut je = Matrix3xX::zeros(ne);
                    p += e.point_correction(&m, o, t, Some(&mut je));
                    for c in 0..ne {
                        for a in 0..3 {
                            j[(row + a, col + c)] = w * je[(a, c)];
                        }
                    }
                } else {
                    p += e.point_correction(&m, o, t, None);
                }
                col += ne;
            }
            let e = p - o.p.coords;
            for a in 0..3 {
                r[row + a] = w * e[a];
            }
            if let Some(d) = rot_res {
                for a in 0..3 {
                    r[row + 3 + a] = w * d[a];
                }
            }
        }
        (r, j)
    }

    /// Names of the entries of `x`.
    pub fn x_names(&self) -> Vec<String> {
        let mut v: Vec<String> = self
            .free
            .iter()
            .map(|&i| self.model.params()[i].name.clone())
            .collect();
        for e in self.effects.iter() {
            v.extend(e.param_names());
        }
        v
    }
}

impl LsqProblem for KinProblem<'_> {
    fn n_params(&self) -> usize {
        self.free.len() + self.n_effect()
    }
    fn residuals(&self, x: &DVector<f64>) -> DVector<f64> {
        self.eval(x, false).0
    }
    fn residuals_jacobian(&self, x: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
        let (r, j) = self.eval(x, true);
        (r, j.unwrap_or_else(|| DMatrix::zeros(0, 0)))
    }
}

/// Per-parameter result (internal units: mm or rad).
#[derive(Debug, Clone, PartialEq)]
pub struct ParamEstimate {
    pub name: String,
    pub value: f64,
    pub nominal: f64,
    /// 1-σ from the covariance (free parameters only).
    pub std: Option<f64>,
    pub unit: Unit,
    pub free: bool,
}

/// A parameter fixed by the identifiability analysis and why.
#[derive(Debug, Clone, PartialEq)]
pub struct FixedParam {
    pub name: String,
    pub reason: String,
}

/// Held-out scores (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeldoutScores {
    pub n: usize,
    pub rms_before: f64,
    pub rms_after: f64,
    pub max_before: f64,
    pub max_after: f64,
    /// `validation` records, a `--heldout` file, or k-fold cross-validation.
    pub source: HeldoutSource,
}

/// Where the held-out scores come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HeldoutSource {
    ValidationRecords,
    HeldoutFile,
    KFold(usize),
}

impl HeldoutSource {
    pub fn describe(&self) -> String {
        match self {
            HeldoutSource::ValidationRecords => "validation records of the data file".into(),
            HeldoutSource::HeldoutFile => "the --heldout file".into(),
            HeldoutSource::KFold(k) => format!("{k}-fold cross-validation on the training poses"),
        }
    }
}

/// Result of [`identify`].
#[derive(Debug, Clone)]
pub struct IdentResult {
    /// The identified model (effects not included).
    pub model: KinematicModel,
    /// Nominal model with base and tool fitted (the "before").
    pub nominal: KinematicModel,
    pub params: Vec<ParamEstimate>,
    /// Names of `x` (free model parameters, then effect parameters).
    pub x_names: Vec<String>,
    pub x: DVector<f64>,
    /// Effect parameter values (one slice per effect).
    pub effect_values: Vec<Vec<f64>>,
    /// Covariance of `x` (`σ²(JᵀJ)⁻¹`, unweighted σ² from the final residual).
    pub covariance: DMatrix<f64>,
    /// Final (weighted) residual vector and Jacobian of `x`.
    pub residuals: DVector<f64>,
    pub jacobian: DMatrix<f64>,
    pub fixed: Vec<FixedParam>,
    pub identifiability: Identifiability,
    pub termination: Termination,
    pub iterations: usize,
    pub train_obs: Vec<PoseObs>,
    pub heldout_obs: Vec<PoseObs>,
    pub skipped: Vec<Skipped>,
    /// Per training pose: 3-D error (mm) after the fit.
    pub train_errors: Vec<f64>,
    pub train_rms_mm: f64,
    pub train_rms_mm_before: f64,
    pub sigma_mm: f64,
    pub heldout: Option<HeldoutScores>,
    /// Ids of poses the Huber loss down-weighted (error > threshold), with their error.
    pub outliers: Vec<(u64, f64)>,
    pub huber_mm: Option<f64>,
    /// Rotation residual weight (mm/rad) when marker orientation was used.
    pub orientation: Option<f64>,
}

/// 3-D errors (mm) of a model (+ effects) on observations.
pub fn point_errors(pred: &[Point3<f64>], obs: &[PoseObs]) -> Vec<f64> {
    pred.iter()
        .zip(obs)
        .map(|(p, o)| (p - o.p).norm())
        .collect()
}

/// 3-D errors of a plain model.
pub fn model_errors(model: &KinematicModel, obs: &[PoseObs]) -> Vec<f64> {
    obs.iter()
        .map(|o| (model.measured_point(&o.q) - o.p).norm())
        .collect()
}

fn max_of(v: &[f64]) -> f64 {
    v.iter().cloned().fold(0.0, f64::max)
}

/// The core fit on observations (no held-out scoring): nominal init, identifiability,
/// LM (+ Huber IRLS), covariance. Used by [`identify`], k-fold and the bootstrap.
pub struct CoreFit {
    pub model: KinematicModel,
    pub nominal: KinematicModel,
    pub free: Vec<usize>,
    pub x: DVector<f64>,
    pub fixed: Vec<FixedParam>,
    pub identifiability: Identifiability,
    pub termination: Termination,
    pub iterations: usize,
    pub residuals: DVector<f64>,
    pub jacobian: DMatrix<f64>,
    pub weights: Option<Vec<f64>>,
}

/// Candidate free set (before the identifiability test) for a model and options.
fn candidate_model(
    base: &KinematicModel,
    opts: &IdentOptions,
) -> Result<KinematicModel, SolveError> {
    let mut m = base.clone();
    let names: Vec<(String, ParamGroup)> = m
        .params()
        .iter()
        .map(|p| (p.name.clone(), p.group))
        .collect();
    for (n, g) in &names {
        if *g == ParamGroup::Tool {
            let rot = n.ends_with("rx") || n.ends_with("ry") || n.ends_with("rz");
            m.set_free(n, !rot || opts.orientation)?;
        }
        if *g == ParamGroup::Base {
            m.set_free(n, true)?;
        }
    }
    for n in &opts.free {
        m.set_free(n, true)?;
    }
    for n in &opts.fix {
        m.set_free(n, false)?;
    }
    Ok(m)
}

/// Fit on `train` starting from the nominal chain `nominal_chain`.
pub fn core_fit(
    nominal_chain: &KinematicModel,
    train: &[PoseObs],
    opts: &IdentOptions,
) -> Result<CoreFit, SolveError> {
    let nom = nominal::fit_nominal_obs(nominal_chain, train, opts.orientation)?;
    let start = candidate_model(&nom.model, opts)?;
    let orientation = opts
        .orientation
        .then_some(opts.orientation_weight_mm_per_rad);
    // Identifiability at the start point (effect columns included, kept with priority).
    let mut prob = KinProblem::new(start.clone(), train, &opts.effects);
    prob.orientation = orientation;
    let x0 = prob.x0();
    let (_, j0) = prob.residuals_jacobian(&x0);
    let names = prob.x_names();
    let n_model = prob.free.len();
    let priority = identifiability::priority_order(&start, &prob.free, names.len());
    let idf = identifiability::analyse(&j0, &names, &priority, opts.identifiability_tol);
    let mut fixed = Vec::new();
    let mut model = start.clone();
    for d in &idf.dropped {
        if d.index < n_model {
            model.set_free(&names[d.index], false)?;
            fixed.push(FixedParam {
                name: names[d.index].clone(),
                reason: d.reason.clone(),
            });
        }
    }
    let dropped_effect = idf.dropped.iter().any(|d| d.index >= n_model);
    if dropped_effect {
        let which: Vec<_> = idf
            .dropped
            .iter()
            .filter(|d| d.index >= n_model)
            .map(|d| format!("{} ({})", names[d.index], d.reason))
            .collect();
        return Err(SolveError::Degenerate(format!(
            "effect parameters not identifiable from these poses: {}",
            which.join("; ")
        )));
    }
    let mut prob = KinProblem::new(model, train, &opts.effects);
    prob.orientation = orientation;
    let mut x = prob.x0();
    let mut rep = lm::minimize(&prob, x.clone(), &opts.lm);
    let mut weights = None;
    if let Some(c) = opts.huber_mm {
        // IRLS with Huber weights on the per-pose 3-D error.
        for _ in 0..10 {
            let pred = prob.predict(&rep.x, train);
            let errs = point_errors(&pred, train);
            let w: Vec<f64> = errs
                .iter()
                .map(|&e| if e <= c { 1.0 } else { c / e })
                .collect();
            let changed = weights
                .as_ref()
                .map(|old: &Vec<f64>| {
                    old.iter()
                        .zip(&w)
                        .map(|(a, b)| (a - b).abs())
                        .fold(0.0, f64::max)
                        > 1e-6
                })
                .unwrap_or(true);
            if !changed {
                break;
            }
            prob.weights = Some(w.clone());
            weights = Some(w);
            rep = lm::minimize(&prob, rep.x.clone(), &opts.lm);
        }
    }
    if rep.termination == Termination::NonFinite {
        return Err(SolveError::Solver(rep.termination.describe().into()));
    }
    x.copy_from(&rep.x);
    let model = prob.model_at(&x);
    Ok(CoreFit {
        model,
        nominal: nom.model,
        free: prob.free.clone(),
        x,
        fixed,
        identifiability: idf,
        termination: rep.termination,
        iterations: rep.iterations,
        residuals: rep.residuals,
        jacobian: rep.jacobian,
        weights,
    })
}

/// Full identification of a dataset (see the module docs).
pub fn identify(ds: &Dataset, opts: &IdentOptions) -> Result<IdentResult, SolveError> {
    let chain = KinematicModel::from_robot_block(&ds.header.robot)?;
    let dof = chain.dof();
    let (train, mut skipped) = observations(ds, dof, Split::Train);
    let (heldout, source) = match &opts.heldout {
        Some(h) => {
            super::obs::check_same_frame(ds, h).map_err(SolveError::Invalid)?;
            let (o, s) = observations(h, dof, Split::All);
            if o.is_empty() {
                // Never silently replaced by cross-validation.
                return Err(SolveError::Invalid(format!(
                    "no usable held-out poses in the --heldout file ({} pose records skipped: {}): a \
                     held-out file must hold poses with `q` and a visible marker `p`",
                    s.len(),
                    s.first().map_or("no pose records".into(), |x| x.reason.clone())
                )));
            }
            skipped.extend(s);
            (o, Some(HeldoutSource::HeldoutFile))
        }
        None => {
            let (o, s) = observations(ds, dof, Split::Validation);
            skipped.extend(s);
            let src = (!o.is_empty()).then_some(HeldoutSource::ValidationRecords);
            (o, src)
        }
    };
    if opts.orientation && train.iter().any(|o| o.quat.is_none()) {
        return Err(SolveError::Invalid(
            "--orientation needs a marker quaternion on every training pose".into(),
        ));
    }
    identify_obs(&chain, train, heldout, source, skipped, opts)
}

thread_local! {
    static IDENTIFICATIONS: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

/// How many kinematic identifications ([`identify`] / [`identify_obs`]) this thread has run:
/// a test counts the geometric fits of a pipeline.
pub fn identifications_on_this_thread() -> usize {
    IDENTIFICATIONS.with(|c| c.get())
}

/// As [`identify`], on already extracted observations.
pub fn identify_obs(
    chain: &KinematicModel,
    train: Vec<PoseObs>,
    heldout: Vec<PoseObs>,
    source: Option<HeldoutSource>,
    skipped: Vec<Skipped>,
    opts: &IdentOptions,
) -> Result<IdentResult, SolveError> {
    IDENTIFICATIONS.with(|c| c.set(c.get() + 1));
    check_enough_poses(chain, &train, opts)?;
    let fit = core_fit(chain, &train, opts)?;
    let mut prob = KinProblem::new(fit.model.clone(), &train, &opts.effects);
    prob.free = fit.free.clone();
    prob.model = fit.model.clone();
    let pred = prob.predict(&fit.x, &train);
    let train_errors = point_errors(&pred, &train);
    let train_rms = stats::rms(&train_errors);
    let train_rms_before = stats::rms(&model_errors(&fit.nominal, &train));
    // Covariance: σ² (JᵀJ)⁻¹ with σ² = SSR / (m − n) on the (weighted) residual.
    let m_rows = fit.residuals.len();
    let nx = fit.x.len();
    let dof_res = m_rows.saturating_sub(nx).max(1);
    let sigma2 = fit.residuals.norm_squared() / dof_res as f64;
    let jtj = fit.jacobian.tr_mul(&fit.jacobian);
    let covariance = jtj
        .clone()
        .try_inverse()
        .map(|inv| inv * sigma2)
        .unwrap_or_else(|| {
            let svd = jtj.svd(true, true);
            let eps = 1e-12 * svd.singular_values.max();
            svd.pseudo_inverse(eps)
                .map(|p| p * sigma2)
                .unwrap_or_else(|_| DMatrix::from_element(nx, nx, f64::NAN))
        });
    let nominal_vals = chain.param_values();
    let mut params: Vec<ParamEstimate> = fit
        .model
        .params()
        .iter()
        .enumerate()
        .map(|(i, p)| ParamEstimate {
            name: p.name.clone(),
            value: p.value,
            nominal: match p.group {
                ParamGroup::Base | ParamGroup::Tool => fit.nominal.params()[i].value,
                _ => nominal_vals[i],
            },
            std: None,
            unit: p.unit,
            free: p.free,
        })
        .collect();
    for (k, &i) in fit.free.iter().enumerate() {
        params[i].std = Some(covariance[(k, k)].max(0.0).sqrt());
    }
    let outliers = match (opts.huber_mm, &fit.weights) {
        (Some(c), Some(_)) => train
            .iter()
            .zip(&train_errors)
            .filter(|(_, &e)| e > c)
            .map(|(o, &e)| (o.id, e))
            .collect(),
        _ => Vec::new(),
    };
    let heldout_scores = if !heldout.is_empty() {
        let pa = prob.predict(&fit.x, &heldout);
        let after = point_errors(&pa, &heldout);
        let before = model_errors(&fit.nominal, &heldout);
        Some(HeldoutScores {
            n: heldout.len(),
            rms_before: stats::rms(&before),
            rms_after: stats::rms(&after),
            max_before: max_of(&before),
            max_after: max_of(&after),
            source: source.unwrap_or(HeldoutSource::ValidationRecords),
        })
    } else if opts.kfold >= 2 && train.len() >= 2 * opts.kfold {
        Some(kfold_scores(chain, &train, opts)?)
    } else {
        None
    };
    let effect_values = prob
        .effect_params(&fit.x)
        .into_iter()
        .map(|s| s.to_vec())
        .collect();
    Ok(IdentResult {
        x_names: prob.x_names(),
        model: fit.model,
        nominal: fit.nominal,
        params,
        x: fit.x,
        effect_values,
        covariance,
        residuals: fit.residuals,
        jacobian: fit.jacobian,
        fixed: fit.fixed,
        identifiability: fit.identifiability,
        termination: fit.termination,
        iterations: fit.iterations,
        train_obs: train,
        heldout_obs: heldout,
        skipped,
        train_errors,
        train_rms_mm: train_rms,
        train_rms_mm_before: train_rms_before,
        sigma_mm: sigma2.sqrt(),
        heldout: heldout_scores,
        outliers,
        huber_mm: opts.huber_mm,
        orientation: opts
            .orientation
            .then_some(opts.orientation_weight_mm_per_rad),
    })
}

/// Poses needed for `n` parameters at `rows_per_pose` equations each: twice as many
/// equations as parameters (so the residual keeps as many degrees of freedom as the fit
/// uses, and σ and the parameter covariance mean something).
pub fn poses_needed(n: usize, rows_per_pose: usize) -> usize {
    (2 * n).div_ceil(rows_per_pose.max(1))
}

/// Structural identifiability of the candidate free set: the parameters the model can
/// determine from *well spread* poses (deterministic pseudo-random joint angles within the
/// limits), as names. Data-independent, so it says how many parameters a fit of this model
/// really has, whatever the (possibly too few) poses given.
pub fn structural_parameters(
    chain: &KinematicModel,
    opts: &IdentOptions,
) -> Result<Vec<String>, SolveError> {
    let mut start = candidate_model(chain, opts)?;
    // A generic tool point (off the last joint's axis) so no parameter is lost to a
    // special geometry of the nominal tool.
    start.set_tool(&nalgebra::Isometry3::from_parts(
        nalgebra::Translation3::new(37.0, 23.0, 110.0),
        UnitQuaternion::identity(),
    ));
    let limits = chain.joint_limits();
    let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut unit = || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let synth: Vec<PoseObs> = (0..60)
        .map(|i| {
            let q: Vec<f64> = limits
                .iter()
                .map(|&(lo, hi)| {
                    let (lo, hi) = (lo.max(-std::f64::consts::PI), hi.min(std::f64::consts::PI));
                    lo + (hi - lo) * unit()
                })
                .collect();
            let pose = start.flange_pose(&q);
            let mut o = PoseObs::at(i, i as f64, q.clone(), start.measured_point(&q));
            o.quat = Some(pose.rotation);
            o
        })
        .collect();
    let none: [Arc<dyn Effect>; 0] = [];
    let mut prob = KinProblem::new(start.clone(), &synth, &none);
    prob.orientation = opts
        .orientation
        .then_some(opts.orientation_weight_mm_per_rad);
    let (_, j) = prob.residuals_jacobian(&prob.x0());
    let names = prob.x_names();
    let priority = identifiability::priority_order(&start, &prob.free, names.len());
    let idf = identifiability::analyse(&j, &names, &priority, opts.identifiability_tol);
    let dropped: std::collections::HashSet<usize> = idf.dropped.iter().map(|d| d.index).collect();
    Ok(names
        .into_iter()
        .enumerate()
        .filter(|(i, _)| !dropped.contains(i))
        .map(|(_, n)| n)
        .collect())
}

/// Refuses an under-determined fit: fewer poses than [`poses_needed`] for the structurally
/// identifiable parameters (plus the effects' parameters), saying how many more are needed.
pub fn check_enough_poses(
    chain: &KinematicModel,
    train: &[PoseObs],
    opts: &IdentOptions,
) -> Result<(), SolveError> {
    let params = structural_parameters(chain, opts)?;
    let n_effect: usize = opts.effects.iter().map(|e| e.param_names().len()).sum();
    let n = params.len() + n_effect;
    let rpo = if opts.orientation { 6 } else { 3 };
    let need = poses_needed(n, rpo);
    if train.len() < need {
        return Err(SolveError::Invalid(format!(
            "under-determined fit: {} usable training poses give {} equations for {n} \
             identifiable parameters ({} of the model{}): at least {need} poses are needed \
             (twice as many equations as parameters); measure {} more poses",
            train.len(),
            rpo * train.len(),
            params.len(),
            if n_effect > 0 {
                format!(", {n_effect} of the effects")
            } else {
                String::new()
            },
            need - train.len()
        )));
    }
    Ok(())
}

/// k-fold cross-validated held-out scores (folds by position modulo k).
pub fn kfold_scores(
    chain: &KinematicModel,
    train: &[PoseObs],
    opts: &IdentOptions,
) -> Result<HeldoutScores, SolveError> {
    let k = opts.kfold;
    let mut before = Vec::new();
    let mut after = Vec::new();
    for f in 0..k {
        let tr: Vec<PoseObs> = train
            .iter()
            .enumerate()
            .filter(|(i, _)| i % k != f)
            .map(|(_, o)| o.clone())
            .collect();
        let te: Vec<PoseObs> = train
            .iter()
            .enumerate()
            .filter(|(i, _)| i % k == f)
            .map(|(_, o)| o.clone())
            .collect();
        let fit = core_fit(chain, &tr, opts)?;
        let mut prob = KinProblem::new(fit.model.clone(), &tr, &opts.effects);
        prob.free = fit.free.clone();
        after.extend(point_errors(&prob.predict(&fit.x, &te), &te));
        before.extend(model_errors(&fit.nominal, &te));
    }
    Ok(HeldoutScores {
        n: train.len(),
        rms_before: stats::rms(&before),
        rms_after: stats::rms(&after),
        max_before: max_of(&before),
        max_after: max_of(&after),
        source: HeldoutSource::KFold(k),
    })
}
