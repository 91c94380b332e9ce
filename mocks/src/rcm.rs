//! The RCM cell: an instrument shaft pivoting through a fixed trocar, seen by an
//! endoscope camera fixed in the robot base. Truth lives here, computed with this module's own
//! geometry (contour generators of the cylinder, pinhole projection, clipping to the image),
//! independent of the estimator's tangent-plane algebra in `robocal::solve::rcm`.
//!
//! The scenario file (`mocks/rcm/rcm-endoscope.toml`) names the trocar, the camera
//! (pose by look-at, intrinsics, distortion), the shaft radius, a small planar marker on a
//! flat of the shaft (for the `AX = XB` baselines, which need the instrument's full pose in
//! the camera) and the noise of the observations.
use std::path::Path;

use nalgebra::{Isometry3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

/// Camera of the cell.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RcmCameraConfig {
    /// Optical centre in the base (mm).
    pub xyz_mm: [f64; 3],
    /// Point the optical axis goes through (mm, base).
    pub look_at_mm: [f64; 3],
    /// Direction in the base that appears "up" (−y of the image).
    pub up: [f64; 3],
    /// Image size (px).
    pub width: u32,
    /// Image size (px).
    pub height: u32,
    /// Focal lengths (px).
    pub fx: f64,
    /// Focal lengths (px).
    pub fy: f64,
    /// Principal point (px).
    pub cx: f64,
    /// Principal point (px).
    pub cy: f64,
    /// OpenCV distortion `[k1, k2, p1, p2, k3]` (observations are reported undistorted).
    #[serde(default)]
    pub dist: [f64; 5],
}

/// The instrument.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RcmInstrumentConfig {
    /// Shaft radius (mm).
    pub shaft_radius_mm: f64,
    /// Length of shaft behind the tip that can be seen (the jaw / wrist is ignored) (mm).
    pub visible_mm: f64,
    /// Planar marker on a flat of the shaft (plane x = radius of the instrument frame):
    /// `cols × rows` dots with `pitch_mm`, the first row `offset_mm` behind the tip.
    pub marker_cols: u32,
    /// See `marker_cols`.
    pub marker_rows: u32,
    /// See `marker_cols`.
    pub marker_pitch_mm: f64,
    /// See `marker_cols`.
    pub marker_offset_mm: f64,
}

/// Observation noise.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RcmNoiseConfig {
    /// σ of each end-point coordinate of a silhouette segment (px).
    pub line_px: f64,
    /// σ of each marker dot coordinate (px).
    pub marker_px: f64,
    /// σ of the robot's reported instrument position per axis (mm).
    #[serde(default)]
    pub robot_mm: f64,
    /// σ of the robot's reported instrument orientation per axis (deg).
    #[serde(default)]
    pub robot_deg: f64,
}

/// An RCM scenario.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RcmScenario {
    /// Name.
    pub name: String,
    /// Free text.
    #[serde(default)]
    pub description: String,
    /// Seed of the noise.
    pub seed: u64,
    /// Robot preset holding the instrument.
    pub robot: String,
    /// The trocar (RCM) in the base (mm).
    pub trocar_mm: [f64; 3],
    /// Nominal insertion direction (into the body) in the base.
    pub insertion_dir: [f64; 3],
    /// Camera.
    pub camera: RcmCameraConfig,
    /// Instrument.
    pub instrument: RcmInstrumentConfig,
    /// Noise.
    pub noise: RcmNoiseConfig,
    /// How the endoscope image is rendered (`crate::rcm_render`); defaults when absent.
    #[serde(default)]
    pub render: crate::rcm_render::RcmRenderConfig,
}

