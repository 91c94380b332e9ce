//! The effect library: physical effects a geometric model lacks, each as a block of
//! regressors that is linear in its coefficients, and the exact (nonlinear) way the fitted
//! effect changes a prediction.
//!
//! One file per effect family (`compliance.rs`, `backlash.rs`, ...): each owns its kind
//! name, its typed calibration-file parameters (a serde struct), its regressors / Jacobian
//! columns, its identifiability check, its candidates, its plot driver and its plain-word
//! sentence ([`EffectModel`] and [`Family`]). The one registry is the `registry!` list at
//! the end of this file: the [`Block`] enum, the calibration-file reader ([`Effect::from_cal`]),
//! the diagnosis' candidate library ([`registry_candidates`]) and the test fixtures
//! ([`registry_examples`]) are generated from it. Adding an effect is one new file and one
//! line of that list. The reader is one generic parse of the family's `Family::File` struct
//! (a missing or mistyped field named by `file::from_params`) followed by the family's
//! validation hook [`Family::from_file`] (a field out of range named).
//!
//! Internal units: mm, rad, s, kg, N·m. Calibration files use degrees (see [`Effect::to_cal`]).
//!
//! Prediction of a marker point with effects (tracker frame):
//! 1. joint-angle effects add `δθ_j = Σ_c coef_c · f_c(q, ctx)` to the measured angle `q_j`
//!    (compliance, backlash, eccentricity, per-joint thermal drift, latency);
//! 2. frame effects change the model used for that pose (base shift after a change point,
//!    thermal growth of link lengths);
//! 3. point effects move the predicted point (link deflection, tracker depth scale);
//! 4. `tracker_scale` scales the point about the tracker origin: `y = (1 + s) p`;
//! 5. `nonparametric` adds a kernel correction of `q` (see [`super::nonparam`]).
use nalgebra::{Matrix3xX, Point3, Vector3};
use serde_json::{Map, Value};
use std::borrow::Cow;

use super::nonparam::Rbf;
use crate::dataset::CalEffect;
use crate::model::{KinematicModel, ModelConsts, ParamGroup, PoseFrames};
use crate::schema::EffectParameter;
use crate::solve::obs::{PoseCtx, PoseObs};

mod file;
pub use file::EffectFileError;
mod held;
pub use held::{apply_effects_held, JointRange, Outside, OUTSIDE_REPORT_DEG};

mod backlash;
mod base_shift;
mod compliance;
mod coupling;
mod deflection;
mod eccentricity;
mod latency;
mod nonparametric;
mod temperature;
mod thermal;
mod tracker_depth;
mod tracker_scale;
mod transmission;
mod transmission_map;
mod wave_generator;

pub use backlash::Backlash;
pub use base_shift::BaseShift;
pub use compliance::Compliance;
pub use coupling::Coupling;
pub use deflection::{deflection_terms, LinkDeflection};
pub use eccentricity::Eccentricity;
pub use latency::Latency;
pub use temperature::{TempDrift, TEMP_DRIFT_JOINTS};
pub use thermal::{JointDrift, LengthDrift};
pub use tracker_depth::TrackerDepthScale;
pub use tracker_scale::TrackerScale;
pub use transmission::{Ripple, Transmission};
pub use transmission_map::{TransmissionMap, MAX_MAP_HARMONICS};
pub use wave_generator::WaveGenerator;

/// Standard gravity (m/s²).
pub const GRAVITY: f64 = 9.80665;
/// Gravity direction in the robot base frame (the base z axis points up).
pub const GRAVITY_DIR: [f64; 3] = [0.0, 0.0, -1.0];

/// A point of the generic mass model: an MDH frame origin (1-based frame index) or the
/// marker/tool point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MassPoint {
    Frame(usize),
    /// The flange origin (a payload on the flange axis is a combination of the wrist
    /// centre and the flange origin).
    Flange,
    Marker,
}

impl MassPoint {
    fn label(&self) -> String {
        match self {
            MassPoint::Frame(k) => format!("frame{k}"),
            MassPoint::Flange => "flange".into(),
            MassPoint::Marker => "marker".into(),
        }
    }
    fn parse(s: &str) -> Option<Self> {
        if s == "marker" {
            return Some(MassPoint::Marker);
        }
        if s == "flange" {
            return Some(MassPoint::Flange);
        }
        s.strip_prefix("frame")?.parse().ok().map(MassPoint::Frame)
    }
    /// The point in plain words (`the frame-3 origin`, `the flange`, `the marker`).
    fn words(&self) -> String {
        match self {
            MassPoint::Frame(k) => format!("the frame-{k} origin"),
            MassPoint::Flange => "the flange".into(),
            MassPoint::Marker => "the marker".into(),
        }
    }
    /// Position (robot base, mm) at the pose whose frames are `f`.
    fn position_in(&self, f: &PoseFrames) -> Vector3<f64> {
        match self {
            MassPoint::Frame(k) => f.joint_frame(*k).translation.vector,
            MassPoint::Flange => f.flange_origin(),
            MassPoint::Marker => f.tool_origin(),
        }
    }
}

/// What drives a thermal effect.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Driver {
    /// Hours since `t0_s` (s): a linear drift.
    Time { t0_s: f64 },
    /// Temperature rise (°C) above `t0_c` (records carry `temp_c`).
    Temp { t0_c: f64 },
    /// Exponential warm-up by time: `x = 1 − e^{−(t − t0)/τ}` (0 at `t0_s`, 1 when warm).
    /// A warm-up that began before `t0_s` has the same shape up to its amplitude and a
    /// constant (absorbed by the geometric offsets), so the power-on time is not needed.
    WarmUp { t0_s: f64, tau_s: f64 },
}

