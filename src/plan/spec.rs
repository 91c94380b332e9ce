//! Strict TOML plan specifications (`plans/*.toml`). File units: mm, degrees, seconds.
//!
//! A spec names exactly one generator table (`[annulus]`, `[shell]`, `[planes]`, `[rcm]` or
//! `[validation]`) plus optional `[tool]`, `[tracker]`, `[laser]`, `[constraints]`,
//! `[timing]` and `[observability]` tables. Unknown keys are errors.
use serde::{Deserialize, Serialize};

use robocal_drivers::safety::Envelope;

use super::PlanError;

/// A whole plan specification.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlanSpec {
    /// Plan name (written into the plan file).
    pub name: String,
    /// Free text.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub description: Option<String>,
    /// Seed of the random generator (deterministic plans).
    #[serde(default)]
    pub seed: u64,
    /// `group` label of the poses (`train`, `validation`, ...).
    #[serde(default = "default_group")]
    pub group: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub annulus: Option<AnnulusSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shell: Option<ShellSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub planes: Option<PlanesSpec>,
    /// Seed 002: instrument poses pivoting about a trocar (the tool is the instrument's tip).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rcm: Option<super::rcm::RcmSpecTable>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub validation: Option<ValidationSpec>,
    /// The measured point / sensor in the flange frame (marker, probe tip, laser, camera).
    #[serde(default)]
    pub tool: FrameSpec,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tracker: Option<TrackerSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub laser: Option<LaserSpec>,
    #[serde(default)]
    pub constraints: ConstraintSpec,
    #[serde(default)]
    pub timing: TimingSpec,
    #[serde(default)]
    pub observability: ObservabilitySpec,
    /// The cell's geometry (tracker pose, measurement volume, view angle, occluders) as the
    /// cell file states it; when present it replaces `tracker` in the visibility checks.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cell: Option<super::cell::CellGeometry>,
}

fn default_group() -> String {
    "train".into()
}

/// A fixed frame: translation (mm) then URDF roll-pitch-yaw (deg, `R = Rz·Ry·Rx`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct FrameSpec {
    #[serde(default)]
    pub xyz: [f64; 3],
    #[serde(default)]
    pub rpy: [f64; 3],
}

/// Seed 001 §4.2: random points in a cylindrical annulus about the base z axis, random
/// end-effector attitude, every feasible IK branch of each point.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AnnulusSpec {
    /// Number of random points.
    pub points: usize,
    /// Azimuth range about base z (deg), 0 = base +x.
    pub angle_deg: [f64; 2],
    /// Radius range (mm).
    pub radius_mm: [f64; 2],
    /// Height range (mm, base z).
    pub height_mm: [f64; 2],
    /// Attitude of the tool frame, fixed axes: `R = Rz(z)·Ry(y)·Rx(x)` (deg).
    pub attitude_x_deg: [f64; 2],
    pub attitude_y_deg: [f64; 2],
    pub attitude_z_deg: [f64; 2],
    /// Keep only points reached by at least this many IK branches (seed 001 validation:
    /// the inverse-solution coincidence test needs ≥ 2).
    #[serde(default = "one")]
    pub min_branches: usize,
}

fn one() -> usize {
    1
}

/// Seed 004: camera viewpoints on a spherical shell about a target centre.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShellSpec {
    /// Target (marker) centre in the robot base (mm).
    pub center_mm: [f64; 3],
    /// Pole direction of the spherical coordinates in the robot base (the marker normal).
    #[serde(default = "up")]
    pub pole: [f64; 3],
    /// Azimuth zero direction (projected onto the plane normal to the pole).
    #[serde(default = "xdir")]
    pub azimuth_zero: [f64; 3],
    pub radius_mm: [f64; 2],
    pub polar_deg: [f64; 2],
    pub azimuth_deg: [f64; 2],
    /// Strata per coordinate: `[n_r, n_theta, n_alpha]`.
    pub strata: [usize; 3],
    /// Jitter inside each stratum (false: cell centres).
    #[serde(default)]
    pub jitter: bool,
    /// Keep only the best IK branch per viewpoint (true) or every feasible branch.
    #[serde(default = "yes")]
    pub best_branch_only: bool,
}