impl RcmScenario {
    /// Parses a scenario file.
    pub fn load(path: impl AsRef<Path>) -> anyhow::Result<RcmScenario> {
        let p = path.as_ref();
        let text =
            std::fs::read_to_string(p).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
        Self::parse(&text).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))
    }
    /// Parses scenario text.
    pub fn parse(text: &str) -> anyhow::Result<RcmScenario> {
        let s: RcmScenario = toml::from_str(text)?;
        if s.instrument.shaft_radius_mm.is_nan() || s.instrument.shaft_radius_mm <= 0.0 {
            anyhow::bail!("instrument.shaft_radius_mm must be > 0");
        }
        Ok(s)
    }
    /// The built-in scenario (the file shipped in `mocks/rcm/rcm-endoscope.toml`).
    pub fn builtin() -> RcmScenario {
        Self::parse(include_str!("../rcm/rcm-endoscope.toml")).expect("builtin scenario")
    }
}

/// What the camera sees of the instrument at one pose (undistorted pixels).
#[derive(Debug, Clone, PartialEq)]
pub struct RcmView {
    /// The two silhouette segments `[u1, v1, u2, v2]`.
    pub shaft_lines: [[f64; 4]; 2],
    /// Marker dots (row-major), when the marker faces the camera and is inside the image.
    pub marker_px: Option<Vec<[f64; 2]>>,
}

/// The RCM cell: the true camera pose and the instrument geometry.
#[derive(Debug, Clone)]
pub struct RcmCell {
    /// Scenario.
    pub scenario: RcmScenario,
    /// True camera frame (OpenCV axes) in the base.
    pub camera: Isometry3<f64>,
}

fn v3(a: [f64; 3]) -> Vector3<f64> {
    Vector3::new(a[0], a[1], a[2])
}

impl RcmCell {
    /// Builds the cell.
    pub fn new(scenario: RcmScenario) -> RcmCell {
        let c = &scenario.camera;
        let eye = v3(c.xyz_mm);
        let z = (v3(c.look_at_mm) - eye).normalize();
        let up = v3(c.up);
        let x = (-up).cross(&z).normalize(); // image y points down = −up
        let y = z.cross(&x);
        let r = Rotation3::from_basis_unchecked(&[x, y, z]);
        let camera = Isometry3::from_parts(
            Translation3::from(eye),
            UnitQuaternion::from_rotation_matrix(&r),
        );
        RcmCell { scenario, camera }
    }

    /// The marker model: dots `(a, b)` in the marker plane (mm).
    pub fn marker_model(&self) -> Vec<[f64; 2]> {
        let i = &self.scenario.instrument;
        let mut v = Vec::new();
        for r in 0..i.marker_rows {
            for c in 0..i.marker_cols {
                v.push([c as f64 * i.marker_pitch_mm, r as f64 * i.marker_pitch_mm]);
            }
        }
        v
    }

    /// The marker frame in the instrument frame: on the flat at `x = radius`, its `a` axis along
    /// the instrument's y, its `b` axis back along −z from `offset_mm` behind the tip, normal +x.
    pub fn marker_in_instrument(&self) -> Isometry3<f64> {
        let i = &self.scenario.instrument;
        let w = (i.marker_cols.max(1) - 1) as f64 * i.marker_pitch_mm;
        // a = −y, b = −z, normal a × b = +x (right-handed).
        let (a, b, n) = (-Vector3::y(), -Vector3::z(), Vector3::x());
        let r = Rotation3::from_basis_unchecked(&[a, b, n]);
        let o = Vector3::new(i.shaft_radius_mm, w / 2.0, -i.marker_offset_mm);
        Isometry3::from_parts(
            Translation3::from(o),
            UnitQuaternion::from_rotation_matrix(&r),
        )
    }

    fn project(&self, p_base: &Vector3<f64>) -> Option<[f64; 2]> {
        let c = &self.scenario.camera;
        let p = self.camera.inverse() * Point3::from(*p_base);
        (p.z > 1.0).then(|| [c.fx * p.x / p.z + c.cx, c.fy * p.y / p.z + c.cy])
    }

    fn inside(&self, q: &[f64; 2]) -> bool {
        let c = &self.scenario.camera;
        q[0] >= 0.0 && q[1] >= 0.0 && q[0] <= c.width as f64 && q[1] <= c.height as f64
    }