impl Driver {
    /// The driver value for one pose (hours, K or the warm-up fraction).
    pub fn value(&self, ctx: &PoseCtx) -> f64 {
        match self {
            Driver::Time { t0_s } => (ctx.t - t0_s) / 3600.0,
            Driver::Temp { t0_c } => ctx.temp_c.map(|t| t - t0_c).unwrap_or(0.0),
            Driver::WarmUp { t0_s, tau_s } => 1.0 - (-(ctx.t - t0_s) / tau_s.max(1e-9)).exp(),
        }
    }
    /// Unit of the driver (in coefficient names `deg_per_<unit>`).
    pub fn unit(&self) -> &'static str {
        match self {
            Driver::Time { .. } => "hour",
            Driver::Temp { .. } => "K",
            Driver::WarmUp { .. } => "full_warm_up",
        }
    }
    /// Short label (`time`, `temperature`, `warm-up τ=1800 s`).
    pub fn label(&self) -> String {
        match self {
            Driver::Time { .. } => "time".into(),
            Driver::Temp { .. } => "temperature".into(),
            Driver::WarmUp { tau_s, .. } => format!("warm-up τ={tau_s:.0} s"),
        }
    }
    /// The same driver with another time constant (warm-up only).
    pub fn with_tau(&self, tau: f64) -> Driver {
        match self {
            Driver::WarmUp { t0_s, .. } => Driver::WarmUp {
                t0_s: *t0_s,
                tau_s: tau,
            },
            d => *d,
        }
    }
}

/// A fitted block's coefficients (internal units) and their standard deviations, as the
/// file form, the diagnosis parameters and the sentence of a family read them.
#[derive(Debug, Clone, Copy)]
pub struct Coefs<'a> {
    pub value: &'a [f64],
    pub std: &'a [f64],
    /// Standard deviation of a warm-up time constant τ (s), NaN when not estimated.
    pub tau_std: f64,
}

impl Coefs<'_> {
    /// Coefficient `k` (NaN when absent).
    pub fn v(&self, k: usize) -> f64 {
        self.value.get(k).copied().unwrap_or(f64::NAN)
    }
    /// Standard deviation of coefficient `k` (NaN when absent).
    pub fn s(&self, k: usize) -> f64 {
        self.std.get(k).copied().unwrap_or(f64::NAN)
    }
}

/// One effect family: the interface the diagnosis uses for every candidate and fitted
/// effect. A candidate is checked for identifiability on the data
/// ([`EffectModel::check_identifiable`]), scored by its columns of the same problem's
/// Jacobian ([`super::fit::DiagnoseProblem`], built from [`EffectModel::columns`]), and
/// refitted jointly with the geometry on the one LM solver ([`crate::solve::lm`]); the
/// finite-difference tests check those columns for every registered family.
pub trait EffectModel {
    /// Effect kind (the contract's names: `joint_compliance`, `backlash`, ...).
    fn kind(&self) -> &'static str;
    /// The joint (1-based) the effect belongs to, if any.
    fn joint(&self) -> Option<usize> {
        None
    }
    /// Number of linear parameters (coefficients).
    fn n_params(&self) -> usize;
    /// Names of the parameters with their internal unit (`name [unit]`).
    fn param_names(&self) -> Vec<String>;
    /// A short human label, e.g. `joint_compliance(j2)`.
    fn label(&self) -> String {
        match self.joint() {
            Some(j) => format!("{}(j{j})", self.kind()),
            None => self.kind().to_string(),
        }
    }
    /// Joint-angle regressor: `(joint index 0-based, parameter index, feature)` so that
    /// `δθ_joint += coef · feature`. Empty for effects that do not act on joint angles.
    fn joint_features(&self, _model: &KinematicModel, _ctx: &PoseCtx) -> Vec<(usize, usize, f64)> {
        vec![]
    }
    /// The driver `x` of a link-length growth `a_i ← (1 + g·x)·a_i` at one pose (`g` the
    /// first coefficient); `None` for effects that do not grow the links.
    fn growth_driver(&self, _ctx: &PoseCtx) -> Option<f64> {
        None
    }
    /// Apply a frame effect (base shift, link growth) with coefficients `coefs` to the model
    /// one pose is predicted with; joint-angle effects leave it alone. The default applies
    /// the link growth of [`EffectModel::growth_driver`].
    fn apply_frame(&self, coefs: &[f64], out: &mut Cow<KinematicModel>, ctx: &PoseCtx) {
        let (Some(x), Some(g)) = (self.growth_driver(ctx), coefs.first()) else {
            return;
        };
        let f = 1.0 + g * x;
        if f == 1.0 {
            return;
        }
        let m = out.to_mut();
        let mut v = m.param_values();
        for (i, p) in m.params().iter().enumerate() {
            if is_length(p) {
                v[i] *= f;
            }
        }
        m.set_param_values(&v);
    }
    /// Displacement (tracker frame, mm) of the predicted point that the effect adds
    /// directly (link deflection, tracker depth scale) at one pose, with the pose's model.
    fn point_displacement(
        &self,
        _model: &KinematicModel,
        _coefs: &[f64],
        _ctx: &PoseCtx,
    ) -> Option<Vector3<f64>> {
        None
    }
    /// Analytic Jacobian: d point / d parameter at one pose, given the model the pose is
    /// evaluated with, its full parameter Jacobian `jm` and the point `p`. The default is
    /// the joint-angle regressors through the joint-offset columns.
    fn columns(
        &self,
        model: &KinematicModel,
        jm: &Matrix3xX<f64>,
        _p: &Point3<f64>,
        ctx: &PoseCtx,
    ) -> Vec<Vector3<f64>> {
        joint_columns(self, model, jm, ctx)
    }
    /// Whether the data can identify the effect at all (`Err` says why not: no approach
    /// from both sides, a vertical axis with constant gravity torque, no joint velocity).
    /// The numerical identifiability against the model (independence of the columns) is
    /// part of the score.
    fn check_identifiable(
        &self,
        _model: &KinematicModel,
        _train: &[PoseObs],
    ) -> Result<(), String> {
        Ok(())
    }
    /// The coefficients in file units (degrees for angles, ppm for ratios), each with its
    /// standard deviation and 95 % interval (`diagnosis.json`).
    fn parameters(&self, c: &Coefs) -> Vec<EffectParameter>;
    /// The calibration-file parameters (the family's typed serde struct as a JSON map).
    fn file_params(&self, c: &Coefs) -> Map<String, Value>;
    /// The fitted effect in plain words with its size (no identifiers), e.g. "joint 2
    /// bends 0.0021° per N·m of gravity torque …".
    fn sentence(&self, c: &Coefs) -> String;
    /// The quantity the effect's regressor is a function of at one pose and its axis label
    /// (the x axis of the diagnosis' driver plot). The default is the pose time.
    fn plot_driver(&self, _model: &KinematicModel, o: &PoseObs) -> (f64, String) {
        (o.ctx.t, "time (s)".into())
    }
}

