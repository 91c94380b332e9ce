//! The optical tracker's own error model (seed 003, "光学追踪系统内部成像误差"): a stereo
//! pair with baseline `b` and focal length `f` reconstructs depth `z = b·f / d` from the
//! disparity `d`, so a disparity noise `σ_d` (px) gives a depth error
//! `σ_z = z² / (b·f) · σ_d` that grows with the square of the distance, while the lateral
//! error of an image noise `σ_px` grows only linearly, `σ_⊥ = z / f · σ_px`.
//!
//! The covariance of a measured point is anisotropic: `σ_z²` along the line of sight (from
//! the tracker origin to the point) and `σ_⊥²` across it. It is used as the weights of the
//! registrations ([`super::paired`], [`super::robot_world`]) and as the tracker link of the
//! error chain ([`crate::navchain`]).
use nalgebra::{Matrix3, Point3, Vector3};
use serde::{Deserialize, Serialize};

use super::RegisterError;

/// Stereo tracker noise model (file units: mm and pixels).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StereoTrackerModel {
    /// Camera baseline (mm).
    pub baseline_mm: f64,
    /// Focal length (px).
    pub focal_px: f64,
    /// Disparity noise, 1σ (px).
    pub disparity_sigma_px: f64,
    /// Image-point noise across the line of sight, 1σ (px).
    pub pixel_sigma_px: f64,
    /// Floor added in quadrature on every axis (mm): marker geometry, calibration residue.
    #[serde(default)]
    pub floor_mm: f64,
}

impl StereoTrackerModel {
    /// A Polaris-Vega-like pair: 500 mm baseline, 1500 px focal, 0.04 px disparity noise,
    /// 0.03 px image noise: σ_z ≈ 0.07 mm at 1.5 m, 0.16 mm at 2.4 m.
    pub fn polaris_like() -> Self {
        StereoTrackerModel {
            baseline_mm: 500.0,
            focal_px: 1500.0,
            disparity_sigma_px: 0.04,
            pixel_sigma_px: 0.03,
            floor_mm: 0.0,
        }
    }

    /// Refuses non-finite or non-positive geometry and negative noise.
    pub fn validate(&self) -> Result<(), RegisterError> {
        let ok = self.baseline_mm.is_finite()
            && self.baseline_mm > 0.0
            && self.focal_px.is_finite()
            && self.focal_px > 0.0
            && self.disparity_sigma_px.is_finite()
            && self.disparity_sigma_px >= 0.0
            && self.pixel_sigma_px.is_finite()
            && self.pixel_sigma_px >= 0.0
            && self.floor_mm.is_finite()
            && self.floor_mm >= 0.0;
        if ok {
            Ok(())
        } else {
            Err(RegisterError::Invalid(format!(
                "tracker model: baseline_mm and focal_px must be > 0 and the sigmas ≥ 0 (got {self:?})"
            )))
        }
    }

    /// Depth (distance from the tracker origin) and (σ_depth, σ_lateral) in mm at `p`.
    pub fn sigmas(&self, p: &Point3<f64>) -> (f64, f64) {
        let z = p.coords.norm();
        let sd = z * z / (self.baseline_mm * self.focal_px) * self.disparity_sigma_px;
        let sl = z / self.focal_px * self.pixel_sigma_px;
        (
            (sd * sd + self.floor_mm * self.floor_mm).sqrt(),
            (sl * sl + self.floor_mm * self.floor_mm).sqrt(),
        )
    }

    /// Covariance (mm²) of a point measured at `p` (tracker frame).
    pub fn covariance(&self, p: &Point3<f64>) -> Matrix3<f64> {
        let (sd, sl) = self.sigmas(p);
        let l = p
            .coords
            .try_normalize(1e-12)
            .unwrap_or_else(|| -Vector3::z());
        let llt = l * l.transpose();
        llt * (sd * sd) + (Matrix3::identity() - llt) * (sl * sl)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_error_grows_with_square_of_distance() {
        let m = StereoTrackerModel::polaris_like();
        let (d1, l1) = m.sigmas(&Point3::new(0.0, 0.0, -1000.0));
        let (d2, l2) = m.sigmas(&Point3::new(0.0, 0.0, -2000.0));
        assert!((d2 / d1 - 4.0).abs() < 1e-12);
        assert!((l2 / l1 - 2.0).abs() < 1e-12);
        // z²/(b f) σ_d at 1.5 m
        let (d, _) = m.sigmas(&Point3::new(0.0, 0.0, -1500.0));
        assert!((d - 1500.0 * 1500.0 / (500.0 * 1500.0) * 0.04).abs() < 1e-12);
        let c = m.covariance(&Point3::new(0.0, 0.0, -1500.0));
        assert!((c[(2, 2)] - d * d).abs() < 1e-12);
        assert!(c[(0, 0)] < c[(2, 2)]);
    }
}