    /// Noise-free view of the instrument at its true pose `inst` (instrument frame in base,
    /// origin at the tip, z along the shaft towards the tip). `None` when a silhouette is not
    /// in the image over at least 20 px.
    pub fn view(&self, inst: &Isometry3<f64>) -> Option<RcmView> {
        let ins = &self.scenario.instrument;
        let r = ins.shaft_radius_mm;
        let z = inst.rotation * Vector3::z();
        let tip = inst.translation.vector;
        let trocar = v3(self.scenario.trocar_mm);
        // Visible part: inside the body only (beyond the trocar).
        let s_trocar = (trocar - tip).dot(&z); // ≤ 0
        let s0 = (-ins.visible_mm).max(s_trocar + 1.0);
        if s0 >= -1.0 {
            return None;
        }
        let e1 = inst.rotation * Vector3::x();
        let e2 = inst.rotation * Vector3::y();
        let cam = self.camera.translation.vector;
        // Contour generators: n(θ)·(a − C) + r = 0 with n(θ) = cos θ e1 + sin θ e2 (the same θ
        // for every cross-section since e1, e2 ⟂ z).
        let a0 = tip - cam;
        let (aa, bb) = (e1.dot(&a0), e2.dot(&a0));
        let rr = (aa * aa + bb * bb).sqrt();
        if rr <= r * 1.001 {
            return None;
        }
        let phi = bb.atan2(aa);
        let dth = (-r / rr).acos();
        let mut segs = [[0.0; 4]; 2];
        for (k, th) in [phi + dth, phi - dth].iter().enumerate() {
            let off = (e1 * th.cos() + e2 * th.sin()) * r;
            let pa = self.project(&(tip + z * s0 + off))?;
            let pb = self.project(&(tip + off))?;
            let seg = clip(
                pa,
                pb,
                self.scenario.camera.width as f64,
                self.scenario.camera.height as f64,
            )?;
            if ((seg[2] - seg[0]).powi(2) + (seg[3] - seg[1]).powi(2)).sqrt() < 20.0 {
                return None;
            }
            segs[k] = seg;
        }
        // Marker.
        let m = inst * self.marker_in_instrument();
        let normal = m.rotation * Vector3::z();
        let facing = normal.dot(&(cam - m.translation.vector)) > 0.0;
        let marker_px = if facing {
            self.marker_model()
                .iter()
                .map(|ab| {
                    let p = m * Point3::new(ab[0], ab[1], 0.0);
                    self.project(&p.coords).filter(|q| self.inside(q))
                })
                .collect::<Option<Vec<[f64; 2]>>>()
        } else {
            None
        };
        Some(RcmView {
            shaft_lines: segs,
            marker_px,
        })
    }

    /// A noisy view (end points and dots perturbed with the scenario's σ, or `sigma_px` when
    /// given).
    pub fn view_noisy<R: Rng>(
        &self,
        inst: &Isometry3<f64>,
        sigma_px: Option<f64>,
        rng: &mut R,
    ) -> Option<RcmView> {
        let mut v = self.view(inst)?;
        let sl = sigma_px.unwrap_or(self.scenario.noise.line_px);
        let sm = sigma_px.unwrap_or(self.scenario.noise.marker_px);
        if sl > 0.0 {
            let n = Normal::new(0.0, sl).expect("sigma");
            for s in &mut v.shaft_lines {
                for x in s.iter_mut() {
                    *x += n.sample(rng);
                }
            }
        }
        if let (Some(px), true) = (&mut v.marker_px, sm > 0.0) {
            let n = Normal::new(0.0, sm).expect("sigma");
            for q in px.iter_mut() {
                q[0] += n.sample(rng);
                q[1] += n.sample(rng);
            }
        }
        Some(v)
    }