/// The static side of a family: its kind, how its calibration-file entry is read, its
/// candidates for the diagnosis and a fixture for the registry's tests.
pub trait Family: EffectModel + Sized {
    /// The kind name written in files.
    const KIND: &'static str;
    /// Whether a calibration-file entry is this family's (by default: the kind matches).
    fn claims(e: &CalEffect) -> bool {
        e.kind == Self::KIND
    }
    /// The family's parameters as `calibration.json` holds them: a typed serde struct, parsed
    /// by the one generic reader ([`file::from_params`]: a missing or mistyped field is named).
    type File: serde::de::DeserializeOwned + serde::Serialize + Default;
    /// The family's validation hook: the block, its coefficients and their standard deviations
    /// (NaN where the file has none), internal units, from the parsed parameters of `e`; `Err`
    /// names a field out of range.
    fn from_file(
        e: &CalEffect,
        f: Self::File,
    ) -> Result<(Self, Vec<f64>, Vec<f64>), EffectFileError>;
    /// Read the entry: the generic parse, then [`Family::from_file`].
    fn read(e: &CalEffect) -> Result<(Self, Vec<f64>, Vec<f64>), EffectFileError> {
        Self::from_file(e, file::from_params(e)?)
    }
    /// Candidate groups of this family on joint `j` (a group's variants count as separate
    /// tests; see [`super::candidates`]).
    fn joint_candidates(
        _model: &KinematicModel,
        _opt: &super::Options,
        _j: usize,
    ) -> Vec<Vec<Self>> {
        vec![]
    }
    /// Candidate groups of this family that belong to no joint (after every joint's).
    fn global_candidates(
        _model: &KinematicModel,
        _train: &[PoseObs],
        _opt: &super::Options,
    ) -> Vec<Vec<Block>> {
        vec![]
    }
    /// A fitted example on `model` (block and coefficients, internal units) that moves the
    /// point measurably: the registry's tests check its file form, sentence and columns.
    fn example(model: &KinematicModel) -> (Self, Vec<f64>);
}

/// The columns of a block's joint-angle regressors (through the joint-offset columns).
pub fn joint_columns<E: EffectModel + ?Sized>(
    e: &E,
    model: &KinematicModel,
    jm: &Matrix3xX<f64>,
    ctx: &PoseCtx,
) -> Vec<Vector3<f64>> {
    features_columns(e.n_params(), e.joint_features(model, ctx), model, jm)
}

/// The columns of `n` coefficients from their joint-angle regressors `features` (see
/// [`EffectModel::joint_features`]) through the joint-offset columns of `jm`.
fn features_columns(
    n: usize,
    features: Vec<(usize, usize, f64)>,
    model: &KinematicModel,
    jm: &Matrix3xX<f64>,
) -> Vec<Vector3<f64>> {
    let mut cols = vec![Vector3::zeros(); n];
    for (j, c, f) in features {
        if let Some(ip) = phi_index(model, j) {
            cols[c] += jm.column(ip) * f;
        }
    }
    cols
}

/// Index of the joint-offset parameter `phi<j+1>` of joint `j` (0-based) in `model`
/// (without allocating a name for the first 8 joints: this runs per pose and block).
fn phi_index(model: &KinematicModel, j: usize) -> Option<usize> {
    const NAMES: [&str; 8] = [
        "phi1", "phi2", "phi3", "phi4", "phi5", "phi6", "phi7", "phi8",
    ];
    match NAMES.get(j) {
        Some(n) => model.param_index(n),
        None => model.param_index(&format!("phi{}", j + 1)),
    }
}

/// The measured angle of joint `joint` (1-based) if the joint exists in `model` and `ctx`.
fn joint_angle(model: &KinematicModel, ctx: &PoseCtx, joint: usize) -> Option<f64> {
    match ctx.q.get(joint.wrapping_sub(1)) {
        Some(&q) if joint >= 1 && joint <= model.dof() => Some(q),
        _ => None,
    }
}

/// Standard deviation of a sample.
pub(crate) fn spread(v: impl Iterator<Item = f64>) -> f64 {
    let v: Vec<f64> = v.collect();
    let n = v.len().max(1) as f64;
    let m = v.iter().sum::<f64>() / n;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n).sqrt()
}

/// Whether a model parameter is a link length (`a_i`, `d_i`), which thermal growth scales.
fn is_length(p: &crate::model::Param) -> bool {
    matches!(p.group, ParamGroup::Joint(_))
        && (p.name.starts_with('a') && !p.name.starts_with("alpha") || p.name.starts_with('d'))
}

