//! The effect library: physical effects a geometric model lacks, each as a block of
//! regressors that is linear in its coefficients, and the exact (nonlinear) way the fitted
//! effect changes a prediction.
//!
//! Internal units: mm, rad, s, kg, N·m. Calibration files use degrees (see [`Effect::to_cal`]).
//!
//! Prediction of a marker point with effects (tracker frame):
//! 1. joint-angle effects add `δθ_j = Σ_c coef_c · f_c(q, ctx)` to the measured angle `q_j`
//!    (compliance, backlash, eccentricity, per-joint thermal drift, latency);
//! 2. frame effects change the model used for that pose (base shift after a change point,
//!    thermal growth of link lengths);
//! 3. `tracker_scale` scales the point about the tracker origin: `y = (1 + s) p`;
//! 4. `nonparametric` adds a kernel correction of `q` (see [`super::nonparam`]).
use nalgebra::{Matrix3xX, Point3, Vector3};
use serde_json::{json, Map, Value};
use std::borrow::Cow;

use super::nonparam::Rbf;
use crate::dataset::CalEffect;
use crate::model::{KinematicModel, ParamGroup};
use crate::solve::obs::{PoseCtx, PoseObs};

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

/// One candidate effect, before its coefficients are known.
#[derive(Debug, Clone, PartialEq)]
pub enum Block {
    /// Joint compliance under gravity: `δθ_j = Σ_c coef_c τ_c(q)`, `τ_c` the gravity torque
    /// (N·m) about joint `j` of 1 kg at mass point `c` (coef: rad·kg/(N·m) = compliance × mass).
    Compliance {
        joint: usize,
        points: Vec<MassPoint>,
    },
    /// Backlash / lost motion: `δθ_j = b · s_j`, `s_j` the approach direction.
    Backlash { joint: usize },
    /// Encoder/gear eccentricity: `δθ_j = a1 sin q + b1 cos q + a2 sin 2q + b2 cos 2q`.
    Eccentricity { joint: usize },
    /// Thermal offset drift of one joint: `δθ_j = κ · x`, `x` the driver.
    JointDrift { joint: usize, driver: Driver },
    /// Thermal growth of every link length: `a_i, d_i ← (1 + g·x)·a_i, d_i`.
    LengthDrift { driver: Driver },
    /// Tracker scale about its origin.
    TrackerScale,
    /// Tracker–base shift: the base pose changes by a small twist after `t_change` (s).
    BaseShift { t_change: f64 },
    /// Timing latency: `y(t) = p(t − Δt)`, i.e. `δθ = −q̇ Δt` (needs recorded `qd`).
    Latency,
    /// Transmission ripple of one joint at harmonic `k` ≥ 3 of its rotation (gear tooth /
    /// bearing / harmonic-drive flexspline errors): `δθ_j = a sin kq + b cos kq`
    /// (kind `transmission_ripple`; harmonics 1 and 2 are `joint_eccentricity`).
    Ripple { joint: usize, harmonic: u32 },
    /// Transmission-ratio error of one joint: `δθ_j = ε · q_j` (kind `transmission_ratio`,
    /// not in the contract's list: a new name).
    Transmission { joint: usize },
    /// Link / bearing deflection under the full gravity wrench at joint `joint`: the part
    /// downstream of the joint rotates by `δφ = Σ_c coef_c M⊥_c(q)` about the joint origin,
    /// `M⊥_c` the gravity moment (N·m) of 1 kg at mass point `c` about the joint origin with
    /// its component along the joint axis removed (bending about the two axes orthogonal to
    /// the axis; the axial part is [`Block::Compliance`]). Isotropic bending compliance per
    /// mass point (coef: rad·kg/(N·m)). The gravity force at a joint is the same vector in
    /// every pose, so a shear displacement under it is a constant offset the base absorbs:
    /// only the moment is identifiable. Small-deflection (first-order) model: the marker
    /// moves by `R_base (δφ × (p − o_j))`, p and o_j at the measured angles (kind
    /// `link_deflection`).
    ///
    /// `anisotropic`: separate compliances for bending about the two link-fixed axes
    /// orthogonal to the joint axis (the `x` and `y` axes of MDH frame `joint`, which turn
    /// with the joint): `δφ = Σ_c (a_c (x·M⊥_c) x + b_c (y·M⊥_c) y)`, two coefficients per
    /// mass point (a link's cross-section and a bearing are stiffer one way than the other).
    LinkDeflection {
        joint: usize,
        points: Vec<MassPoint>,
        anisotropic: bool,
    },
    /// Joint-coupled error: the angle error of joint `joint` driven by the angle of joint
    /// `driver` (wrist cross-talk, cable/hose torque, encoder coupling):
    /// `δθ_joint = a sin q_driver + b cos q_driver` (kind `joint_coupling`).
    Coupling { joint: usize, driver: usize },
    /// Harmonic-drive wave-generator harmonics of joint `joint`: the wave generator turns
    /// `ratio` times per output turn, and its errors repeat `harmonic` times per wave-generator
    /// turn (1: wave-generator eccentricity, 2: the elliptical flexspline), so
    /// `δθ_j = a sin(h·N·q) + b cos(h·N·q)`, `N = ratio` (kind `wave_generator`).
    WaveGenerator {
        joint: usize,
        ratio: f64,
        harmonic: u32,
    },
    /// Temperature-driven drift of the whole arm as one block: every link length grows by
    /// `g·ΔT` and every joint offset drifts by `κ_j·ΔT`, `ΔT = temp_c − t0_c` (params
    /// `[g, κ_1..κ_n]`; kind `temperature_drift`).
    TempDrift { t0_c: f64 },
    /// A data-driven correction of the joint-space residual.
    Nonparametric(Box<Rbf>),
}

/// One effect of the library: the interface the diagnosis uses for every candidate and
/// fitted effect. A candidate is checked for identifiability on the data
/// ([`EffectModel::check_identifiable`]), scored by its columns of the same problem's
/// Jacobian ([`super::fit::DiagnoseProblem`], built from [`EffectModel::columns`]), and
/// refitted jointly with the geometry on the one LM solver ([`crate::solve::lm`]); the
/// finite-difference test of `diagnose::fit` checks those columns for every effect.
///
/// The library is the closed set of [`Block`] variants (each with its arm in every method
/// below), so calibration files round-trip by kind name.
pub trait EffectModel {
    /// Effect kind (the contract's names: `joint_compliance`, `backlash`, ...).
    fn kind(&self) -> &'static str;
    /// The joint (1-based) the effect belongs to, if any.
    fn joint(&self) -> Option<usize>;
    /// Number of linear parameters (coefficients).
    fn n_params(&self) -> usize;
    /// Names of the parameters with their internal unit (`name [unit]`).
    fn param_names(&self) -> Vec<String>;
    /// A short human label, e.g. `joint_compliance(j2)`.
    fn label(&self) -> String;
    /// Joint-angle regressor: `(joint index 0-based, parameter index, feature)` so that
    /// `δθ_joint += coef · feature`. Empty for effects that do not act on joint angles.
    fn joint_features(&self, model: &KinematicModel, ctx: &PoseCtx) -> Vec<(usize, usize, f64)>;
    /// Apply a frame effect (base shift, link growth) with coefficients `coefs` to the model
    /// one pose is predicted with; joint-angle effects leave it alone.
    fn apply_frame(&self, coefs: &[f64], model: &mut Cow<KinematicModel>, ctx: &PoseCtx);
    /// Analytic Jacobian: d point / d parameter at one pose, given the model the pose is
    /// evaluated with, its full parameter Jacobian `jm` and the point `p`.
    fn columns(
        &self,
        model: &KinematicModel,
        jm: &Matrix3xX<f64>,
        p: &Point3<f64>,
        ctx: &PoseCtx,
    ) -> Vec<Vector3<f64>>;
    /// Whether the data can identify the effect at all (`Err` says why not: no approach
    /// from both sides, a vertical axis with constant gravity torque, no joint velocity).
    /// The numerical identifiability against the model (independence of the columns) is
    /// part of the score.
    fn check_identifiable(&self, model: &KinematicModel, train: &[PoseObs]) -> Result<(), String>;
}