fn up() -> [f64; 3] {
    [0.0, 0.0, 1.0]
}
fn xdir() -> [f64; 3] {
    [1.0, 0.0, 0.0]
}
fn yes() -> bool {
    true
}

/// One planar target in the robot base.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlaneTarget {
    /// Label (`P1`, `P2`, `P3`, or a validation target name).
    pub name: String,
    /// Centre of the usable rectangle (mm, robot base).
    pub center_mm: [f64; 3],
    /// Outward normal (towards the sensor).
    pub normal: [f64; 3],
    /// In-plane u direction (projected to be normal to `normal`).
    pub u_axis: [f64; 3],
    /// Rectangle size along u and v (mm).
    pub size_mm: [f64; 2],
}

/// Seed 000 §2.2: laser calibration on (three orthogonal) planes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlanesSpec {
    pub planes: Vec<PlaneTarget>,
    /// Blocks per plane as a `[nu, nv]` grid of similar-area rectangles (seed: 15 = 5 × 3).
    pub blocks: [usize; 2],
    /// Laser stand-off range from the plane (mm).
    pub standoff_mm: [f64; 2],
    /// Incidence (beam vs. plane normal) of the three translation groups (deg).
    pub translate_tilt_deg: [f64; 3],
    /// Maximum incidence of the rotation+translation move (deg).
    pub rotate_max_deg: f64,
    /// Roll of the sensor about the beam for the translation groups (deg).
    #[serde(default)]
    pub roll_deg: f64,
}

/// Validation sets.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ValidationSpec {
    /// Seed 000 §2.3.1: per target the plane normal plus four directions tilted by
    /// `tilt_deg` and spaced 90° about it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub five_direction: Option<FiveDirectionSpec>,
    /// Seed 001 §4.4: random annulus poses reached by all feasible IK branches.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub coincidence: Option<AnnulusSpec>,
}

/// Five-direction validation on a plane.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FiveDirectionSpec {
    pub plane: PlaneTarget,
    /// Targets = block centres of a `[nu, nv]` grid (seed: 10 = 5 × 2).
    pub targets: [usize; 2],
    /// Laser stand-off along the beam (mm).
    pub standoff_mm: f64,
    /// Tilt of the four oblique directions from the normal (deg, seed: ≈45).
    pub tilt_deg: f64,
    /// Azimuth of the first oblique direction about the normal, from the plane's u axis
    /// (deg); the others follow at +90°, +180°, +270°.
    #[serde(default)]
    pub azimuth0_deg: f64,
}

/// Tracker model used by the visibility check.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TrackerKind {
    /// NDI Polaris Vega, pyramid volume.
    PolarisVega,
    /// NDI Polaris Vega, extended pyramid volume.
    PolarisVegaExtended,
    /// NDI Polaris Spectra, pyramid volume.
    PolarisSpectra,
    /// NDI Optotrak Certus.
    OptotrakCertus,
}

/// Where the tracker is and how the marker must face it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrackerSpec {
    pub kind: TrackerKind,
    /// Tracker pose in the robot base. The measurement volume lies along the tracker's −z
    /// (NDI convention), tracker +y up in its images.
    pub pose: FrameSpec,
    /// Marker normal in the tool frame (unit vector).
    #[serde(default = "up")]
    pub marker_normal: [f64; 3],
    /// Largest angle between marker normal and the line of sight to the tracker (deg).
    #[serde(default = "sixty")]
    pub max_angle_deg: f64,
}

fn sixty() -> f64 {
    60.0
}

/// Laser displacement sensor (beam = tool z axis from the tool origin).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LaserSpec {
    /// Measuring window (mm). IL-600: 200–1000.
    #[serde(default = "il600")]
    pub range_mm: [f64; 2],
    /// Largest incidence angle (deg).
    #[serde(default = "twenty")]
    pub max_incidence_deg: f64,
}