/// The columns of a link-growth coefficient: `Σ_i ∂P/∂a_i · a_i · x` over the lengths.
fn growth_column(model: &KinematicModel, jm: &Matrix3xX<f64>, x: f64, col: &mut Vector3<f64>) {
    for (i, pr) in model.params().iter().enumerate() {
        if is_length(pr) {
            *col += jm.column(i) * (pr.value * x);
        }
    }
}

/// Gravity torque (N·m) about joint `joint` (1-based) of 1 kg at each mass point, at `q`.
pub fn gravity_torques(
    model: &KinematicModel,
    q: &[f64],
    joint: usize,
    points: &[MassPoint],
) -> Vec<f64> {
    gravity_torques_in(&model.pose_frames(q), joint, points)
}

/// [`gravity_torques`] at the pose whose frames are `f` (the same values).
pub fn gravity_torques_in(f: &PoseFrames, joint: usize, points: &[MassPoint]) -> Vec<f64> {
    let fj = f.joint_frame(joint);
    let z = fj.rotation * Vector3::z();
    let o = fj.translation.vector;
    let g = Vector3::from(GRAVITY_DIR) * GRAVITY;
    points
        .iter()
        .map(|p| {
            let c = p.position_in(f);
            // mm → m
            z.dot(&((c - o) * 1e-3).cross(&g))
        })
        .collect()
}

/// Distinct mass points downstream of joint `joint` (1-based): origins of the following
/// MDH frames (frames that coincide, e.g. at a spherical wrist, count once) and the marker.
pub fn mass_points(model: &KinematicModel, joint: usize) -> Vec<MassPoint> {
    let n = model.dof();
    let q0 = vec![0.0; n];
    let mut pts: Vec<(MassPoint, Vector3<f64>)> = Vec::new();
    let origin = model.joint_frame(&q0, joint.min(n)).translation.vector;
    let mut last = origin;
    for k in joint + 1..=n {
        let p = model.joint_frame(&q0, k).translation.vector;
        if (p - last).norm() > 30.0 {
            pts.push((MassPoint::Frame(k), p));
            last = p;
        }
    }
    for (mp, p) in [
        (MassPoint::Flange, model.flange_pose(&q0).translation.vector),
        (
            MassPoint::Marker,
            model.tool_pose_in_base(&q0).translation.vector,
        ),
    ] {
        if pts.iter().all(|(_, x)| (x - p).norm() > 30.0) && (p - origin).norm() > 30.0 {
            pts.push((mp, p));
        }
    }
    pts.into_iter().map(|(p, _)| p).collect()
}

/// A number in a sentence: plain decimals for ordinary magnitudes, exponents for tiny or
/// huge ones, `digits` significant-ish decimals.
pub fn plain_number(x: f64, digits: usize) -> String {
    if x == 0.0 || (1e-3..1e5).contains(&x.abs()) {
        format!("{x:.digits$}")
    } else {
        format!("{x:.digits$e}")
    }
}

/// ` (± ci)` of a 95 % interval half-width `1.96·sd` in `unit`, empty when `sd` is unknown.
fn pm(sd: f64, unit: &str) -> String {
    if sd.is_finite() {
        format!(" (± {}{unit})", plain_number(1.96 * sd, 4))
    } else {
        String::new()
    }
}

/// A parameter in degrees from coefficient `k` (rad) of `c` (`diagnosis.json`).
fn deg_param(name: &str, c: &Coefs, k: usize) -> EffectParameter {
    EffectParameter::new(name, "deg", c.v(k).to_degrees(), c.s(k).to_degrees())
}

/// The angle (rad) of joint `joint` (1-based) at one observation, NaN when absent (the x
/// axis of a driver plot).
fn q_at(o: &PoseObs, joint: usize) -> f64 {
    o.ctx
        .q
        .get(joint.wrapping_sub(1))
        .copied()
        .unwrap_or(f64::NAN)
}

/// The file form of a sin/cos pair `a sin φ + b cos φ` (rad inside): `sin_deg`, `cos_deg`
/// and their standard deviations `std_deg` (flattened into the family's struct).
#[derive(Debug, Default, serde::Serialize, serde::Deserialize)]
struct SinCosFile {
    sin_deg: f64,
    cos_deg: f64,
    #[serde(default, deserialize_with = "file::lenient_vec")]
    std_deg: Vec<f64>,
}

impl SinCosFile {
    fn of(c: &Coefs) -> Self {
        SinCosFile {
            sin_deg: c.v(0).to_degrees(),
            cos_deg: c.v(1).to_degrees(),
            std_deg: file::deg(c.std),
        }
    }
    /// Coefficients and standard deviations (rad).
    fn coefs(&self) -> (Vec<f64>, Vec<f64>) {
        (
            file::rad(&[self.sin_deg, self.cos_deg]),
            file::rad(&self.std_deg),
        )
    }
}

/// The amplitude (deg) of a sin/cos pair.
fn amplitude_deg(c: &Coefs) -> f64 {
    c.v(0).hypot(c.v(1)).to_degrees()
}

/// A fitted effect: its block, coefficients (internal units) and their standard deviations.
#[derive(Debug, Clone, PartialEq)]
pub struct Effect {
    pub block: Block,
    pub coefs: Vec<f64>,
    pub std: Vec<f64>,
    /// Standard deviation of a warm-up time constant τ (s), from the profile of the fit
    /// over τ (NaN when not estimated).
    pub tau_std: f64,
}