impl EffectModel for Block {
    /// Effect kind (the contract's names).
    fn kind(&self) -> &'static str {
        match self {
            Block::Compliance { .. } => "joint_compliance",
            Block::Backlash { .. } => "backlash",
            Block::Eccentricity { .. } => "joint_eccentricity",
            Block::JointDrift { .. } | Block::LengthDrift { .. } => "thermal_drift",
            Block::TrackerScale => "tracker_scale",
            Block::BaseShift { .. } => "base_shift",
            Block::Latency => "latency",
            Block::Transmission { .. } => "transmission_ratio",
            Block::Ripple { .. } => "transmission_ripple",
            Block::LinkDeflection { .. } => "link_deflection",
            Block::Coupling { .. } => "joint_coupling",
            Block::WaveGenerator { .. } => "wave_generator",
            Block::TempDrift { .. } => "temperature_drift",
            Block::Nonparametric(_) => "nonparametric",
        }
    }
    /// The joint (1-based) the effect belongs to, if any.
    fn joint(&self) -> Option<usize> {
        match self {
            Block::Compliance { joint, .. }
            | Block::Backlash { joint }
            | Block::Eccentricity { joint }
            | Block::Transmission { joint }
            | Block::Ripple { joint, .. }
            | Block::LinkDeflection { joint, .. }
            | Block::Coupling { joint, .. }
            | Block::WaveGenerator { joint, .. }
            | Block::JointDrift { joint, .. } => Some(*joint),
            _ => None,
        }
    }
    /// Number of linear coefficients.
    fn n_params(&self) -> usize {
        match self {
            Block::Compliance { points, .. } => points.len(),
            Block::LinkDeflection {
                points,
                anisotropic,
                ..
            } => points.len() * if *anisotropic { 2 } else { 1 },
            Block::Eccentricity { .. } => 4,
            Block::Ripple { .. } | Block::Coupling { .. } | Block::WaveGenerator { .. } => 2,
            // One growth rate and an offset rate per joint (the dof is not known here: the
            // library's arms have 6 joints; `TempDrift` sizes itself by `TEMP_DRIFT_JOINTS`).
            Block::TempDrift { .. } => 1 + TEMP_DRIFT_JOINTS,
            Block::BaseShift { .. } => 6,
            Block::Nonparametric(_) => 0,
            _ => 1,
        }
    }
    /// A short human label, e.g. `joint_compliance(j2)`.
    fn label(&self) -> String {
        let extra = match self {
            Block::JointDrift { driver, .. } | Block::LengthDrift { driver } => {
                format!(", {}", driver.label())
            }
            Block::BaseShift { t_change } => format!("t≥{t_change:.1}s"),
            Block::Ripple { harmonic, .. } => format!(", ×{harmonic}"),
            Block::Coupling { driver, .. } => format!(" ← q{driver}"),
            Block::WaveGenerator {
                ratio, harmonic, ..
            } => format!(", {harmonic}×N, N={ratio}"),
            Block::TempDrift { .. } => "lengths + offsets, temperature".into(),
            Block::LinkDeflection {
                anisotropic: true, ..
            } => ", link x/y".into(),
            _ => String::new(),
        };
        let lengths = if matches!(self, Block::LengthDrift { .. }) {
            "link lengths"
        } else {
            ""
        };
        match self.joint() {
            Some(j) => format!("{}(j{j}{extra})", EffectModel::kind(self)),
            None if extra.is_empty() && lengths.is_empty() => EffectModel::kind(self).to_string(),
            None if matches!(self, Block::TempDrift { .. }) => {
                format!("{}({extra})", EffectModel::kind(self))
            }
            None => format!("{}({lengths}{extra})", EffectModel::kind(self)),
        }
    }
    /// Names of the coefficients with their internal unit.
    fn param_names(&self) -> Vec<String> {
        match self {
            Block::Compliance { points, .. } => points
                .iter()
                .map(|p| format!("c·m@{} [rad·kg/Nm]", p.label()))
                .collect(),
            Block::Backlash { .. } => vec!["half lost motion [rad]".into()],
            Block::Eccentricity { .. } => vec![
                "sin q [rad]".into(),
                "cos q [rad]".into(),
                "sin 2q [rad]".into(),
                "cos 2q [rad]".into(),
            ],
            Block::JointDrift { driver, .. } => vec![format!("rate [rad/{}]", driver.unit())],
            Block::LengthDrift { driver } => vec![format!("growth [1/{}]", driver.unit())],
            Block::TrackerScale => vec!["scale [1]".into()],
            Block::BaseShift { .. } => [
                "dx [mm]",
                "dy [mm]",
                "dz [mm]",
                "drx [rad]",
                "dry [rad]",
                "drz [rad]",
            ]
            .iter()
            .map(|s| s.to_string())
            .collect(),
            Block::Latency => vec!["latency [s]".into()],
            Block::Transmission { .. } => vec!["ratio error [1]".into()],
            Block::Ripple { harmonic, .. } => {
                vec![
                    format!("sin {harmonic}q [rad]"),
                    format!("cos {harmonic}q [rad]"),
                ]
            }
            Block::LinkDeflection {
                points,
                anisotropic,
                ..
            } => points
                .iter()
                .flat_map(|p| {
                    if *anisotropic {
                        vec![
                            format!("c_bend_x·m@{} [rad·kg/Nm]", p.label()),
                            format!("c_bend_y·m@{} [rad·kg/Nm]", p.label()),
                        ]
                    } else {
                        vec![format!("c_bend·m@{} [rad·kg/Nm]", p.label())]
                    }
                })
                .collect(),
            Block::Coupling { driver, .. } => {
                vec![
                    format!("sin q{driver} [rad]"),
                    format!("cos q{driver} [rad]"),
                ]
            }
            Block::WaveGenerator { harmonic, .. } => vec![
                format!("sin {harmonic}Nq [rad]"),
                format!("cos {harmonic}Nq [rad]"),
            ],
            Block::TempDrift { .. } => std::iter::once("growth [1/K]".to_string())
                .chain((1..=TEMP_DRIFT_JOINTS).map(|j| format!("offset j{j} [rad/K]")))
                .collect(),
            Block::Nonparametric(_) => vec![],
        }
    }

    /// Sparse joint-angle regressors: `(joint index 0-based, coef index, feature)` so that
    /// `δθ_joint += coef · feature`. Empty for effects that do not act on joint angles.
    fn joint_features(&self, model: &KinematicModel, ctx: &PoseCtx) -> Vec<(usize, usize, f64)> {
        let n = model.dof();
        match self {
            Block::Compliance { joint, points } => {
                let j = *joint;
                if j == 0 || j > n {
                    return vec![];
                }
                gravity_torques(model, &ctx.q, j, points)
                    .into_iter()
                    .enumerate()
                    .map(|(c, tau)| (j - 1, c, tau))
                    .collect()
            }
            Block::Backlash { joint } => match ctx.approach.get(joint.wrapping_sub(1)) {
                Some(s) if *joint >= 1 && *joint <= n => vec![(joint - 1, 0, *s)],
                _ => vec![],
            },
            Block::Eccentricity { joint } => match ctx.q.get(joint.wrapping_sub(1)) {
                Some(&q) if *joint >= 1 && *joint <= n => vec![
                    (joint - 1, 0, q.sin()),
                    (joint - 1, 1, q.cos()),
                    (joint - 1, 2, (2.0 * q).sin()),
                    (joint - 1, 3, (2.0 * q).cos()),
                ],
                _ => vec![],
            },
            Block::Transmission { joint } => match ctx.q.get(joint.wrapping_sub(1)) {
                Some(&q) if *joint >= 1 && *joint <= n => vec![(joint - 1, 0, q)],
                _ => vec![],
            },
            Block::Ripple { joint, harmonic } => match ctx.q.get(joint.wrapping_sub(1)) {
                Some(&q) if *joint >= 1 && *joint <= n => {
                    let k = f64::from(*harmonic);
                    vec![(joint - 1, 0, (k * q).sin()), (joint - 1, 1, (k * q).cos())]
                }
                _ => vec![],
            },
            Block::JointDrift { joint, driver } if *joint >= 1 && *joint <= n => {
                vec![(joint - 1, 0, driver.value(ctx))]
            }
            Block::Coupling { joint, driver }
                if *joint >= 1 && *joint <= n && *driver >= 1 && *driver <= ctx.q.len() =>
            {
                let q = ctx.q[driver - 1];
                vec![(joint - 1, 0, q.sin()), (joint - 1, 1, q.cos())]
            }
            Block::WaveGenerator {
                joint,
                ratio,
                harmonic,
            } => match ctx.q.get(joint.wrapping_sub(1)) {
                Some(&q) if *joint >= 1 && *joint <= n => {
                    let w = f64::from(*harmonic) * ratio * q;
                    vec![(joint - 1, 0, w.sin()), (joint - 1, 1, w.cos())]
                }
                _ => vec![],
            },
            Block::TempDrift { t0_c } => {
                let x = ctx.temp_c.map(|t| t - t0_c).unwrap_or(0.0);
                (0..n.min(TEMP_DRIFT_JOINTS))
                    .map(|j| (j, 1 + j, x))
                    .collect()
            }
            Block::Latency => match &ctx.qd {
                Some(qd) => qd
                    .iter()
                    .take(n)
                    .enumerate()
                    .map(|(j, v)| (j, 0, -v))
                    .collect(),
                None => vec![],
            },
            _ => vec![],
        }
    }

    fn apply_frame(&self, coefs: &[f64], out: &mut Cow<KinematicModel>, ctx: &PoseCtx) {
        match self {
            Block::BaseShift { t_change } if ctx.t >= *t_change && coefs.len() == 6 => {
                let m = out.to_mut();
                for (k, sfx) in ["x", "y", "z", "rx", "ry", "rz"].iter().enumerate() {
                    let name = format!("base_{sfx}");
                    if let Some(v) = m.param(&name) {
                        let _ = m.set_param(&name, v + coefs[k]);
                    }
                }
            }
            Block::LengthDrift { .. } | Block::TempDrift { .. } if !coefs.is_empty() => {
                let f = self.growth(coefs, ctx).unwrap_or(1.0);
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
            _ => {}
        }
    }

    fn columns(
        &self,
        model: &KinematicModel,
        jm: &Matrix3xX<f64>,
        p: &Point3<f64>,
        ctx: &PoseCtx,
    ) -> Vec<Vector3<f64>> {
        let mut cols = vec![Vector3::zeros(); self.n_params()];
        for (j, c, f) in self.joint_features(model, ctx) {
            if let Some(ip) = phi_index(model, j) {
                cols[c] += jm.column(ip) * f;
            }
        }
        match self {
            Block::BaseShift { t_change } if ctx.t >= *t_change => {
                for (k, sfx) in ["x", "y", "z", "rx", "ry", "rz"].iter().enumerate() {
                    if let Some(ip) = model.param_index(&format!("base_{sfx}")) {
                        cols[k] = jm.column(ip).into_owned();
                    }
                }
            }
            Block::LengthDrift { .. } | Block::TempDrift { .. } => {
                let x = self.growth_driver(ctx);
                for (i, pr) in model.params().iter().enumerate() {
                    if is_length(pr) {
                        cols[0] += jm.column(i) * (pr.value * x);
                    }
                }
            }
            Block::LinkDeflection {
                joint,
                points,
                anisotropic,
            } => {
                let (rb, lever, dirs) =
                    deflection_terms(model, &ctx.q, *joint, points, *anisotropic);
                for (c, d) in dirs.iter().enumerate() {
                    cols[c] = rb * d.cross(&lever);
                }
            }
            Block::TrackerScale => cols[0] = p.coords,
            _ => {}
        }
        cols
    }

    fn check_identifiable(&self, model: &KinematicModel, train: &[PoseObs]) -> Result<(), String> {
        match self {
            Block::Compliance { joint, points } => {
                // A vertical axis carries a constant gravity torque: absorbed by the offset.
                let taus: Vec<f64> = train
                    .iter()
                    .map(|o| gravity_torques(model, &o.q, *joint, points).iter().sum())
                    .collect();
                let n = taus.len().max(1) as f64;
                let m = taus.iter().sum::<f64>() / n;
                let sd = (taus.iter().map(|t| (t - m).powi(2)).sum::<f64>() / n).sqrt();
                if points.is_empty() || sd <= 0.05 {
                    return Err(format!(
                        "the gravity torque about joint {joint} hardly varies over the poses (sd {sd:.3} N·m per kg)"
                    ));
                }
                Ok(())
            }
            Block::LinkDeflection { joint, points, .. } => {
                // The bending moment must vary over the poses (its direction or size).
                let m: Vec<Vector3<f64>> = train
                    .iter()
                    .map(|o| {
                        deflection_terms(model, &o.q, *joint, points, false)
                            .2
                            .iter()
                            .sum::<Vector3<f64>>()
                    })
                    .collect();
                let n = m.len().max(1) as f64;
                let mean = m.iter().sum::<Vector3<f64>>() / n;
                let sd = (m.iter().map(|v| (v - mean).norm_squared()).sum::<f64>() / n).sqrt();
                if points.is_empty() || sd <= 0.05 {
                    return Err(format!(
                        "the bending moment at joint {joint} hardly varies over the poses (sd {sd:.3} N·m per kg)"
                    ));
                }
                Ok(())
            }
            Block::Coupling { joint, driver } => {
                let sd = spread(train.iter().filter_map(|o| o.q.get(driver - 1).copied()));
                if joint == driver || sd < 0.1 {
                    return Err(format!(
                        "joint {driver} hardly moves (sd {:.2}°): it cannot drive joint {joint}",
                        sd.to_degrees()
                    ));
                }
                Ok(())
            }
            Block::WaveGenerator {
                joint,
                ratio,
                harmonic,
            } => {
                // The phase h·N·q must cover the circle: the joint must move over more than one
                // wave-generator period across the poses.
                let sd = spread(train.iter().filter_map(|o| o.q.get(joint - 1).copied()));
                let period = std::f64::consts::TAU / (f64::from(*harmonic) * ratio);
                if ratio.is_nan() || *ratio <= 0.0 || sd < 2.0 * period {
                    return Err(format!(
                        "joint {joint} moves less than two wave-generator periods (sd {:.3}°, period {:.3}°)",
                        sd.to_degrees(),
                        period.to_degrees()
                    ));
                }
                Ok(())
            }
            Block::Ripple { joint, harmonic } if *harmonic > 4 => {
                // A high harmonic needs the joint to sweep at least one of its periods (else
                // it is a smooth function of q over the data, confounded with the offset and
                // eccentricity).
                let sd = spread(train.iter().filter_map(|o| o.q.get(joint - 1).copied()));
                let period = std::f64::consts::TAU / f64::from(*harmonic);
                if sd < period {
                    return Err(format!(
                        "joint {joint} moves less than one period of harmonic {harmonic} (sd {:.2}°, period {:.2}°)",
                        sd.to_degrees(),
                        period.to_degrees()
                    ));
                }
                Ok(())
            }
            Block::TempDrift { .. } => {
                let t: Vec<f64> = train.iter().filter_map(|o| o.temp_c).collect();
                if t.len() < train.len() || t.is_empty() {
                    return Err("not every record carries temp_c".into());
                }
                let (lo, hi) = (
                    t.iter().copied().fold(f64::INFINITY, f64::min),
                    t.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                );
                if hi - lo < 0.5 {
                    return Err(format!(
                        "temp_c spans only {:.2} °C (need ≥ 0.5 °C)",
                        hi - lo
                    ));
                }
                Ok(())
            }
            Block::Backlash { joint } => {
                let side = |s: f64| {
                    train
                        .iter()
                        .filter(|o| o.approach.get(joint - 1) == Some(&s))
                        .count()
                };
                let (plus, minus) = (side(1.0), side(-1.0));
                if plus >= 5 && minus >= 5 {
                    Ok(())
                } else {
                    Err(format!(
                        "joint {joint} is approached {plus}× from below and {minus}× from above (need ≥ 5 each)"
                    ))
                }
            }
            Block::Latency => {
                let with_qd = train.iter().filter(|o| o.qd.is_some()).count();
                if with_qd * 2 >= train.len() && with_qd > 0 {
                    Ok(())
                } else {
                    Err("records carry no joint velocity (stop-and-measure data): latency is unobservable and irrelevant".into())
                }
            }
            Block::JointDrift { driver, .. } | Block::LengthDrift { driver } => {
                let (lo, hi) = match driver {
                    Driver::Temp { .. } => {
                        let t: Vec<f64> = train.iter().filter_map(|o| o.temp_c).collect();
                        if t.len() < train.len() || t.is_empty() {
                            return Err("not every record carries temp_c".into());
                        }
                        (
                            t.iter().copied().fold(f64::INFINITY, f64::min),
                            t.iter().copied().fold(f64::NEG_INFINITY, f64::max) - 0.5,
                        )
                    }
                    _ => (
                        train.iter().map(|o| o.t).fold(f64::INFINITY, f64::min),
                        train.iter().map(|o| o.t).fold(f64::NEG_INFINITY, f64::max) - 60.0,
                    ),
                };
                if hi > lo {
                    Ok(())
                } else {
                    Err("the session spans less than a minute (or 0.5 °C)".into())
                }
            }
            _ => Ok(()),
        }
    }
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

/// Joints a [`Block::TempDrift`] carries an offset rate for (the library's arms: 6).
pub const TEMP_DRIFT_JOINTS: usize = 6;

/// Standard deviation of a sample.
fn spread(v: impl Iterator<Item = f64>) -> f64 {
    let v: Vec<f64> = v.collect();
    let n = v.len().max(1) as f64;
    let m = v.iter().sum::<f64>() / n;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n).sqrt()
}

