//! Hidden physical effects of the true robot and their physics.
//!
//! Every effect is switchable (absent = off) and parameterised with its unit in the field name.
//! The encoder reading is `q`; the true joint angle of the link side is
//!
//! θ_i = (1 + ε_i)·q_i + δθ_i + Σ_h (s_ih sin hq_i + c_ih cos hq_i) + (b_i/2)·s_i + κ_i ΔT(t) + c_i τ_i(q)
//!
//! (transmission-ratio error, zero offset, encoder/gear eccentricity, backlash/lost motion with
//! s_i the sign of the last motion of joint i, thermal offset drift, joint compliance under the
//! gravity torque τ_i). Link lengths grow by `1 + α ΔT(t)` (thermal expansion) and link
//! deflection adds a rotation `c_def · M_⟂` about the axes perpendicular to joint i, with M_⟂
//! the gravity moment the joint transmits. Units inside: mm, rad, s, N·m, kg.

use super::chain::{ChainFrames, JointTilt, UrdfChain};
use super::gear::{add_gear_errors, Coupling, NonlinearCompliance, Ripple, WaveGenerator};
use nalgebra::{Isometry3, Point3, Vector3};
use serde::{Deserialize, Serialize};

/// Standard gravity (m/s²).
pub const G0: f64 = 9.80665;

/// Gravity-driven joint compliance (torsion of the reducer), out of the encoder loop.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JointCompliance {
    /// Joint number (1-based).
    pub joint: usize,
    /// Compliance 1/k (rad per N·m).
    pub rad_per_nm: f64,
}

/// Link deflection / bearing tilt: rotation about the two axes perpendicular to the joint axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinkDeflection {
    /// Joint number (1-based) whose bearing/link bends.
    pub joint: usize,
    /// Bending compliance (rad per N·m of moment perpendicular to the axis).
    pub rad_per_nm: f64,
}

/// Backlash / lost motion: the link lags by half the lost motion behind the approach direction.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Backlash {
    /// Joint number (1-based).
    pub joint: usize,
    /// Total lost motion b (deg): approaches from + and − differ by b.
    pub lost_motion_deg: f64,
}

/// Encoder / gear eccentricity: first and second harmonics of the joint angle.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Eccentricity {
    /// Joint number (1-based).
    pub joint: usize,
    /// Amplitude of sin(q) (deg).
    #[serde(default)]
    pub sin1_deg: f64,
    /// Amplitude of cos(q) (deg).
    #[serde(default)]
    pub cos1_deg: f64,
    /// Amplitude of sin(2q) (deg).
    #[serde(default)]
    pub sin2_deg: f64,
    /// Amplitude of cos(2q) (deg).
    #[serde(default)]
    pub cos2_deg: f64,
}

/// Transmission-ratio error: θ = (1 + ε) q.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Transmission {
    /// Joint number (1-based).
    pub joint: usize,
    /// Ratio error ε in parts per million.
    pub ratio_error_ppm: f64,
}

/// Thermal warm-up: ΔT(t) = ΔT∞ (1 − e^(−(t + t_power_on)/τ)).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Thermal {
    /// Final temperature rise ΔT∞ (K).
    pub delta_t_inf_k: f64,
    /// Warm-up time constant τ (s).
    pub tau_s: f64,
    /// Linear expansion of every link (1/K); aluminium ≈ 23e-6.
    #[serde(default = "default_expansion")]
    pub expansion_per_k: f64,
    /// Per-joint zero-offset drift κ_i (deg/K); missing joints drift 0.
    #[serde(default)]
    pub offset_drift_deg_per_k: Vec<f64>,
    /// Time the arm had been powered before the world's t = 0 (s).
    #[serde(default)]
    pub t_power_on_s: f64,
}

fn default_expansion() -> f64 {
    23e-6
}

impl Thermal {
    /// ΔT (K) at world time `t_s`.
    pub fn delta_t_k(&self, t_s: f64) -> f64 {
        if self.tau_s <= 0.0 {
            return self.delta_t_inf_k;
        }
        self.delta_t_inf_k * (1.0 - (-(t_s + self.t_power_on_s).max(0.0) / self.tau_s).exp())
    }
}

/// Every hidden effect of one arm; all off by default.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArmEffects {
    /// Joint compliance under gravity torque.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub joint_compliance: Vec<JointCompliance>,
    /// Link deflection / bearing tilt under gravity moments.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub link_deflection: Vec<LinkDeflection>,
    /// Backlash / lost motion.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub backlash: Vec<Backlash>,
    /// Encoder / gear eccentricity.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub eccentricity: Vec<Eccentricity>,
    /// Transmission-ratio error.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub transmission: Vec<Transmission>,
    /// Thermal warm-up drift.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub thermal: Option<Thermal>,
    /// Transmission ripple (see [`super::gear`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub ripple: Vec<Ripple>,
    /// Joint coupling (see [`super::gear`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub coupling: Vec<Coupling>,
    /// Harmonic-drive wave-generator errors (see [`super::gear`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub wave_generator: Vec<WaveGenerator>,
    /// Load-dependent reducer stiffness (see [`super::gear::NonlinearCompliance`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub nonlinear_compliance: Vec<NonlinearCompliance>,
    /// Servo positioning error at the end of each move, 1σ per joint (deg): the arm settles at
    /// `q_cmd + e`, and the encoders read where it settled.
    #[serde(default)]
    pub servo_error_deg: f64,
}