impl Effect {
    /// A zero effect of a block.
    pub fn zero(block: Block) -> Self {
        let n = block.n_params();
        Effect {
            block,
            coefs: vec![0.0; n],
            std: vec![f64::NAN; n],
            tau_std: f64::NAN,
        }
    }
    fn fitted(&self) -> Coefs<'_> {
        Coefs {
            value: &self.coefs,
            std: &self.std,
            tau_std: self.tau_std,
        }
    }
    /// The coefficients in file units (degrees for angles, ppm for ratios), each with its
    /// standard deviation and 95 % interval (`diagnosis.json`).
    pub fn parameters(&self) -> Vec<EffectParameter> {
        self.block.model().parameters(&self.fitted())
    }
    /// The effect in plain words with its size.
    pub fn sentence(&self) -> String {
        self.block.model().sentence(&self.fitted())
    }
    /// The calibration-file form (degrees where the internal unit is rad).
    pub fn to_cal(&self) -> CalEffect {
        CalEffect {
            kind: self.block.kind().into(),
            joint: self.block.joint(),
            params: self.block.model().file_params(&self.fitted()),
            extra: Map::new(),
        }
    }
    /// Read an effect from its calibration-file form (the registry's family that claims
    /// the entry reads it).
    pub fn from_cal(e: &CalEffect) -> Result<Effect, EffectFileError> {
        let (block, coefs, std) = read_block(e)?;
        Ok(Effect {
            block,
            coefs,
            std,
            tau_std: f64::NAN,
        })
    }
}

/// Whether `e` leaves every prediction exactly as it is: coefficients present and all
/// zero (a candidate appended at zero to take its columns). Its joint offsets (`d + 0·f`),
/// frame change (`v + 0`, growth `1 + 0·x`) and displacement (`p + 0`) change no bit of a
/// finite prediction, so [`joint_offsets`], [`pose_model`] and [`point_displacement`] skip
/// it; its columns are still computed. (A round's ~1,000 candidates otherwise cost their
/// features, a model copy per base shift and two forward kinematics per link deflection at
/// every pose, for nothing.)
fn inert(e: &Effect) -> bool {
    !e.coefs.is_empty() && e.coefs.iter().all(|&c| c == 0.0)
}

/// `δθ` (rad, per joint) of all joint-angle effects at one pose.
pub fn joint_offsets(model: &KinematicModel, effects: &[Effect], ctx: &PoseCtx) -> Vec<f64> {
    let mut d = vec![0.0; model.dof()];
    for e in effects.iter().filter(|e| !inert(e)) {
        for (j, c, f) in e.block.joint_features(model, ctx) {
            if let Some(v) = e.coefs.get(c) {
                d[j] += v * f;
            }
        }
    }
    d
}

/// The model a pose is predicted with (base shift / link growth applied), borrowed when
/// no frame effect applies.
pub fn pose_model<'a>(
    model: &'a KinematicModel,
    effects: &[Effect],
    ctx: &PoseCtx,
) -> Cow<'a, KinematicModel> {
    let mut out: Cow<KinematicModel> = Cow::Borrowed(model);
    for e in effects.iter().filter(|e| !inert(e)) {
        e.block.apply_frame(&e.coefs, &mut out, ctx);
    }
    out
}

/// Marker displacement (tracker frame, mm) of the point-displacement effects (link
/// deflection, tracker depth scale) of `effects` at one pose, predicted with `model`.
pub fn point_displacement(
    model: &KinematicModel,
    effects: &[Effect],
    ctx: &PoseCtx,
) -> Vector3<f64> {
    let mut d = Vector3::zeros();
    for e in effects.iter().filter(|e| !inert(e)) {
        if let Some(v) = e.block.point_displacement(model, &e.coefs, ctx) {
            d += v;
        }
    }
    d
}

fn tracker_scale(effects: &[Effect]) -> f64 {
    effects
        .iter()
        .filter(|e| matches!(e.block, Block::TrackerScale(_)))
        .filter_map(|e| e.coefs.first())
        .sum()
}

/// Predicted marker origin (mm, tracker frame) of one pose with all effects applied.
pub fn apply_effects(model: &KinematicModel, effects: &[Effect], ctx: &PoseCtx) -> Point3<f64> {
    let np = effects.iter().filter_map(|e| np_correction(model, e, ctx));
    apply_effects_np(model, effects, ctx, np)
}

/// The kernel correction of a `nonparametric` effect at one pose (`None` for other effects).
pub fn np_correction(model: &KinematicModel, e: &Effect, ctx: &PoseCtx) -> Option<Vector3<f64>> {
    match &e.block {
        Block::Nonparametric(r) => Some(r.correction(model, &ctx.q)),
        _ => None,
    }
}

/// [`apply_effects`] with the kernel corrections of the `nonparametric` effects of
/// `effects` given (`np`, in `effects` order, [`np_correction`]): a caller predicting the
/// same pose under several effect lists evaluates each kernel sum once.
pub fn apply_effects_np(
    model: &KinematicModel,
    effects: &[Effect],
    ctx: &PoseCtx,
    np: impl IntoIterator<Item = Vector3<f64>>,
) -> Point3<f64> {
    let d = joint_offsets(model, effects, ctx);
    let th: Vec<f64> = ctx.q.iter().zip(d.iter()).map(|(q, d)| q + d).collect();
    let m = pose_model(model, effects, ctx);
    let p = m.measured_point(&th).coords + point_displacement(&m, effects, ctx);
    let mut y = p * (1.0 + tracker_scale(effects));
    for c in np {
        y += c;
    }
    Point3::from(y)
}

/// Prediction, full parameter Jacobian of the (effect-adjusted) geometric model and the
/// columns of every effect coefficient at one pose. Effect columns are in `effects` order.
pub struct PoseEval {
    pub pred: Point3<f64>,
    /// d pred / d every model parameter (3 × params().len()).
    pub jac_model: Matrix3xX<f64>,
    /// d pred / d every coefficient of `effects`, concatenated.
    pub jac_effects: Matrix3xX<f64>,
}