impl Block {
    /// Driver of a link-growth block at one pose (0 for other blocks).
    fn growth_driver(&self, ctx: &PoseCtx) -> f64 {
        match self {
            Block::LengthDrift { driver } => driver.value(ctx),
            Block::TempDrift { t0_c } => ctx.temp_c.map(|t| t - t0_c).unwrap_or(0.0),
            _ => 0.0,
        }
    }
    /// The link-length growth factor `1 + g·x` of a growth block (None for other blocks).
    pub fn growth(&self, coefs: &[f64], ctx: &PoseCtx) -> Option<f64> {
        match self {
            Block::LengthDrift { .. } | Block::TempDrift { .. } => {
                coefs.first().map(|g| 1.0 + g * self.growth_driver(ctx))
            }
            _ => None,
        }
    }
}

/// The terms of a [`Block::LinkDeflection`] at `q`: the base rotation (tracker ← robot
/// base), the lever from the joint origin to the marker (robot base, mm) and, per mass
/// point, the bending moment of 1 kg about the joint origin with its axial component
/// removed (N·m per kg, robot base frame). The marker moves by
/// `R_base (Σ_c coef_c M⊥_c) × lever`. `anisotropic`: two terms per mass point, the
/// components of `M⊥_c` along the link-fixed `x` and `y` axes of frame `joint`
/// (`(x·M⊥_c) x`, `(y·M⊥_c) y`), one coefficient each.
pub fn deflection_terms(
    model: &KinematicModel,
    q: &[f64],
    joint: usize,
    points: &[MassPoint],
    anisotropic: bool,
) -> (nalgebra::Rotation3<f64>, Vector3<f64>, Vec<Vector3<f64>>) {
    let n = model.dof();
    let fj = model.joint_frame(q, joint.min(n));
    let z = fj.rotation * Vector3::z();
    let o = fj.translation.vector;
    let g = Vector3::from(GRAVITY_DIR) * GRAVITY;
    let marker = model.tool_pose_in_base(q).translation.vector;
    let dirs = points
        .iter()
        .map(|p| {
            let c = match p {
                MassPoint::Frame(k) => model.joint_frame(q, (*k).min(n)).translation.vector,
                MassPoint::Flange => model.flange_pose(q).translation.vector,
                MassPoint::Marker => marker,
            };
            let m = ((c - o) * 1e-3).cross(&g);
            m - z * z.dot(&m)
        })
        .flat_map(|m: Vector3<f64>| {
            if anisotropic {
                let x = fj.rotation * Vector3::x();
                let y = fj.rotation * Vector3::y();
                vec![x * x.dot(&m), y * y.dot(&m)]
            } else {
                vec![m]
            }
        })
        .collect();
    (model.base().rotation.to_rotation_matrix(), marker - o, dirs)
}

