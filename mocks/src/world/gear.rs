//! Periodic gear errors of the true arm: transmission ripple, joint coupling and harmonic-drive
//! wave-generator errors. The world's own physics, written as an amplitude and a phase (not
//! as the estimator's sin/cos coefficients):
//!
//! * ripple of joint i at `harmonic` k cycles per output turn (gear tooth, bearing or
//!   output-encoder errors): `δθ_i = A sin(k q_i + φ)`;
//! * coupling of joint i to the angle of joint d (wrist cross-talk, a cable or hose whose
//!   torque follows another joint), `harmonic` m cycles per turn of joint d (1 by default):
//!   `δθ_i = A sin(m q_d + φ)`;
//! * wave generator of joint i with gear ratio N at harmonic h of the wave generator's turn
//!   (h = 1 its eccentricity, h = 2 the elliptical flexspline): `δθ_i = A sin(h N q_i + φ)`.
//!
//! `q` is the encoder reading (rad); the result is added to the link-side angle.
use serde::{Deserialize, Serialize};

/// Transmission ripple of one joint.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ripple {
    /// Joint number (1-based).
    pub joint: usize,
    /// Cycles per output turn.
    pub harmonic: u32,
    /// Amplitude (deg).
    pub amplitude_deg: f64,
    /// Phase (deg).
    #[serde(default)]
    pub phase_deg: f64,
}

/// Angle error of one joint driven by another joint's angle.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Coupling {
    /// Joint number (1-based) whose angle errs.
    pub joint: usize,
    /// Joint number (1-based) whose angle drives the error.
    pub driver: usize,
    /// Cycles per turn of the driving joint (default 1).
    #[serde(default = "one")]
    pub harmonic: u32,
    /// Amplitude (deg).
    pub amplitude_deg: f64,
    /// Phase (deg).
    #[serde(default)]
    pub phase_deg: f64,
}

/// Harmonic-drive wave-generator error of one joint.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WaveGenerator {
    /// Joint number (1-based).
    pub joint: usize,
    /// Wave-generator turns per output turn.
    pub gear_ratio: f64,
    /// Cycles per wave-generator turn.
    pub harmonic: u32,
    /// Amplitude (deg).
    pub amplitude_deg: f64,
    /// Phase (deg).
    #[serde(default)]
    pub phase_deg: f64,
}

fn one() -> u32 {
    1
}

/// A reducer whose torsional stiffness changes with load (a harmonic drive's torsion curve is
/// not a straight line): besides the linear compliance of [`super::effects::JointCompliance`],
/// the joint twists by `rad_per_nm2 · τ |τ|` under the gravity torque τ.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NonlinearCompliance {
    /// Joint number (1-based).
    pub joint: usize,
    /// Quadratic compliance (rad per (N·m)²).
    pub rad_per_nm2: f64,
}

/// `A sin(x + φ)` with A and φ in degrees, in rad.
fn wave(amplitude_deg: f64, x: f64, phase_deg: f64) -> f64 {
    amplitude_deg.to_radians() * (x + phase_deg.to_radians()).sin()
}

/// Adds the gear errors to the link-side angles `th` (rad) for the encoder reading `q` (rad).
/// Joints out of range are ignored.
pub fn add_gear_errors(
    ripple: &[Ripple],
    coupling: &[Coupling],
    wave_generator: &[WaveGenerator],
    q: &[f64],
    th: &mut [f64],
) {
    let n = th.len().min(q.len());
    let at = |j: usize| j.checked_sub(1).filter(|&k| k < n);
    for r in ripple {
        if let Some(k) = at(r.joint) {
            th[k] += wave(r.amplitude_deg, f64::from(r.harmonic) * q[k], r.phase_deg);
        }
    }
    for c in coupling {
        if let (Some(k), Some(d)) = (at(c.joint), at(c.driver)) {
            th[k] += wave(c.amplitude_deg, f64::from(c.harmonic) * q[d], c.phase_deg);
        }
    }
    for w in wave_generator {
        if let Some(k) = at(w.joint) {
            let x = f64::from(w.harmonic) * w.gear_ratio * q[k];
            th[k] += wave(w.amplitude_deg, x, w.phase_deg);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_error_has_its_period_and_amplitude() {
        let r = [Ripple {
            joint: 2,
            harmonic: 7,
            amplitude_deg: 0.01,
            phase_deg: 0.0,
        }];
        let c = [Coupling {
            joint: 1,
            driver: 3,
            harmonic: 1,
            amplitude_deg: 0.02,
            phase_deg: 90.0,
        }];
        let w = [WaveGenerator {
            joint: 3,
            gear_ratio: 100.0,
            harmonic: 2,
            amplitude_deg: 0.003,
            phase_deg: 0.0,
        }];
        // Joint 2 at a quarter of its ripple period: the full amplitude.
        let x = std::f64::consts::FRAC_PI_2 / 7.0;
        let q = [0.0, x, 0.0];
        let mut th = q;
        add_gear_errors(&r, &c, &w, &q, &mut th);
        assert!((th[1] - x - 0.01f64.to_radians()).abs() < 1e-15);
        // Joint 1 follows cos q3 = 1.
        assert!((th[0] - 0.02f64.to_radians()).abs() < 1e-15);
        // Joint 3 at q = 0: sin 0 = 0; a quarter of 2·100 cycles further: full amplitude.
        assert!(th[2].abs() < 1e-15);
        let q3 = std::f64::consts::FRAC_PI_2 / 200.0;
        let mut th = [0.0, 0.0, q3];
        add_gear_errors(&[], &[], &w, &[0.0, 0.0, q3], &mut th);
        assert!((th[2] - q3 - 0.003f64.to_radians()).abs() < 1e-15);
    }
}