fn il600() -> [f64; 2] {
    [200.0, 1000.0]
}
fn twenty() -> f64 {
    20.0
}

/// Pose constraints.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConstraintSpec {
    /// Margin inside the joint limits (deg).
    #[serde(default)]
    pub joint_margin_deg: f64,
    /// Table plane height in the robot base (mm); every arm point stays above it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub table_z_mm: Option<f64>,
    /// Clearance above the table (mm).
    #[serde(default = "fifty")]
    pub table_clearance_mm: f64,
    /// Capsule radius of the arm links (mm) for self-collision.
    #[serde(default = "forty")]
    pub link_radius_mm: f64,
    /// Capsule radius of the tool (flange → tool point) (mm).
    #[serde(default = "twenty")]
    pub tool_radius_mm: f64,
    /// Check self-collision.
    #[serde(default = "yes")]
    pub self_collision: bool,
    /// Cartesian envelope (the safety wrappers' type) every arm check point stays in.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub envelope: Option<Envelope>,
}

fn fifty() -> f64 {
    50.0
}
fn forty() -> f64 {
    40.0
}

impl Default for ConstraintSpec {
    fn default() -> Self {
        ConstraintSpec {
            joint_margin_deg: 0.0,
            table_z_mm: None,
            table_clearance_mm: 50.0,
            link_radius_mm: 40.0,
            tool_radius_mm: 20.0,
            self_collision: true,
            envelope: None,
        }
    }
}

/// Time model of a session (per-joint trapezoidal profiles).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimingSpec {
    /// Joint speed cap (deg/s), one value for all joints or one per joint.
    #[serde(default = "speed_default")]
    pub speed_deg_s: Vec<f64>,
    /// Joint acceleration cap (deg/s²).
    #[serde(default = "acc_default")]
    pub accel_deg_s2: Vec<f64>,
    /// Settling time after each move (s).
    #[serde(default = "settle_default")]
    pub settle_s: f64,
    /// Measurement time per pose (s), e.g. averaging 30 tracker frames.
    #[serde(default = "sample_default")]
    pub sample_s: f64,
    /// Start (and home) joint configuration (deg); zeros when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub home_deg: Option<Vec<f64>>,
}

fn speed_default() -> Vec<f64> {
    vec![60.0]
}
fn acc_default() -> Vec<f64> {
    vec![120.0]
}
fn settle_default() -> f64 {
    1.5
}
fn sample_default() -> f64 {
    2.0
}

impl Default for TimingSpec {
    fn default() -> Self {
        TimingSpec {
            speed_deg_s: speed_default(),
            accel_deg_s2: acc_default(),
            settle_s: settle_default(),
            sample_s: sample_default(),
            home_deg: None,
        }
    }
}

/// How the identification Jacobian is built.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObservabilitySpec {
    /// Fix the parameters point measurements cannot separate (joint 1 vs base, last joint
    /// vs tool position) before judging identifiability.
    #[serde(default = "yes")]
    pub fix_point_redundancies: bool,
    /// Extra parameters to fix (by name).
    #[serde(default)]
    pub fixed: Vec<String>,
    /// Singular values below `rel_tol · σ_1` mark unidentifiable directions.
    #[serde(default = "rel_tol")]
    pub rel_tol: f64,
}

fn rel_tol() -> f64 {
    1e-6
}

impl Default for ObservabilitySpec {
    fn default() -> Self {
        ObservabilitySpec {
            fix_point_redundancies: true,
            fixed: Vec::new(),
            rel_tol: rel_tol(),
        }
    }
}

impl PlanSpec {
    /// Parse and validate a TOML spec.
    pub fn from_toml_str(s: &str) -> Result<Self, PlanError> {
        let spec: PlanSpec = toml::from_str(s).map_err(|e| PlanError::Spec {
            message: crate::schema::kind::with_toml_hint(
                &e,
                s,
                crate::schema::kind::TomlKind::PlanSpec,
            ),
        })?;
        spec.validate()?;
        Ok(spec)
    }