    /// What the robot reports for a true instrument pose (its repeatability noise).
    pub fn reported<R: Rng>(&self, inst: &Isometry3<f64>, rng: &mut R) -> Isometry3<f64> {
        let n = &self.scenario.noise;
        if n.robot_mm <= 0.0 && n.robot_deg <= 0.0 {
            return *inst;
        }
        let g = |s: f64, rng: &mut R| {
            if s > 0.0 {
                Normal::new(0.0, s).expect("sigma").sample(rng)
            } else {
                0.0
            }
        };
        let dt = Vector3::new(g(n.robot_mm, rng), g(n.robot_mm, rng), g(n.robot_mm, rng));
        let dr = Vector3::new(
            g(n.robot_deg.to_radians(), rng),
            g(n.robot_deg.to_radians(), rng),
            g(n.robot_deg.to_radians(), rng),
        );
        Isometry3::new(dt, dr) * inst
    }

    /// A `robocal-dataset/1` JSON Lines text with the endoscope header and one pose record per
    /// `(reported instrument pose, view)` (written with this crate's own serialiser).
    pub fn dataset_jsonl(&self, poses: &[(Isometry3<f64>, RcmView)]) -> String {
        let c = &self.scenario.camera;
        let header = serde_json::json!({
            "format": "robocal-dataset/1",
            "robot": {"model": self.scenario.robot},
            "camera": {"kind": "endoscope", "width": c.width, "height": c.height,
                       "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy, "dist": c.dist},
            "instrument": {"shaft_radius_mm": self.scenario.instrument.shaft_radius_mm},
            "notes": format!("simulated RCM cell {}", self.scenario.name),
        });
        let mut out = header.to_string();
        out.push('\n');
        for (i, (p, v)) in poses.iter().enumerate() {
            let q = p.rotation;
            let t = p.translation.vector;
            let rec = serde_json::json!({
                "kind": "pose", "id": i + 1, "t": i as f64, "group": "train",
                "flange": {"p": [t.x, t.y, t.z], "quat": [q.w, q.i, q.j, q.k]},
                "shaft_lines": v.shaft_lines,
            });
            out.push_str(&rec.to_string());
            out.push('\n');
        }
        out
    }
}

/// Liang–Barsky clip of the segment `a b` to `[0, w] × [0, h]`.
fn clip(a: [f64; 2], b: [f64; 2], w: f64, h: f64) -> Option<[f64; 4]> {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (p, q) in [(-dx, a[0]), (dx, w - a[0]), (-dy, a[1]), (dy, h - a[1])] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let r = q / p;
            if p < 0.0 {
                t0 = t0.max(r);
            } else {
                t1 = t1.min(r);
            }
        }
    }
    (t0 < t1).then(|| {
        [
            a[0] + t0 * dx,
            a[1] + t0 * dy,
            a[0] + t1 * dx,
            a[1] + t1 * dy,
        ]
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_scenario_sees_the_instrument_at_the_nominal_pose() {
        let cell = RcmCell::new(RcmScenario::builtin());
        let s = &cell.scenario;
        let z = v3(s.insertion_dir).normalize();
        let tip = v3(s.trocar_mm) + z * 100.0;
        let x = Vector3::y().cross(&z).normalize();
        let r = Rotation3::from_basis_unchecked(&[x, z.cross(&x), z]);
        let inst = Isometry3::from_parts(
            Translation3::from(tip),
            UnitQuaternion::from_rotation_matrix(&r),
        );
        let v = cell.view(&inst).expect("visible");
        // The two silhouettes are distinct lines.
        let d = (v.shaft_lines[0][0] - v.shaft_lines[1][0]).abs()
            + (v.shaft_lines[0][1] - v.shaft_lines[1][1]).abs();
        assert!(d > 5.0, "{v:?}");
    }

    #[test]
    fn clip_keeps_inside_and_cuts_outside() {
        assert_eq!(
            clip([1.0, 1.0], [5.0, 5.0], 10.0, 10.0),
            Some([1.0, 1.0, 5.0, 5.0])
        );
        let c = clip([-10.0, 5.0], [20.0, 5.0], 10.0, 10.0).unwrap();
        assert_eq!(c, [0.0, 5.0, 10.0, 5.0]);
        assert!(clip([-10.0, -5.0], [-1.0, -1.0], 10.0, 10.0).is_none());
    }
}