/// A point mass rigidly attached to a link.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PointMass {
    /// Link number: the frame of joint `link` (1-based), or `dof + 1` for the flange frame.
    pub link: usize,
    /// Position in that frame (mm).
    pub xyz_mm: [f64; 3],
    /// Mass (kg).
    pub kg: f64,
}

/// Joint-side inputs to the effects at one instant.
#[derive(Debug, Clone, PartialEq)]
pub struct JointContext {
    /// World time (s).
    pub t_s: f64,
    /// Sign (±1) of the last motion of each joint (for backlash).
    pub approach: Vec<f64>,
}

impl JointContext {
    /// A static context: time 0, every joint last moved in the + direction.
    pub fn at_rest(dof: usize) -> Self {
        Self {
            t_s: 0.0,
            approach: vec![1.0; dof],
        }
    }
}

/// The true arm: true chain, zero offsets, masses and effects.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ArmPhysics {
    /// The controller's nominal chain.
    pub nominal: UrdfChain,
    /// The true geometry (nominal + hidden errors).
    pub chain: UrdfChain,
    /// True joint zero offsets δθ (rad): θ = q + δθ.
    pub offsets_rad: Vec<f64>,
    /// Link point masses and payload (flange-frame masses use `link = dof + 1`).
    pub masses: Vec<PointMass>,
    /// The hidden effects.
    pub effects: ArmEffects,
    /// Gravity direction in the base frame (unit; default −z).
    pub gravity_dir: Vector3<f64>,
}

impl ArmPhysics {
    /// A perfect arm: true = nominal, no offsets, no masses, no effects.
    pub fn ideal(nominal: UrdfChain) -> Self {
        let n = nominal.dof();
        Self {
            chain: nominal.clone(),
            nominal,
            offsets_rad: vec![0.0; n],
            masses: Vec::new(),
            effects: ArmEffects::default(),
            gravity_dir: -Vector3::z(),
        }
    }

    /// Joint angles before compliance: ratio error, offset, eccentricity, backlash, thermal drift.
    pub fn kinematic_angles(&self, q: &[f64], ctx: &JointContext) -> Vec<f64> {
        let e = &self.effects;
        let mut th: Vec<f64> = q
            .iter()
            .enumerate()
            .map(|(i, &qi)| qi + self.offsets_rad.get(i).copied().unwrap_or(0.0))
            .collect();
        let n = th.len();
        let at = |j: usize| j.checked_sub(1).filter(|&k| k < n);
        for t in &e.transmission {
            if let Some(k) = at(t.joint) {
                th[k] += q[k] * t.ratio_error_ppm * 1e-6;
            }
        }
        for ec in &e.eccentricity {
            if let Some(k) = at(ec.joint) {
                let x = q[k];
                th[k] += (ec.sin1_deg * x.sin()
                    + ec.cos1_deg * x.cos()
                    + ec.sin2_deg * (2.0 * x).sin()
                    + ec.cos2_deg * (2.0 * x).cos())
                .to_radians();
            }
        }
        for b in &e.backlash {
            if let Some(k) = at(b.joint) {
                let s = ctx.approach.get(k).copied().unwrap_or(1.0).signum();
                th[k] += 0.5 * b.lost_motion_deg.to_radians() * s;
            }
        }
        add_gear_errors(&e.ripple, &e.coupling, &e.wave_generator, q, &mut th);
        if let Some(tm) = &e.thermal {
            let dt = tm.delta_t_k(ctx.t_s);
            for (k, kappa) in tm.offset_drift_deg_per_k.iter().enumerate() {
                if k < th.len() {
                    th[k] += kappa.to_radians() * dt;
                }
            }
        }
        th
    }

    /// Link-length growth factor at time `t_s` (1 = none).
    pub fn growth(&self, t_s: f64) -> f64 {
        self.effects
            .thermal
            .as_ref()
            .map(|t| 1.0 + t.expansion_per_k * t.delta_t_k(t_s))
            .unwrap_or(1.0)
    }

    /// Position of every point mass in the base frame (mm) for the given frames.
    pub fn mass_positions(&self, frames: &ChainFrames) -> Vec<(usize, Point3<f64>, f64)> {
        let n = self.chain.dof();
        self.masses
            .iter()
            .filter_map(|m| {
                let frame = if m.link == n + 1 {
                    frames.flange
                } else if m.link >= 1 && m.link <= n {
                    frames.joints[m.link - 1]
                } else {
                    return None;
                };
                Some((m.link, frame * Point3::from(m.xyz_mm), m.kg))
            })
            .collect()
    }