/// Marker displacement (tracker frame, mm) of the point-displacement effects (link
/// deflection) of `effects` at one pose, predicted with `model`.
pub fn point_displacement(
    model: &KinematicModel,
    effects: &[Effect],
    ctx: &PoseCtx,
) -> Vector3<f64> {
    let mut d = Vector3::zeros();
    for e in effects {
        if let Block::LinkDeflection {
            joint,
            points,
            anisotropic,
        } = &e.block
        {
            let (rb, lever, dirs) = deflection_terms(model, &ctx.q, *joint, points, *anisotropic);
            let phi: Vector3<f64> = dirs.iter().zip(&e.coefs).map(|(m, c)| m * *c).sum();
            d += rb * phi.cross(&lever);
        }
    }
    d
}

/// Whether a model parameter is a link length (`a_i`, `d_i`), which thermal growth scales.
fn is_length(p: &crate::model::Param) -> bool {
    matches!(p.group, ParamGroup::Joint(_))
        && (p.name.starts_with('a') && !p.name.starts_with("alpha") || p.name.starts_with('d'))
}

/// Gravity torque (N·m) about joint `joint` (1-based) of 1 kg at each mass point, at `q`.
pub fn gravity_torques(
    model: &KinematicModel,
    q: &[f64],
    joint: usize,
    points: &[MassPoint],
) -> Vec<f64> {
    let n = model.dof();
    let fj = model.joint_frame(q, joint.min(n));
    let z = fj.rotation * Vector3::z();
    let o = fj.translation.vector;
    let g = Vector3::from(GRAVITY_DIR) * GRAVITY;
    points
        .iter()
        .map(|p| {
            let c = match p {
                MassPoint::Frame(k) => model.joint_frame(q, (*k).min(n)).translation.vector,
                MassPoint::Flange => model.flange_pose(q).translation.vector,
                MassPoint::Marker => model.tool_pose_in_base(q).translation.vector,
            };
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

fn tau_param(d: &Driver, tau_std: f64) -> Option<crate::schema::EffectParameter> {
    match d {
        Driver::WarmUp { tau_s, .. } => Some(crate::schema::EffectParameter::new(
            "tau", "s", *tau_s, tau_std,
        )),
        _ => None,
    }
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
}

/// `δθ` (rad, per joint) of all joint-angle effects at one pose.
pub fn joint_offsets(model: &KinematicModel, effects: &[Effect], ctx: &PoseCtx) -> Vec<f64> {
    let mut d = vec![0.0; model.dof()];
    for e in effects {
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
    for e in effects {
        e.block.apply_frame(&e.coefs, &mut out, ctx);
    }
    out
}

fn tracker_scale(effects: &[Effect]) -> f64 {
    effects
        .iter()
        .filter(|e| matches!(e.block, Block::TrackerScale))
        .filter_map(|e| e.coefs.first())
        .sum()
}

/// Predicted marker origin (mm, tracker frame) of one pose with all effects applied.
pub fn apply_effects(model: &KinematicModel, effects: &[Effect], ctx: &PoseCtx) -> Point3<f64> {
    let d = joint_offsets(model, effects, ctx);
    let th: Vec<f64> = ctx.q.iter().zip(d.iter()).map(|(q, d)| q + d).collect();
    let m = pose_model(model, effects, ctx);
    let p = m.measured_point(&th).coords + point_displacement(&m, effects, ctx);
    let mut y = p * (1.0 + tracker_scale(effects));
    for e in effects {
        if let Block::Nonparametric(r) = &e.block {
            y += r.correction(model, &ctx.q);
        }
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

/// Evaluate one pose (see [`PoseEval`]).
pub fn eval_pose(model: &KinematicModel, effects: &[Effect], ctx: &PoseCtx) -> PoseEval {
    let d = joint_offsets(model, effects, ctx);
    let th: Vec<f64> = ctx.q.iter().zip(d.iter()).map(|(q, d)| q + d).collect();
    let m = pose_model(model, effects, ctx);
    let (p0, jm_pose) = m.point_param_jacobian(&th);
    // Link deflection adds a displacement linear in its coefficients; its dependence on
    // the geometry (a second-order cross term) is left out of the model columns.
    let p = p0 + point_displacement(&m, effects, ctx);
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
    let s = 1.0 + tracker_scale(effects);
    let mut pred = p.coords * s;
    let ncol: usize = effects.iter().map(|e| e.block.n_params()).sum();
    let mut je = Matrix3xX::zeros(ncol);
    let mut off = 0;
    for e in effects {
        let mut cols = block_columns(&e.block, &m, &jm_pose, &p, ctx);
        if matches!(e.block, Block::LengthDrift { .. } | Block::TempDrift { .. }) {
            // `m` holds the grown lengths a'_i = a_i·growth; the column needs a_i.
            cols[0] /= e.block.growth(&e.coefs, ctx).unwrap_or(1.0);
        }
        for (k, c) in cols.iter().enumerate() {
            je.set_column(off + k, &(c * s));
        }
        if let Block::TrackerScale = e.block {
            // d/ds of (1+s)p is p itself, not scaled again
            je.set_column(off, &p.coords);
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

// ---------------------------------------------------------------------- file form

fn num(v: f64) -> Value {
    if v.is_finite() {
        json!(v)
    } else {
        Value::Null
    }
}

impl Effect {
    /// The coefficients in file units (degrees for angles, ppm for ratios), each with its
    /// standard deviation and 95 % interval (`diagnosis.json`).
    pub fn parameters(&self) -> Vec<crate::schema::EffectParameter> {
        use crate::schema::EffectParameter as P;
        let c = &self.coefs;
        let s = |k: usize| self.std.get(k).copied().unwrap_or(f64::NAN);
        let deg = |v: f64| v.to_degrees();
        match &self.block {
            Block::Compliance { points, .. } => points
                .iter()
                .enumerate()
                .map(|(k, pt)| {
                    P::new(
                        &format!("c_times_mass@{}", pt.label()),
                        "deg*kg/(N*m)",
                        deg(c[k]),
                        deg(s(k)),
                    )
                })
                .collect(),
            Block::Backlash { .. } => vec![P::new("half_lost_motion", "deg", deg(c[0]), deg(s(0)))],
            Block::Eccentricity { .. } => ["sin1", "cos1", "sin2", "cos2"]
                .iter()
                .enumerate()
                .map(|(k, n)| P::new(n, "deg", deg(c[k]), deg(s(k))))
                .collect(),
            Block::JointDrift { driver, .. } => {
                let mut v = vec![P::new(
                    "rate",
                    &format!("deg/{}", driver.unit()),
                    deg(c[0]),
                    deg(s(0)),
                )];
                v.extend(tau_param(driver, self.tau_std));
                v
            }
            Block::LengthDrift { driver } => {
                let mut v = vec![P::new(
                    "growth",
                    &format!("ppm/{}", driver.unit()),
                    c[0] * 1e6,
                    s(0) * 1e6,
                )];
                v.extend(tau_param(driver, self.tau_std));
                v
            }
            Block::TrackerScale => vec![P::new("scale", "ppm", c[0] * 1e6, s(0) * 1e6)],
            Block::BaseShift { t_change } => {
                let mut v = vec![P::new("t_change", "s", *t_change, f64::NAN)];
                for (k, n) in ["dx", "dy", "dz"].iter().enumerate() {
                    v.push(P::new(n, "mm", c[k], s(k)));
                }
                for (k, n) in ["drx", "dry", "drz"].iter().enumerate() {
                    v.push(P::new(n, "deg", deg(c[3 + k]), deg(s(3 + k))));
                }
                v
            }
            Block::Latency => vec![P::new("latency", "s", c[0], s(0))],
            Block::Transmission { .. } => {
                vec![P::new("ratio_error", "ppm", c[0] * 1e6, s(0) * 1e6)]
            }
            Block::Ripple { harmonic, .. } => vec![
                P::new(&format!("sin{harmonic}"), "deg", deg(c[0]), deg(s(0))),
                P::new(&format!("cos{harmonic}"), "deg", deg(c[1]), deg(s(1))),
            ],
            Block::LinkDeflection {
                points,
                anisotropic,
                ..
            } => {
                let axes: &[&str] = if *anisotropic { &["_x", "_y"] } else { &[""] };
                points
                    .iter()
                    .flat_map(|pt| axes.iter().map(move |a| (pt, *a)))
                    .enumerate()
                    .map(|(k, (pt, a))| {
                        P::new(
                            &format!("c_bend{a}_times_mass@{}", pt.label()),
                            "deg*kg/(N*m)",
                            deg(c[k]),
                            deg(s(k)),
                        )
                    })
                    .collect()
            }
            Block::Coupling { driver, .. } => vec![
                P::new(&format!("sin_q{driver}"), "deg", deg(c[0]), deg(s(0))),
                P::new(&format!("cos_q{driver}"), "deg", deg(c[1]), deg(s(1))),
            ],
            Block::WaveGenerator { ratio, .. } => vec![
                P::new("ratio", "1", *ratio, f64::NAN),
                P::new("sin", "deg", deg(c[0]), deg(s(0))),
                P::new("cos", "deg", deg(c[1]), deg(s(1))),
            ],
            Block::TempDrift { t0_c } => {
                let mut v = vec![
                    P::new("t0", "degC", *t0_c, f64::NAN),
                    P::new("growth", "ppm/K", c[0] * 1e6, s(0) * 1e6),
                ];
                for (k, ck) in c.iter().enumerate().skip(1) {
                    v.push(P::new(
                        &format!("offset_j{k}"),
                        "deg/K",
                        deg(*ck),
                        deg(s(k)),
                    ));
                }
                v
            }
            Block::Nonparametric(_) => vec![],
        }
    }

    /// The calibration-file form (degrees where the internal unit is rad).
    pub fn to_cal(&self) -> CalEffect {
        let mut p = Map::new();
        let c = &self.coefs;
        let s = &self.std;
        let deg = |v: f64| v.to_degrees();
        match &self.block {
            Block::Compliance { points, .. } => {
                p.insert("model".into(), json!("gravity_point_masses"));
                p.insert("gravity_dir".into(), json!(GRAVITY_DIR));
                p.insert(
                    "points".into(),
                    json!(points.iter().map(|x| x.label()).collect::<Vec<_>>()),
                );
                p.insert(
                    "c_times_mass_deg_kg_per_nm".into(),
                    json!(c.iter().map(|v| deg(*v)).collect::<Vec<_>>()),
                );
                p.insert(
                    "c_times_mass_std".into(),
                    json!(s.iter().map(|v| num(deg(*v))).collect::<Vec<_>>()),
                );
                p.insert(
                    "sum_c_times_mass_deg_kg_per_nm".into(),
                    json!(deg(c.iter().sum::<f64>())),
                );
            }
            Block::Backlash { .. } => {
                p.insert("half_lost_motion_deg".into(), num(deg(c[0])));
                p.insert("half_lost_motion_std".into(), num(deg(s[0])));
            }
            Block::Eccentricity { .. } => {
                for (k, nm) in ["sin1_deg", "cos1_deg", "sin2_deg", "cos2_deg"]
                    .iter()
                    .enumerate()
                {
                    p.insert((*nm).into(), num(deg(c[k])));
                }
                p.insert(
                    "std_deg".into(),
                    json!(s.iter().map(|v| num(deg(*v))).collect::<Vec<_>>()),
                );
            }
            Block::JointDrift { driver, .. } | Block::LengthDrift { driver } => {
                match driver {
                    Driver::Time { t0_s } => {
                        p.insert("driver".into(), json!("time"));
                        p.insert("t0_s".into(), num(*t0_s));
                    }
                    Driver::WarmUp { t0_s, tau_s } => {
                        p.insert("driver".into(), json!("warm_up"));
                        p.insert("t0_s".into(), num(*t0_s));
                        p.insert("tau_s".into(), num(*tau_s));
                    }
                    Driver::Temp { t0_c } => {
                        p.insert("driver".into(), json!("temp_c"));
                        p.insert("t0_c".into(), num(*t0_c));
                    }
                }
                if matches!(self.block, Block::JointDrift { .. }) {
                    p.insert(format!("deg_per_{}", driver.unit()), num(deg(c[0])));
                    p.insert("std".into(), num(deg(s[0])));
                } else {
                    p.insert("target".into(), json!("link_lengths"));
                    p.insert(format!("ppm_per_{}", driver.unit()), num(c[0] * 1e6));
                    p.insert("std".into(), num(s[0] * 1e6));
                }
            }
            Block::TrackerScale => {
                p.insert("scale_ppm".into(), num(c[0] * 1e6));
                p.insert("std".into(), num(s[0] * 1e6));
            }
            Block::BaseShift { t_change } => {
                p.insert("t_change_s".into(), num(*t_change));
                for (k, nm) in ["dx_mm", "dy_mm", "dz_mm"].iter().enumerate() {
                    p.insert((*nm).into(), num(c[k]));
                }
                for (k, nm) in ["drx_deg", "dry_deg", "drz_deg"].iter().enumerate() {
                    p.insert((*nm).into(), num(deg(c[3 + k])));
                }
                p.insert(
                    "std".into(),
                    json!(s
                        .iter()
                        .enumerate()
                        .map(|(k, v)| num(if k < 3 { *v } else { deg(*v) }))
                        .collect::<Vec<_>>()),
                );
            }
            Block::Transmission { .. } => {
                p.insert("ratio_error_ppm".into(), num(c[0] * 1e6));
                p.insert("std".into(), num(s[0] * 1e6));
            }
            Block::Ripple { harmonic, .. } => {
                p.insert("harmonic".into(), json!(harmonic));
                p.insert("sin_deg".into(), num(deg(c[0])));
                p.insert("cos_deg".into(), num(deg(c[1])));
                p.insert(
                    "std_deg".into(),
                    json!(s.iter().map(|v| num(deg(*v))).collect::<Vec<_>>()),
                );
            }
            Block::Latency => {
                p.insert("latency_s".into(), num(c[0]));
                p.insert("std".into(), num(s[0]));
            }
            Block::LinkDeflection {
                points,
                anisotropic,
                ..
            } => {
                p.insert("model".into(), json!("gravity_bending_point_masses"));
                // Anisotropic: coefficients in point order, x then y of each point.
                p.insert(
                    "axes".into(),
                    json!(if *anisotropic {
                        "link_x_y"
                    } else {
                        "isotropic"
                    }),
                );
                p.insert("gravity_dir".into(), json!(GRAVITY_DIR));
                p.insert(
                    "points".into(),
                    json!(points.iter().map(|x| x.label()).collect::<Vec<_>>()),
                );
                p.insert(
                    "c_bend_times_mass_deg_kg_per_nm".into(),
                    json!(c.iter().map(|v| deg(*v)).collect::<Vec<_>>()),
                );
                p.insert(
                    "std".into(),
                    json!(s.iter().map(|v| num(deg(*v))).collect::<Vec<_>>()),
                );
            }
            Block::Coupling { driver, .. } => {
                p.insert("driver_joint".into(), json!(driver));
                p.insert("sin_deg".into(), num(deg(c[0])));
                p.insert("cos_deg".into(), num(deg(c[1])));
                p.insert(
                    "std_deg".into(),
                    json!(s.iter().map(|v| num(deg(*v))).collect::<Vec<_>>()),
                );
            }
            Block::WaveGenerator {
                ratio, harmonic, ..
            } => {
                p.insert("gear_ratio".into(), num(*ratio));
                p.insert("harmonic".into(), json!(harmonic));
                p.insert("sin_deg".into(), num(deg(c[0])));
                p.insert("cos_deg".into(), num(deg(c[1])));
                p.insert(
                    "std_deg".into(),
                    json!(s.iter().map(|v| num(deg(*v))).collect::<Vec<_>>()),
                );
            }
            Block::TempDrift { t0_c } => {
                p.insert("t0_c".into(), num(*t0_c));
                p.insert("growth_ppm_per_k".into(), num(c[0] * 1e6));
                p.insert(
                    "offset_deg_per_k".into(),
                    json!(c[1..].iter().map(|v| num(deg(*v))).collect::<Vec<_>>()),
                );
                p.insert(
                    "std".into(),
                    json!(s
                        .iter()
                        .enumerate()
                        .map(|(k, v)| num(if k == 0 { v * 1e6 } else { deg(*v) }))
                        .collect::<Vec<_>>()),
                );
            }
            Block::Nonparametric(r) => {
                p = r.to_json();
            }
        }
        CalEffect {
            kind: self.block.kind().into(),
            joint: self.block.joint(),
            params: p,
            extra: Map::new(),
        }
    }

    /// Read an effect from its calibration-file form.
    pub fn from_cal(e: &CalEffect) -> anyhow::Result<Effect> {
        let p = &e.params;
        let f = |k: &str| -> anyhow::Result<f64> {
            p.get(k)
                .and_then(|v| v.as_f64())
                .filter(|v| v.is_finite())
                .ok_or_else(|| anyhow::anyhow!("effect {}: missing or bad number \"{k}\"", e.kind))
        };
        let arr = |k: &str| -> anyhow::Result<Vec<f64>> {
            let a = p
                .get(k)
                .and_then(|v| v.as_array())
                .ok_or_else(|| anyhow::anyhow!("effect {}: missing array \"{k}\"", e.kind))?;
            a.iter()
                .map(|v| {
                    v.as_f64()
                        .filter(|x| x.is_finite())
                        .ok_or_else(|| anyhow::anyhow!("effect {}: bad number in \"{k}\"", e.kind))
                })
                .collect()
        };
        let joint = || {
            e.joint
                .filter(|j| *j >= 1)
                .ok_or_else(|| anyhow::anyhow!("effect {}: needs a joint (1-based)", e.kind))
        };
        let driver = || -> anyhow::Result<Driver> {
            match p.get("driver").and_then(|v| v.as_str()) {
                Some("temp_c") => Ok(Driver::Temp { t0_c: f("t0_c")? }),
                Some("warm_up") => Ok(Driver::WarmUp {
                    t0_s: f("t0_s")?,
                    tau_s: f("tau_s")?.max(1e-9),
                }),
                _ => Ok(Driver::Time { t0_s: f("t0_s")? }),
            }
        };
        let rad = |v: f64| v.to_radians();
        // Mass points and their per-point coefficients (deg·kg/(N·m) in the file, rad inside).
        let mass_points =
            |coef_key: &str, per_point: usize| -> anyhow::Result<(Vec<MassPoint>, Vec<f64>)> {
                let pts = p
                    .get("points")
                    .and_then(|v| v.as_array())
                    .ok_or_else(|| anyhow::anyhow!("{}: missing \"points\"", e.kind))?
                    .iter()
                    .map(|v| {
                        v.as_str()
                            .and_then(MassPoint::parse)
                            .ok_or_else(|| anyhow::anyhow!("{}: bad point {v}", e.kind))
                    })
                    .collect::<anyhow::Result<Vec<_>>>()?;
                let c: Vec<f64> = arr(coef_key)?.into_iter().map(rad).collect();
                if c.len() != pts.len() * per_point {
                    anyhow::bail!(
                        "{}: {} points but {} coefficients (need {} per point)",
                        e.kind,
                        pts.len(),
                        c.len(),
                        per_point
                    );
                }
                Ok((pts, c))
            };
        let (block, coefs) = match e.kind.as_str() {
            "joint_compliance" => {
                let (pts, c) = mass_points("c_times_mass_deg_kg_per_nm", 1)?;
                (
                    Block::Compliance {
                        joint: joint()?,
                        points: pts,
                    },
                    c,
                )
            }
            "backlash" => (
                Block::Backlash { joint: joint()? },
                vec![rad(f("half_lost_motion_deg")?)],
            ),
            "joint_eccentricity" => (
                Block::Eccentricity { joint: joint()? },
                vec![
                    rad(f("sin1_deg")?),
                    rad(f("cos1_deg")?),
                    rad(f("sin2_deg")?),
                    rad(f("cos2_deg")?),
                ],
            ),
            "thermal_drift" => {
                let d = driver()?;
                let unit = d.unit();
                if e.joint.is_some() {
                    (
                        Block::JointDrift {
                            joint: joint()?,
                            driver: d,
                        },
                        vec![rad(f(&format!("deg_per_{unit}"))?)],
                    )
                } else {
                    (
                        Block::LengthDrift { driver: d },
                        vec![f(&format!("ppm_per_{unit}"))? * 1e-6],
                    )
                }
            }
            "tracker_scale" => (Block::TrackerScale, vec![f("scale_ppm")? * 1e-6]),
            "base_shift" => (
                Block::BaseShift {
                    t_change: f("t_change_s")?,
                },
                vec![
                    f("dx_mm")?,
                    f("dy_mm")?,
                    f("dz_mm")?,
                    rad(f("drx_deg")?),
                    rad(f("dry_deg")?),
                    rad(f("drz_deg")?),
                ],
            ),
            "latency" => (Block::Latency, vec![f("latency_s")?]),
            "transmission_ratio" => (
                Block::Transmission { joint: joint()? },
                vec![f("ratio_error_ppm")? * 1e-6],
            ),
            "transmission_ripple" => {
                let harmonic = p
                    .get("harmonic")
                    .and_then(|v| v.as_u64())
                    .filter(|h| (1..=100_000).contains(h))
                    .ok_or_else(|| {
                        anyhow::anyhow!("transmission_ripple: \"harmonic\" must be an integer ≥ 1")
                    })? as u32;
                (
                    Block::Ripple {
                        joint: joint()?,
                        harmonic,
                    },
                    vec![rad(f("sin_deg")?), rad(f("cos_deg")?)],
                )
            }
            "link_deflection" => {
                let anisotropic = match p.get("axes").and_then(|v| v.as_str()) {
                    None | Some("isotropic") => false,
                    Some("link_x_y") => true,
                    Some(other) => anyhow::bail!(
                        "link_deflection: \"axes\" must be \"isotropic\" or \"link_x_y\" (got \"{other}\")"
                    ),
                };
                let (pts, c) = mass_points(
                    "c_bend_times_mass_deg_kg_per_nm",
                    if anisotropic { 2 } else { 1 },
                )?;
                (
                    Block::LinkDeflection {
                        joint: joint()?,
                        points: pts,
                        anisotropic,
                    },
                    c,
                )
            }
            "joint_coupling" => {
                let driver = p
                    .get("driver_joint")
                    .and_then(|v| v.as_u64())
                    .filter(|d| (1..=64).contains(d))
                    .ok_or_else(|| {
                        anyhow::anyhow!(
                            "joint_coupling: \"driver_joint\" must be a joint number ≥ 1"
                        )
                    })? as usize;
                (
                    Block::Coupling {
                        joint: joint()?,
                        driver,
                    },
                    vec![rad(f("sin_deg")?), rad(f("cos_deg")?)],
                )
            }
            "wave_generator" => {
                let harmonic = p
                    .get("harmonic")
                    .and_then(|v| v.as_u64())
                    .filter(|h| (1..=1000).contains(h))
                    .ok_or_else(|| {
                        anyhow::anyhow!("wave_generator: \"harmonic\" must be an integer ≥ 1")
                    })? as u32;
                let ratio = f("gear_ratio")?;
                if ratio <= 0.0 {
                    anyhow::bail!("wave_generator: \"gear_ratio\" must be > 0 (got {ratio})");
                }
                (
                    Block::WaveGenerator {
                        joint: joint()?,
                        ratio,
                        harmonic,
                    },
                    vec![rad(f("sin_deg")?), rad(f("cos_deg")?)],
                )
            }
            "temperature_drift" => {
                let off = arr("offset_deg_per_k")?;
                if off.len() != TEMP_DRIFT_JOINTS {
                    anyhow::bail!(
                        "temperature_drift: {} offset rates (need {TEMP_DRIFT_JOINTS})",
                        off.len()
                    );
                }
                let mut c = vec![f("growth_ppm_per_k")? * 1e-6];
                c.extend(off.into_iter().map(rad));
                (Block::TempDrift { t0_c: f("t0_c")? }, c)
            }
            "nonparametric" => (Block::Nonparametric(Box::new(Rbf::from_json(p)?)), vec![]),
            other => anyhow::bail!("unknown effect kind \"{other}\""),
        };
        let n = coefs.len();
        Ok(Effect {
            block,
            coefs,
            std: vec![f64::NAN; n],
            tau_std: f64::NAN,
        })
    }
}

/// Predicted marker point of one pose from calibration-file effects (for `robocal predict`).
pub fn apply_cal_effects(
    model: &KinematicModel,
    effects: &[CalEffect],
    ctx: &PoseCtx,
) -> anyhow::Result<Point3<f64>> {
    let e = effects
        .iter()
        .map(Effect::from_cal)
        .collect::<anyhow::Result<Vec<_>>>()?;
    Ok(apply_effects(model, &e, ctx))
}

/// Prediction of one pose record of `ds` with a calibration's effects (the hook of
/// `robocal predict`).
pub fn predict_record(
    model: &KinematicModel,
    effects: &[CalEffect],
    rec: &crate::dataset::PoseRecord,
    ds: &crate::dataset::Dataset,
) -> anyhow::Result<Point3<f64>> {
    let ctx = crate::solve::obs::record_context(rec, ds, model.dof()).ok_or_else(|| {
        anyhow::anyhow!(
            "pose {}: no usable joint angles `q` for the effects",
            rec.id
        )
    })?;
    apply_cal_effects(model, effects, &ctx)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A transmission ripple survives the calibration-file form (degrees, harmonic) and a
    /// bad harmonic is refused with its name.
    #[test]
    fn ripple_round_trips_through_the_calibration_file() {
        let e = Effect {
            block: Block::Ripple {
                joint: 3,
                harmonic: 4,
            },
            coefs: vec![1.5e-4, -2.5e-5],
            std: vec![1e-6, 2e-6],
            tau_std: f64::NAN,
        };
        let cal = e.to_cal();
        assert_eq!(cal.kind, "transmission_ripple");
        let back = Effect::from_cal(&cal).unwrap();
        assert_eq!(back.block, e.block);
        for (a, b) in back.coefs.iter().zip(&e.coefs) {
            assert!((a - b).abs() < 1e-15, "{a} vs {b}");
        }
        let mut bad = cal.clone();
        bad.params.insert("harmonic".into(), json!(0));
        let err = Effect::from_cal(&bad).unwrap_err().to_string();
        assert!(err.contains("harmonic"), "{err}");
    }
}

#[cfg(test)]
mod new_effect_tests {
    use super::*;

    /// The effects added for real arms (link deflection under the gravity moment, joint
    /// coupling, wave-generator harmonics, temperature drift of lengths and offsets)
    /// survive the calibration-file form with the same prediction, and a bad gear ratio is
    /// refused by name.
    #[test]
    fn new_effects_round_trip_with_the_same_prediction() {
        let model = KinematicModel::preset("denso-vs060").unwrap();
        let pts = mass_points(&model, 3);
        let effects = vec![
            Effect {
                block: Block::LinkDeflection {
                    joint: 3,
                    points: pts.clone(),
                    anisotropic: false,
                },
                coefs: vec![3e-4; pts.len()],
                std: vec![f64::NAN; pts.len()],
                tau_std: f64::NAN,
            },
            Effect {
                block: Block::LinkDeflection {
                    joint: 1,
                    points: mass_points(&model, 1),
                    anisotropic: true,
                },
                coefs: (0..2 * mass_points(&model, 1).len())
                    .map(|k| if k % 2 == 0 { 4e-4 } else { -1e-4 })
                    .collect(),
                std: vec![f64::NAN; 2 * mass_points(&model, 1).len()],
                tau_std: f64::NAN,
            },
            Effect {
                block: Block::Coupling {
                    joint: 5,
                    driver: 4,
                },
                coefs: vec![2e-4, -1e-4],
                std: vec![1e-6; 2],
                tau_std: f64::NAN,
            },
            Effect {
                block: Block::WaveGenerator {
                    joint: 2,
                    ratio: 101.0,
                    harmonic: 2,
                },
                coefs: vec![5e-5, 1e-5],
                std: vec![1e-6; 2],
                tau_std: f64::NAN,
            },
            Effect {
                block: Block::TempDrift { t0_c: 21.5 },
                coefs: vec![1.2e-5, 1e-5, -2e-5, 3e-5, 0.0, 1e-5, -1e-5],
                std: vec![1e-7; 7],
                tau_std: f64::NAN,
            },
        ];
        let mut ctx = PoseCtx {
            id: 1,
            t: 100.0,
            q: vec![0.3, -0.8, 1.2, 0.4, -0.6, 0.9],
            q_cmd: None,
            q_prev: None,
            approach: vec![],
            temp_c: Some(23.0),
            qd: None,
        };
        let p0 = apply_effects(&model, &[], &ctx);
        let p1 = apply_effects(&model, &effects, &ctx);
        // Every effect moves the point (a non-trivial check), and the file form predicts the
        // same point.
        for e in &effects {
            let d = (apply_effects(&model, std::slice::from_ref(e), &ctx) - p0).norm();
            assert!(
                d > 1e-4,
                "{} moves the point by only {d:.2e} mm",
                e.block.label()
            );
        }
        let cal: Vec<CalEffect> = effects.iter().map(Effect::to_cal).collect();
        let back = apply_cal_effects(&model, &cal, &ctx).unwrap();
        assert!((back - p1).norm() < 1e-9, "{}", (back - p1).norm());
        // Gravity bending moves the point in the vertical plane of the arm: flipping the arm
        // over joint 1 by π mirrors the displacement (a sign check of the physics).
        ctx.q[0] += std::f64::consts::PI;
        let d_a = apply_effects(&model, &effects[..1], &ctx) - apply_effects(&model, &[], &ctx);
        assert!(d_a.norm() > 1e-3);
        // Anisotropic bending: the two axes act separately (x only ≠ y only), and a file
        // with a coefficient missing or unknown axes is refused by name.
        let one_axis = |k0: usize| {
            let mut e = effects[1].clone();
            for (k, c) in e.coefs.iter_mut().enumerate() {
                *c = if k % 2 == k0 { 4e-4 } else { 0.0 };
            }
            apply_effects(&model, &[e], &ctx) - apply_effects(&model, &[], &ctx)
        };
        let (dx, dy) = (one_axis(0), one_axis(1));
        assert!(dx.norm() > 1e-4 && dy.norm() > 1e-4 && (dx - dy).norm() > 1e-4);
        let mut bad = effects[1].to_cal();
        bad.params.insert("axes".into(), json!("isotropic"));
        let err = Effect::from_cal(&bad).unwrap_err().to_string();
        assert!(err.contains("per point"), "{err}");
        bad.params.insert("axes".into(), json!("diagonal"));
        let err = Effect::from_cal(&bad).unwrap_err().to_string();
        assert!(err.contains("axes"), "{err}");
        let mut bad = effects[3].to_cal();
        bad.params.insert("gear_ratio".into(), json!(-3.0));
        let err = Effect::from_cal(&bad).unwrap_err().to_string();
        assert!(err.contains("gear_ratio"), "{err}");
    }
}