/// What every column of one pose is computed from: the model the pose is predicted with
/// ([`pose_model`]), the point before the tracker scale (with the point displacements), the
/// model's parameter Jacobian at the effect-adjusted angles and the tracker scale `1 + s`.
pub struct PoseBase<'a> {
    pub m: Cow<'a, KinematicModel>,
    pub p: Point3<f64>,
    pub jm_pose: Matrix3xX<f64>,
    pub s: f64,
}

/// The [`PoseBase`] of one pose under `effects`. Effects with all-zero coefficients change
/// none of it (they are skipped, and add `0` to the tracker scale). `consts`: those of
/// `model` ([`KinematicModel::consts`]) when the caller formed them for many poses; used
/// when the pose is predicted with `model` itself (the same values either way).
pub fn pose_base<'a>(
    model: &'a KinematicModel,
    consts: Option<&ModelConsts>,
    effects: &[Effect],
    ctx: &PoseCtx,
) -> PoseBase<'a> {
    let d = joint_offsets(model, effects, ctx);
    let th: Vec<f64> = ctx.q.iter().zip(d.iter()).map(|(q, d)| q + d).collect();
    let m = pose_model(model, effects, ctx);
    let with_consts = match (&m, consts) {
        (Cow::Borrowed(_), Some(c)) => {
            let mut jm = Matrix3xX::zeros(m.params().len());
            m.point_param_jacobian_with(c, &th, &mut jm)
                .map(|p| (p, jm))
        }
        _ => None,
    };
    let (p0, jm_pose) = with_consts.unwrap_or_else(|| m.point_param_jacobian(&th));
    // Point effects add a displacement linear in their coefficients; its dependence on
    // the geometry (a second-order cross term) is left out of the model columns.
    let p = p0 + point_displacement(&m, effects, ctx);
    PoseBase {
        m,
        p,
        jm_pose,
        s: 1.0 + tracker_scale(effects),
    }
}

/// The Jacobian columns of one effect (`block` with coefficients `coefs`) at one pose as
/// [`eval_pose`] sets them, from the block's own columns `cols` ([`EffectModel::columns`]
/// with the pose's model): the link growth's column in the ungrown lengths, every column
/// times the tracker scale `s`, the tracker scale's own column the point `p`.
pub fn scaled_columns(
    block: &Block,
    coefs: &[f64],
    mut cols: Vec<Vector3<f64>>,
    p: &Point3<f64>,
    s: f64,
    ctx: &PoseCtx,
) -> Vec<Vector3<f64>> {
    if block.growth_driver(ctx).is_some() {
        // `m` holds the grown lengths a'_i = a_i·growth; the column needs a_i.
        cols[0] /= block.growth(coefs, ctx).unwrap_or(1.0);
    }
    for c in cols.iter_mut() {
        *c *= s;
    }
    if let Block::TrackerScale(_) = block {
        // d/ds of (1+s)p is p itself, not scaled again
        cols[0] = p.coords;
    }
    cols
}

/// [`EffectModel::columns`] of `block` at the pose whose frames (of `model` at `ctx.q`)
/// are `f`: the gravity-driven blocks take their frames from `f` instead of walking the
/// chain per mass point (the same values).
pub fn block_columns_in(
    block: &Block,
    f: &PoseFrames,
    model: &KinematicModel,
    jm: &Matrix3xX<f64>,
    p: &Point3<f64>,
    ctx: &PoseCtx,
) -> Vec<Vector3<f64>> {
    match block {
        Block::Compliance(c) => {
            features_columns(c.n_params(), c.features_in(f, model.dof()), model, jm)
        }
        Block::LinkDeflection(d) => d.columns_in(f),
        b => b.columns(model, jm, p, ctx),
    }
}

/// Evaluate one pose (see [`PoseEval`]).
pub fn eval_pose(model: &KinematicModel, effects: &[Effect], ctx: &PoseCtx) -> PoseEval {
    eval_pose_with(model, None, effects, ctx)
}

/// [`eval_pose`] with the constants of `model` formed by the caller (see [`pose_base`]).
pub fn eval_pose_with(
    model: &KinematicModel,
    consts: Option<&ModelConsts>,
    effects: &[Effect],
    ctx: &PoseCtx,
) -> PoseEval {
    let PoseBase { m, p, jm_pose, s } = pose_base(model, consts, effects, ctx);
    // Link growth scales the length parameters: pred = P(a·(1 + g·x)), so
    // d pred / d a_i = (1 + g·x) ∂P/∂a'_i and d pred / d g = Σ ∂P/∂a'_i a_i x.
    let growth: f64 = effects
        .iter()
        .filter_map(|e| e.block.growth(&e.coefs, ctx))
        .product();
    let mut jm = jm_pose.clone();
    if growth != 1.0 {
        for (i, pr) in model.params().iter().enumerate() {
            if is_length(pr) {
                jm.column_mut(i).scale_mut(growth);
            }
        }
    }
    let mut pred = p.coords * s;
    let ncol: usize = effects.iter().map(|e| e.block.n_params()).sum();
    let mut je = Matrix3xX::zeros(ncol);
    let mut off = 0;
    for e in effects {
        let raw = e.block.columns(&m, &jm_pose, &p, ctx);
        for (k, c) in scaled_columns(&e.block, &e.coefs, raw, &p, s, ctx)
            .iter()
            .enumerate()
        {
            je.set_column(off + k, c);
        }
        if let Block::Nonparametric(r) = &e.block {
            pred += r.correction(model, &ctx.q);
        }
        off += e.block.n_params();
    }
    PoseEval {
        pred: Point3::from(pred),
        jac_model: jm * s,
        jac_effects: je,
    }
}