    /// Gravity moment (N·m, base frame) transmitted through each joint: the moment about the
    /// joint origin of the weight of every mass distal to that joint.
    pub fn gravity_moments(&self, frames: &ChainFrames) -> Vec<Vector3<f64>> {
        let masses = self.mass_positions(frames);
        let g = self.gravity_dir.normalize() * G0;
        (0..self.chain.dof())
            .map(|i| {
                let o = frames.joint_origin(i);
                masses
                    .iter()
                    .filter(|(link, _, _)| *link > i)
                    .map(|(_, p, kg)| ((p - o) * 1e-3).cross(&(g * *kg)))
                    .sum()
            })
            .collect()
    }

    /// Gravity torque about each joint axis (N·m) at the given frames.
    pub fn gravity_torques(&self, frames: &ChainFrames) -> Vec<f64> {
        self.gravity_moments(frames)
            .iter()
            .enumerate()
            .map(|(i, m)| m.dot(&frames.joint_axis(&self.chain, i)))
            .collect()
    }

    /// The true joint angles θ (rad) including compliance, and the link tilts, for encoder
    /// reading `q`.
    pub fn true_state(&self, q: &[f64], ctx: &JointContext) -> (Vec<f64>, Option<Vec<JointTilt>>) {
        let mut th = self.kinematic_angles(q, ctx);
        let e = &self.effects;
        if e.joint_compliance.is_empty()
            && e.link_deflection.is_empty()
            && e.nonlinear_compliance.is_empty()
        {
            return (th, None);
        }
        let growth = self.growth(ctx.t_s);
        let frames = self.chain.frames(&th, growth, None);
        let moments = self.gravity_moments(&frames);
        for c in &e.joint_compliance {
            if let Some(k) = c.joint.checked_sub(1).filter(|&k| k < th.len()) {
                let tau = moments[k].dot(&frames.joint_axis(&self.chain, k));
                th[k] += c.rad_per_nm * tau;
            }
        }
        for c in &e.nonlinear_compliance {
            if let Some(k) = c.joint.checked_sub(1).filter(|&k| k < th.len()) {
                let tau = moments[k].dot(&frames.joint_axis(&self.chain, k));
                th[k] += c.rad_per_nm2 * tau * tau.abs();
            }
        }
        if e.link_deflection.is_empty() {
            return (th, None);
        }
        let mut tilts = vec![Vector3::zeros(); th.len()];
        for d in &e.link_deflection {
            if let Some(k) = d.joint.checked_sub(1).filter(|&k| k < th.len()) {
                let local = frames.joints[k].rotation.inverse() * moments[k];
                let a = self.chain.joints[k].axis.into_inner();
                let perp = local - a * local.dot(&a);
                tilts[k] = perp * d.rad_per_nm;
            }
        }
        (th, Some(tilts))
    }

    /// True flange pose in the base frame (mm) for encoder reading `q`.
    pub fn true_flange(&self, q: &[f64], ctx: &JointContext) -> Isometry3<f64> {
        let (th, tilts) = self.true_state(q, ctx);
        self.chain
            .frames(&th, self.growth(ctx.t_s), tilts.as_deref())
            .flange
    }

    /// The controller's nominal FK of the encoder reading (mm).
    pub fn nominal_flange(&self, q: &[f64]) -> Isometry3<f64> {
        self.nominal.fk(q)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compliance_sags_a_stretched_arm_downwards() {
        let mut a = ArmPhysics::ideal(UrdfChain::preset("denso-vs060").unwrap());
        a.masses.push(PointMass {
            link: 7,
            xyz_mm: [0.0, 0.0, 0.0],
            kg: 4.0,
        });
        // Arm stretched forward horizontally: joint 2 at 90°.
        let q = [0.0, 90f64.to_radians(), 0.0, 0.0, 0.0, 0.0];
        let ctx = JointContext::at_rest(6);
        let p0 = a.true_flange(&q, &ctx).translation.vector;
        a.effects.joint_compliance.push(JointCompliance {
            joint: 2,
            rad_per_nm: 1e-4,
        });
        let p1 = a.true_flange(&q, &ctx).translation.vector;
        let frames = a.chain.frames(&q, 1.0, None);
        let tau = a.gravity_torques(&frames)[1];
        // τ = m g L with L the horizontal lever arm (m).
        let lever_m = (p0.x - frames.joint_origin(1).x) * 1e-3;
        assert!((tau - 4.0 * G0 * lever_m).abs() < 1e-9, "{tau}");
        assert!(p1.z < p0.z, "sags down");
        let expected = 1e-4 * tau * lever_m * 1e3;
        assert!(((p0.z - p1.z) - expected).abs() < 1e-3 * expected);
    }
}