    /// Read a TOML spec file.
    pub fn from_file(path: &std::path::Path) -> Result<Self, PlanError> {
        let s = crate::fsio::read_to_string(path).map_err(|e| PlanError::Io {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
        Self::from_toml_str(&s)
    }

    /// Check ranges and that exactly one generator is given.
    pub fn validate(&self) -> Result<(), PlanError> {
        let bad = |m: String| Err(PlanError::Spec { message: m });
        let n = [
            self.annulus.is_some(),
            self.shell.is_some(),
            self.planes.is_some(),
            self.rcm.is_some(),
            self.validation.is_some(),
        ]
        .iter()
        .filter(|b| **b)
        .count();
        if n != 1 {
            return bad(format!(
                "exactly one of [annulus], [shell], [planes], [rcm], [validation] is required, got {n}"
            ));
        }
        if let Some(r) = &self.rcm {
            r.to_spec(self.seed, 0.0)
                .check()
                .map_err(|e| PlanError::Spec {
                    message: format!("[rcm]: {e}"),
                })?;
        }
        // Every number finite and within a plausible magnitude (mm, deg, s): a NaN or 1e308
        // would otherwise loop or allocate without bound further down.
        if let Ok(v) = toml::Value::try_from(self) {
            if let Some((path, x)) = implausible_float(&v, String::new()) {
                return bad(format!(
                    "{path} = {x}: not a finite number within ±{MAX_MAGNITUDE:e} (files use mm, \
                     degrees, seconds)"
                ));
            }
        }
        let count = self.target_count();
        if count > MAX_TARGETS {
            return bad(format!(
                "{} targets requested (points / strata / blocks): more than {MAX_TARGETS}; a \
                 calibration needs a few hundred (seed 001: 200 points)",
                count
            ));
        }
        let range = |name: &str, r: [f64; 2]| -> Result<(), PlanError> {
            if !(r[0].is_finite() && r[1].is_finite() && r[0] <= r[1]) {
                return Err(PlanError::Spec {
                    message: format!("{name}: range [{}, {}] is not ordered", r[0], r[1]),
                });
            }
            Ok(())
        };
        if let Some(a) = &self.annulus {
            a.validate(&range)?;
        }
        if let Some(s) = &self.shell {
            range("shell.radius_mm", s.radius_mm)?;
            range("shell.polar_deg", s.polar_deg)?;
            range("shell.azimuth_deg", s.azimuth_deg)?;
            if s.radius_mm[0] <= 0.0 || s.strata.contains(&0) {
                return bad("shell: radius must be > 0 and every stratum count ≥ 1".into());
            }
        }
        if let Some(p) = &self.planes {
            range("planes.standoff_mm", p.standoff_mm)?;
            if p.planes.is_empty() || p.blocks[0] == 0 || p.blocks[1] == 0 {
                return bad("planes: need at least one plane and ≥ 1 block per side".into());
            }
            for pl in &p.planes {
                pl.validate()?;
            }
        }
        if let Some(v) = &self.validation {
            if v.five_direction.is_none() && v.coincidence.is_none() {
                return bad(
                    "validation: give [validation.five_direction] and/or [validation.coincidence]"
                        .into(),
                );
            }
            if let Some(f) = &v.five_direction {
                f.plane.validate()?;
                if f.targets[0] == 0 || f.targets[1] == 0 || f.standoff_mm <= 0.0 {
                    return bad("validation.five_direction: targets ≥ 1, standoff > 0".into());
                }
            }
            if let Some(c) = &v.coincidence {
                c.validate(&range)?;
            }
        }
        if let Some(l) = &self.laser {
            range("laser.range_mm", l.range_mm)?;
        }
        let t = &self.timing;
        if t.settle_s > MAX_WAIT_S || t.sample_s > MAX_WAIT_S {
            return bad(format!(
                "timing: settle_s {} / sample_s {}: at most {MAX_WAIT_S} s per pose",
                t.settle_s, t.sample_s
            ));
        }
        if t.speed_deg_s.is_empty()
            || t.accel_deg_s2.is_empty()
            || t.speed_deg_s
                .iter()
                .chain(&t.accel_deg_s2)
                .any(|v| v.is_nan() || *v <= 0.0)
            || !(t.settle_s >= 0.0 && t.sample_s >= 0.0)
        {
            return bad("timing: speeds and accelerations must be > 0, times ≥ 0".into());
        }
        Ok(())
    }
}

/// Most targets a spec may request (seed 001 uses 200; the plan is kept in memory).
pub const MAX_TARGETS: usize = 100_000;
/// Largest magnitude of any number in a spec (mm, deg, s).
pub const MAX_MAGNITUDE: f64 = 1.0e6;
/// Longest settle / sample time per pose (s).
pub const MAX_WAIT_S: f64 = 600.0;

impl PlanSpec {
    /// Number of targets the generator will draw (saturating).
    pub fn target_count(&self) -> usize {
        let prod = |v: &[usize]| v.iter().fold(1usize, |a, &b| a.saturating_mul(b));
        let mut n = 0usize;
        if let Some(a) = &self.annulus {
            n = n.saturating_add(a.points);
        }
        if let Some(s) = &self.shell {
            n = n.saturating_add(prod(&s.strata));
        }
        if let Some(p) = &self.planes {
            n = n.saturating_add(prod(&[p.planes.len(), p.blocks[0], p.blocks[1], 10]));
        }
        if let Some(r) = &self.rcm {
            n = n.saturating_add(r.points);
        }
        if let Some(v) = &self.validation {
            if let Some(f) = &v.five_direction {
                n = n.saturating_add(prod(&[f.targets[0], f.targets[1], 5]));
            }
            if let Some(c) = &v.coincidence {
                n = n.saturating_add(c.points);
            }
        }
        n
    }
}

/// The first float of a TOML tree that is not finite or beyond [`MAX_MAGNITUDE`].
fn implausible_float(v: &toml::Value, path: String) -> Option<(String, f64)> {
    match v {
        toml::Value::Float(f) if !f.is_finite() || f.abs() > MAX_MAGNITUDE => Some((path, *f)),
        toml::Value::Table(t) => t.iter().find_map(|(k, x)| {
            let p = if path.is_empty() {
                k.clone()
            } else {
                format!("{path}.{k}")
            };
            implausible_float(x, p)
        }),
        toml::Value::Array(a) => a
            .iter()
            .enumerate()
            .find_map(|(i, x)| implausible_float(x, format!("{path}[{i}]"))),
        _ => None,
    }
}

/// Checks that a `[lo, hi]` range is finite and ordered.
type RangeCheck = dyn Fn(&str, [f64; 2]) -> Result<(), PlanError>;

impl AnnulusSpec {
    fn validate(&self, range: &RangeCheck) -> Result<(), PlanError> {
        range("angle_deg", self.angle_deg)?;
        range("radius_mm", self.radius_mm)?;
        range("height_mm", self.height_mm)?;
        range("attitude_x_deg", self.attitude_x_deg)?;
        range("attitude_y_deg", self.attitude_y_deg)?;
        range("attitude_z_deg", self.attitude_z_deg)?;
        if self.points == 0 || self.radius_mm[0] < 0.0 {
            return Err(PlanError::Spec {
                message: "annulus: points ≥ 1 and radius ≥ 0".into(),
            });
        }
        Ok(())
    }
}

impl PlaneTarget {
    fn validate(&self) -> Result<(), PlanError> {
        let n = nalgebra::Vector3::from(self.normal);
        let u = nalgebra::Vector3::from(self.u_axis);
        if n.norm() < 1e-9 || n.cross(&u).norm() < 1e-6 * n.norm() * u.norm().max(1e-12) {
            return Err(PlanError::Spec {
                message: format!(
                    "plane {}: normal must be non-zero and u_axis not parallel to it",
                    self.name
                ),
            });
        }
        if !(self.size_mm[0] > 0.0 && self.size_mm[1] > 0.0) {
            return Err(PlanError::Spec {
                message: format!("plane {}: size must be > 0", self.name),
            });
        }
        Ok(())
    }
}