/// `d pred / d θ_j` (tracker frame, mm/rad) of every joint `j` at one pose under `effects`
/// (the columns a joint-angle effect's regressors multiply: [`joint_columns`] through the
/// pose's model, times the tracker scale), `None` for a joint without an offset parameter.
pub fn joint_angle_columns(
    model: &KinematicModel,
    effects: &[Effect],
    ctx: &PoseCtx,
) -> Vec<Option<Vector3<f64>>> {
    let PoseBase { jm_pose, s, .. } = pose_base(model, None, effects, ctx);
    (0..model.dof())
        .map(|j| phi_index(model, j).map(|ip| jm_pose.column(ip) * s))
        .collect()
}

/// Columns (d point / d coef) of one block at one pose (see [`EffectModel::columns`]).
pub fn block_columns(
    block: &Block,
    model: &KinematicModel,
    jm: &Matrix3xX<f64>,
    p: &Point3<f64>,
    ctx: &PoseCtx,
) -> Vec<Vector3<f64>> {
    block.columns(model, jm, p, ctx)
}

/// A library effect as an extension of the kinematic identification
/// ([`crate::solve::kinematics::Effect`]): `solve::identify` refits it jointly with the
/// geometry on the same LM solver. Its correction is the exact change of the predicted
/// marker point the effect makes, `p(q, model, effect) − p(q, model)`, and its Jacobian the
/// effect's analytic columns ([`EffectModel::columns`] through [`eval_pose`]).
#[derive(Debug, Clone)]
pub struct LibraryEffect {
    pub block: Block,
    /// Starting coefficients (internal units; zeros by [`LibraryEffect::new`]).
    pub initial: Vec<f64>,
}

impl LibraryEffect {
    /// The effect with zero starting coefficients.
    pub fn new(block: Block) -> Self {
        let n = block.n_params();
        LibraryEffect {
            block,
            initial: vec![0.0; n],
        }
    }
}

impl crate::solve::kinematics::Effect for LibraryEffect {
    fn kind(&self) -> String {
        EffectModel::kind(&self.block).into()
    }
    fn param_names(&self) -> Vec<String> {
        self.block.param_names()
    }
    fn initial(&self) -> Vec<f64> {
        self.initial.clone()
    }
    fn point_correction(
        &self,
        model: &KinematicModel,
        obs: &PoseObs,
        theta: &[f64],
        jac: Option<&mut Matrix3xX<f64>>,
    ) -> Vector3<f64> {
        let e = Effect {
            block: self.block.clone(),
            coefs: theta.to_vec(),
            std: vec![f64::NAN; theta.len()],
            tau_std: f64::NAN,
        };
        let ev = eval_pose(model, std::slice::from_ref(&e), &obs.ctx);
        if let Some(j) = jac {
            if j.ncols() == ev.jac_effects.ncols() {
                j.copy_from(&ev.jac_effects);
            }
        }
        ev.pred.coords - model.measured_point(&obs.q).coords
    }
}

/// Predicted marker point of one pose from calibration-file effects (for `robocal predict`),
/// every effect held at the edge of `range` when given ([`apply_effects_held`]).
pub fn apply_cal_effects(
    model: &KinematicModel,
    effects: &[CalEffect],
    range: Option<&JointRange>,
    ctx: &PoseCtx,
) -> anyhow::Result<Point3<f64>> {
    let e = effects
        .iter()
        .map(Effect::from_cal)
        .collect::<Result<Vec<_>, _>>()?;
    Ok(apply_effects_held(model, &e, ctx, range))
}

/// Prediction of one pose record of `ds` with a calibration's effects (the hook of
/// `robocal predict`).
pub fn predict_record(
    model: &KinematicModel,
    effects: &[CalEffect],
    range: Option<&JointRange>,
    rec: &crate::dataset::PoseRecord,
    ds: &crate::dataset::Dataset,
) -> anyhow::Result<Point3<f64>> {
    let ctx = crate::solve::obs::record_context(rec, ds, model.dof()).ok_or_else(|| {
        anyhow::anyhow!(
            "pose {}: no usable joint angles `q` for the effects",
            rec.id
        )
    })?;
    apply_cal_effects(model, effects, range, &ctx)
}

impl Block {
    /// The link-length growth factor `1 + g·x` of a growth block (None for other blocks).
    pub fn growth(&self, coefs: &[f64], ctx: &PoseCtx) -> Option<f64> {
        let x = self.growth_driver(ctx)?;
        coefs.first().map(|g| 1.0 + g * x)
    }
}

/// The registry: every effect family, one line each (`Variant(type)`). It generates the
/// [`Block`] enum (one variant per family, wrapping the family's typed block), the dispatch
/// of [`EffectModel`] on `Block`, the calibration-file reader, the candidate library and
/// the list of examples the tests loop over. The order is the candidate order of the
/// diagnosis (per joint, then the global groups).
macro_rules! registry {
    ($($(#[$doc:meta])* $variant:ident($ty:ty),)*) => {
        /// One candidate effect, before its coefficients are known: one variant per family
        /// of the registry, wrapping the family's typed block.
        #[derive(Debug, Clone, PartialEq)]
        pub enum Block {
            $($(#[$doc])* $variant($ty),)*
        }

        impl Block {
            /// The family's implementation of [`EffectModel`].
            pub fn model(&self) -> &dyn EffectModel {
                match self {
                    $(Block::$variant(b) => b,)*
                }
            }
        }

        $(impl From<$ty> for Block {
            fn from(b: $ty) -> Block {
                Block::$variant(b)
            }
        })*

        /// Every kind name of the registry (a family may share its kind with another).
        pub const KINDS: &[&str] = &[$(<$ty as Family>::KIND,)*];

        /// The distinct kind names, comma-separated (for messages).
        pub fn known_kinds() -> String {
            let mut k: Vec<&str> = KINDS.to_vec();
            k.dedup();
            k.join(", ")
        }

        fn read_block(e: &CalEffect) -> Result<(Block, Vec<f64>, Vec<f64>), EffectFileError> {
            $(if <$ty as Family>::claims(e) {
                let (b, c, s) = <$ty as Family>::read(e)?;
                let n = b.n_params();
                if c.len() != n {
                    return Err(EffectFileError::invalid(
                        e,
                        format!("{} coefficients (need {n})", c.len()),
                    ));
                }
                let s = if s.len() == n { s } else { vec![f64::NAN; n] };
                return Ok((Block::$variant(b), c, s));
            })*
            Err(EffectFileError::UnknownKind(e.kind.clone()))
        }

        /// The candidate library of every family: for each joint the families' joint
        /// groups, then the families' global groups (registry order).
        pub fn registry_candidates(
            model: &KinematicModel,
            train: &[PoseObs],
            opt: &super::Options,
        ) -> Vec<Vec<Block>> {
            let mut groups: Vec<Vec<Block>> = Vec::new();
            for j in 1..=model.dof() {
                $(groups.extend(
                    <$ty as Family>::joint_candidates(model, opt, j)
                        .into_iter()
                        .map(|g| g.into_iter().map(Block::$variant).collect::<Vec<_>>()),
                );)*
            }
            $(groups.extend(<$ty as Family>::global_candidates(model, train, opt));)*
            groups
        }

        /// One fitted example of every family of the registry on `model`.
        pub fn registry_examples(model: &KinematicModel) -> Vec<Effect> {
            vec![$({
                let (b, c) = <$ty as Family>::example(model);
                let n = c.len();
                Effect {
                    block: Block::$variant(b),
                    coefs: c,
                    std: vec![1e-6; n],
                    tau_std: f64::NAN,
                }
            },)*]
        }
    };
}

impl EffectModel for Block {
    fn kind(&self) -> &'static str {
        self.model().kind()
    }
    fn joint(&self) -> Option<usize> {
        self.model().joint()
    }
    fn n_params(&self) -> usize {
        self.model().n_params()
    }
    fn param_names(&self) -> Vec<String> {
        self.model().param_names()
    }
    fn label(&self) -> String {
        self.model().label()
    }
    fn joint_features(&self, model: &KinematicModel, ctx: &PoseCtx) -> Vec<(usize, usize, f64)> {
        self.model().joint_features(model, ctx)
    }
    fn growth_driver(&self, ctx: &PoseCtx) -> Option<f64> {
        self.model().growth_driver(ctx)
    }
    fn apply_frame(&self, coefs: &[f64], out: &mut Cow<KinematicModel>, ctx: &PoseCtx) {
        self.model().apply_frame(coefs, out, ctx)
    }
    fn point_displacement(
        &self,
        model: &KinematicModel,
        coefs: &[f64],
        ctx: &PoseCtx,
    ) -> Option<Vector3<f64>> {
        self.model().point_displacement(model, coefs, ctx)
    }
    fn columns(
        &self,
        model: &KinematicModel,
        jm: &Matrix3xX<f64>,
        p: &Point3<f64>,
        ctx: &PoseCtx,
    ) -> Vec<Vector3<f64>> {
        self.model().columns(model, jm, p, ctx)
    }
    fn check_identifiable(&self, model: &KinematicModel, train: &[PoseObs]) -> Result<(), String> {
        self.model().check_identifiable(model, train)
    }
    fn parameters(&self, c: &Coefs) -> Vec<EffectParameter> {
        self.model().parameters(c)
    }
    fn file_params(&self, c: &Coefs) -> Map<String, Value> {
        self.model().file_params(c)
    }
    fn sentence(&self, c: &Coefs) -> String {
        self.model().sentence(c)
    }
    fn plot_driver(&self, model: &KinematicModel, o: &PoseObs) -> (f64, String) {
        self.model().plot_driver(model, o)
    }
}

registry! {
    /// Joint compliance under gravity (kind `joint_compliance`).
    Compliance(Compliance),
    /// Backlash / lost motion (kind `backlash`).
    Backlash(Backlash),
    /// Encoder/gear eccentricity, harmonics 1 and 2 (kind `joint_eccentricity`).
    Eccentricity(Eccentricity),
    /// Transmission-ratio error (kind `transmission_ratio`).
    Transmission(Transmission),
    /// Transmission ripple at harmonic ≥ 3 (kind `transmission_ripple`).
    Ripple(Ripple),
    /// A joint's transmission error over its turn, many harmonics with a smoothness prior
    /// (kind `transmission_error_map`; fitted after the chain, never a chain candidate).
    TransmissionMap(TransmissionMap),
    /// Link / bearing bending under the gravity moment (kind `link_deflection`).
    LinkDeflection(LinkDeflection),
    /// Joint-coupled angle error (kind `joint_coupling`).
    Coupling(Coupling),
    /// Harmonic-drive wave-generator harmonics (kind `wave_generator`).
    WaveGenerator(WaveGenerator),
    /// Temperature drift of lengths and offsets as one block (kind `temperature_drift`).
    TempDrift(TempDrift),
    /// Thermal offset drift of one joint (kind `thermal_drift` with a joint).
    JointDrift(JointDrift),
    /// Thermal growth of every link length (kind `thermal_drift` without a joint).
    LengthDrift(LengthDrift),
    /// Tracker scale about its origin (kind `tracker_scale`).
    TrackerScale(TrackerScale),
    /// Tracker depth scale along its viewing axis (kind `tracker_depth_scale`).
    TrackerDepthScale(TrackerDepthScale),
    /// Tracker–base shift after a change point (kind `base_shift`).
    BaseShift(BaseShift),
    /// Timing latency (kind `latency`).
    Latency(Latency),
    /// A data-driven correction of the joint-space residual (kind `nonparametric`).
    Nonparametric(Box<Rbf>),
}

#[cfg(test)]
mod tests;
