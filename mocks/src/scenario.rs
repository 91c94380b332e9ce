//! Scenario files: strict TOML (`deny_unknown_fields`) describing one simulated cell.
//!
//! Units in files: mm, degrees, seconds (names carry the unit). See `mocks/scenarios/*.toml`.

use crate::world::effects::{ArmEffects, PointMass};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Why a scenario could not be loaded or built.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ScenarioError {
    /// The file could not be read.
    #[error("cannot read scenario {path}: {source}")]
    Io {
        /// File path.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// The TOML is malformed or has unknown fields.
    #[error("invalid scenario: {0}")]
    Toml(#[from] toml::de::Error),
    /// The scenario is consistent TOML but names something that does not exist.
    #[error("invalid scenario: {0}")]
    Invalid(String),
}

/// The wire protocol a simulated device speaks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Protocol {
    /// DENSO b-CAP (TCP 5007).
    Bcap,
    /// Universal Robots: RTDE (30004) + dashboard (29999) + script (30001–30003).
    Ur,
    /// NDI API over TCP (Vega, 8765).
    NdiTcp,
    /// NDI API over a serial port (Polaris Spectra/Vicra), served on a pty.
    NdiSerial,
    /// KEYENCE DL-RS1A (IL-series amplifier), served on a pty.
    #[serde(rename = "dl-rs1a")]
    DlRs1a,
    /// NDI Optotrak (Certus).
    Optotrak,
    /// A camera (image source).
    Camera,
}

impl Protocol {
    /// The name used in files and endpoint listings.
    pub fn as_str(self) -> &'static str {
        match self {
            Protocol::Bcap => "bcap",
            Protocol::Ur => "ur",
            Protocol::NdiTcp => "ndi-tcp",
            Protocol::NdiSerial => "ndi-serial",
            Protocol::DlRs1a => "dl-rs1a",
            Protocol::Optotrak => "optotrak",
            Protocol::Camera => "camera",
        }
    }
}

/// Virtual (simulated, jumps) or real (wall-clock) time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ClockMode {
    /// Every operation advances simulated time by its duration instantly.
    #[default]
    Virtual,
    /// Durations pass on the wall clock.
    Real,
}

/// A rigid placement: translation (mm) then URDF roll-pitch-yaw (deg).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Placement {
    /// Translation (mm).
    pub xyz_mm: [f64; 3],
    /// URDF roll-pitch-yaw (deg).
    #[serde(default)]
    pub rpy_deg: [f64; 3],
}

impl Placement {
    /// As an isometry (mm).
    pub fn isometry(&self) -> nalgebra::Isometry3<f64> {
        crate::world::chain::fixed_transform_deg(self.xyz_mm, self.rpy_deg)
    }
}

/// Magnitudes of the hidden geometric errors (each drawn as ±U[lo, hi]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GeometricErrors {
    /// Joint-origin translation error per component (mm).
    #[serde(default = "d_origin_mm")]
    pub origin_mm: [f64; 2],
    /// Joint-origin rpy error per component (deg).
    #[serde(default = "d_origin_deg")]
    pub origin_deg: [f64; 2],
    /// Joint zero-offset error (deg).
    #[serde(default = "d_origin_deg")]
    pub offset_deg: [f64; 2],
    /// Seed of the errors (default: derived from the scenario seed and the arm index).
    #[serde(default)]
    pub seed: Option<u64>,
}

fn d_origin_mm() -> [f64; 2] {
    [0.1, 0.3]
}
fn d_origin_deg() -> [f64; 2] {
    [0.02, 0.05]
}

impl Default for GeometricErrors {
    fn default() -> Self {
        Self {
            origin_mm: d_origin_mm(),
            origin_deg: d_origin_deg(),
            offset_deg: d_origin_deg(),
            seed: None,
        }
    }
}

impl GeometricErrors {
    /// No geometric error at all (true = nominal).
    pub fn none() -> Self {
        Self {
            origin_mm: [0.0; 2],
            origin_deg: [0.0; 2],
            offset_deg: [0.0; 2],
            seed: None,
        }
    }
}

/// Motion caps and settling of a simulated controller.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionConfig {
    /// Joint speed cap of the controller (deg/s).
    #[serde(default = "d_vel")]
    pub max_vel_deg_s: f64,
    /// Joint acceleration cap of the controller (deg/s²).
    #[serde(default = "d_acc")]
    pub max_acc_deg_s2: f64,
    /// Settling time after the profile ends (s).
    #[serde(default = "d_settle")]
    pub settle_s: f64,
}
fn d_vel() -> f64 {
    180.0
}
fn d_acc() -> f64 {
    360.0
}
fn d_settle() -> f64 {
    0.3
}
impl Default for MotionConfig {
    fn default() -> Self {
        Self {
            max_vel_deg_s: d_vel(),
            max_acc_deg_s2: d_acc(),
            settle_s: d_settle(),
        }
    }
}

/// A payload on the flange.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Payload {
    /// Mass (kg).
    pub kg: f64,
    /// Centre of mass in the flange frame (mm).
    pub xyz_mm: [f64; 3],
}

/// One simulated arm.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArmConfig {
    /// Device name (unique in the scenario).
    pub name: String,
    /// Nominal model preset: `denso-vs060`, `ur5e`, `ur10e`.
    pub model: String,
    /// Wire protocol (`bcap` or `ur`).
    pub protocol: Protocol,
    /// Serial number reported by the controller.
    #[serde(default)]
    pub serial: String,
    /// Hidden geometric errors.
    #[serde(default)]
    pub errors: GeometricErrors,
    /// Link point masses (for compliance and deflection).
    #[serde(default, rename = "mass")]
    pub masses: Vec<PointMass>,
    /// Payload on the flange.
    #[serde(default)]
    pub payload: Option<Payload>,
    /// Hidden physical effects.
    #[serde(default)]
    pub effects: ArmEffects,
    /// Motion caps.
    #[serde(default)]
    pub motion: MotionConfig,
    /// Initial joint angles (deg); default all zero.
    #[serde(default)]
    pub home_deg: Option<Vec<f64>>,
    /// The cell's own safety limits around this arm (table plane, envelope; robot base
    /// frame): a plan run on this cell may be stricter, never wider.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub safety: Option<CellSafety>,
}

/// A cell's safety limits in the robot base frame (mm): what the cell is, whatever a plan
/// file says.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CellSafety {
    /// Table plane height (mm): no arm check point below it.
    #[serde(default)]
    pub table_z_mm: Option<f64>,
    /// Least clearance above the table (mm).
    #[serde(default)]
    pub table_clearance_mm: Option<f64>,
    /// Cartesian envelope every arm check point stays in.
    #[serde(default)]
    pub envelope: Option<robocal_drivers::safety::Envelope>,
}

/// Tracker model (sets the default measurement volume).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TrackerKind {
    /// NDI Polaris Vega.
    NdiPolarisVega,
    /// NDI Polaris Spectra.
    NdiPolarisSpectra,
    /// NDI Optotrak Certus.
    NdiOptotrakCertus,
}

impl TrackerKind {
    /// The name used in dataset headers.
    pub fn as_str(self) -> &'static str {
        match self {
            TrackerKind::NdiPolarisVega => "ndi-polaris-vega",
            TrackerKind::NdiPolarisSpectra => "ndi-polaris-spectra",
            TrackerKind::NdiOptotrakCertus => "ndi-optotrak-certus",
        }
    }
}

/// A measurement volume, along the tracker's −z (line of sight) axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum VolumeKind {
    /// Polaris Vega/Spectra pyramid: depth 950–2400 mm.
    PolarisPyramid,
    /// Polaris Vega/Spectra extended pyramid: depth 950–3000 mm.
    PolarisExtended,
    /// Optotrak Certus: depth 1000–6000 mm, wide.
    Optotrak,
    /// No volume limit.
    Unbounded,
}

/// A sphere that blocks the line of sight (base frame).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Occluder {
    /// Centre in the robot base frame (mm).
    pub center_mm: [f64; 3],
    /// Radius (mm).
    pub radius_mm: f64,
}

/// The tracker is knocked at `t_s`: its placement in the base frame is pre-multiplied by a
/// rigid motion (translation `shift_mm`, URDF rpy `rot_deg`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BaseBump {
    /// Time of the bump (s).
    pub t_s: f64,
    /// Translation of the bump (mm, base frame).
    pub shift_mm: [f64; 3],
    /// Rotation of the bump (deg, URDF rpy about the tracker origin).
    #[serde(default)]
    pub rot_deg: [f64; 3],
}

/// Hidden tracker effects (all off by default).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrackerEffects {
    /// Per-frame noise across the line of sight, 1σ per axis (mm).
    #[serde(default)]
    pub noise_lateral_mm: f64,
    /// Per-frame noise along the line of sight, 1σ (mm).
    #[serde(default)]
    pub noise_depth_mm: f64,
    /// Per-frame orientation noise, 1σ per axis (deg).
    #[serde(default)]
    pub noise_rot_deg: f64,
    /// Scale error of every reading about the tracker origin (ppm).
    #[serde(default)]
    pub scale_ppm: f64,
    /// Scale error of the depth (the tracker's z axis, its viewing axis) alone (ppm): a
    /// camera-bar baseline error.
    #[serde(default)]
    pub depth_scale_ppm: f64,
    /// Measurement volume (default: the kind's pyramid).
    #[serde(default)]
    pub volume: Option<VolumeKind>,
    /// Marker visible only when its z axis is within this angle of the line of sight (deg).
    #[serde(default)]
    pub max_view_angle_deg: Option<f64>,
    /// Spheres blocking the line of sight.
    #[serde(default, rename = "occluder")]
    pub occluders: Vec<Occluder>,
    /// A bump of the tracker at a given time.
    #[serde(default)]
    pub base_bump: Option<BaseBump>,
    /// Latency: a frame stamped t shows the marker at t − latency (s).
    #[serde(default)]
    pub latency_s: f64,
}

/// One optical tracker observing a marker on one arm's flange.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrackerConfig {
    /// Device name.
    pub name: String,
    /// Tracker model.
    pub kind: TrackerKind,
    /// Wire protocol (`ndi-tcp`, `ndi-serial`, `optotrak`).
    pub protocol: Protocol,
    /// Name of the arm carrying the marker.
    pub arm: String,
    /// Frame rate (Hz).
    #[serde(default = "d_rate")]
    pub rate_hz: f64,
    /// Tracker pose in the robot base frame.
    pub tracker_in_base: Placement,
    /// Marker (tool) pose in the flange frame.
    pub marker_on_flange: Placement,
    /// Tool name / handle reported in frames.
    #[serde(default = "d_tool")]
    pub tool: String,
    /// Marker fit RMS the tracker reports (mm).
    #[serde(default = "d_fit")]
    pub fit_rms_mm: f64,
    /// Hidden effects.
    #[serde(default)]
    pub effects: TrackerEffects,
}
fn d_rate() -> f64 {
    60.0
}
fn d_tool() -> String {
    "probe".into()
}
fn d_fit() -> f64 {
    0.05
}

/// Hidden laser effects (all off by default).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LaserEffects {
    /// Repeatability noise, 1σ (mm) (IL-600 ≈ 0.05).
    #[serde(default)]
    pub noise_mm: f64,
    /// Scale error (ppm of the distance).
    #[serde(default)]
    pub scale_ppm: f64,
    /// Offset (mm).
    #[serde(default)]
    pub offset_mm: f64,
    /// Incidence bias: reading += incidence_mm · (1 − cos γ).
    #[serde(default)]
    pub incidence_mm: f64,
    /// Range nonlinearity, a bow over the measuring range: reading += nonlinearity_mm · u²,
    /// u = (d − mid) / half (−1 at `min_mm`, +1 at `max_mm`).
    #[serde(default)]
    pub nonlinearity_mm: f64,
}

/// A laser displacement sensor on one arm's flange.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LaserConfig {
    /// Device name.
    pub name: String,
    /// Sensor model (free text, e.g. `keyence-il600`).
    #[serde(default = "d_laser_kind")]
    pub kind: String,
    /// Wire protocol (`dl-rs1a`).
    pub protocol: Protocol,
    /// Arm carrying the sensor.
    pub arm: String,
    /// Beam origin in the flange frame (mm).
    pub beam_origin_mm: [f64; 3],
    /// Beam direction in the flange frame (normalised on load).
    pub beam_dir: [f64; 3],
    /// Near end of the range window (mm).
    #[serde(default = "d_min")]
    pub min_mm: f64,
    /// Far end of the range window (mm).
    #[serde(default = "d_max")]
    pub max_mm: f64,
    /// No reading beyond this incidence angle (deg).
    #[serde(default = "d_max_inc")]
    pub max_incidence_deg: f64,
    /// Sampling rate (Hz).
    #[serde(default = "d_laser_rate")]
    pub rate_hz: f64,
    /// Hidden effects.
    #[serde(default)]
    pub effects: LaserEffects,
}
fn d_laser_kind() -> String {
    "keyence-il600".into()
}
fn d_min() -> f64 {
    200.0
}
fn d_max() -> f64 {
    1000.0
}
fn d_max_inc() -> f64 {
    60.0
}
fn d_laser_rate() -> f64 {
    1000.0
}

/// A pinhole camera (with radial distortion) looking at the chessboard.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// Device name.
    pub name: String,
    /// Wire protocol (`camera`).
    pub protocol: Protocol,
    /// Arm carrying the camera (eye-in-hand); absent = fixed in the base frame.
    #[serde(default)]
    pub arm: Option<String>,
    /// Camera pose in the flange frame (eye-in-hand) or in the base frame (fixed). Camera
    /// frame: z along the optical axis, x right, y down.
    pub placement: Placement,
    /// Image width (px).
    pub width: u32,
    /// Image height (px).
    pub height: u32,
    /// Focal length x (px).
    pub fx: f64,
    /// Focal length y (px).
    pub fy: f64,
    /// Principal point x (px).
    pub cx: f64,
    /// Principal point y (px).
    pub cy: f64,
    /// Radial distortion k1.
    #[serde(default)]
    pub k1: f64,
    /// Radial distortion k2.
    #[serde(default)]
    pub k2: f64,
    /// Gaussian blur σ (px).
    #[serde(default)]
    pub blur_px: f64,
    /// Grey-level noise σ (0–255 scale).
    #[serde(default)]
    pub noise_grey: f64,
}

/// An infinite calibration plane.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlaneConfig {
    /// Label (`P1`, `P2`, `P3`).
    pub name: String,
    /// Unit normal (base frame), pointing to the side the sensor is on.
    pub normal: [f64; 3],
    /// A point on the plane (mm, base frame).
    pub through_mm: [f64; 3],
}

/// A validation target on the plate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetConfig {
    /// Label.
    pub label: String,
    /// Position on the plate (plate x, y in mm).
    pub xy_mm: [f64; 2],
}

/// A flat plate carrying validation targets (plate frame: targets in its xy plane, z = normal).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlateConfig {
    /// Plate pose in the base frame.
    pub placement: Placement,
    /// Plate size (x, y) in mm, centred on the placement origin.
    pub size_mm: [f64; 2],
    /// The targets.
    #[serde(default, rename = "target")]
    pub targets: Vec<TargetConfig>,
    /// The operator centres the laser spot on the targets (seed 000 §2.3.1), if given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub centring: Option<Centring>,
}

/// How the operator centres the laser spot on a plate target: after each move, a spot within
/// `capture_mm` of a target is jogged onto it, to within a 1σ aiming error of `sd_mm` per axis
/// (seed 000 §3: the 1.6 mm spot on a 0.8 mm dot, about 0.4 mm by eye).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Centring {
    /// Capture radius on the plate (mm).
    pub capture_mm: f64,
    /// Aiming error, 1σ per plate axis (mm).
    #[serde(default)]
    pub sd_mm: f64,
}

/// A machined block (a box).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BlockConfig {
    /// Pose of the block centre in the base frame.
    pub placement: Placement,
    /// Edge lengths (mm).
    pub size_mm: [f64; 3],
}

/// A cylindrical instrument pivoting through a remote centre of motion.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InstrumentConfig {
    /// Remote centre of motion in the base frame (mm).
    pub rcm_mm: [f64; 3],
    /// Shaft radius (mm).
    pub radius_mm: f64,
    /// Shaft length (mm), from the flange along the flange z axis.
    pub length_mm: f64,
    /// Nominal insertion direction (into the body), base frame: orients the tissue texture
    /// of the endoscope image.
    #[serde(default = "d_insertion_dir")]
    pub insertion_dir: [f64; 3],
    /// How a fixed camera renders the instrument through the trocar (the endoscope view of
    /// seed 002: body cavity, tissue blobs, specular shaft; `crate::rcm_render`). The camera's
    /// `blur_px` and `noise_grey` replace the table's.
    #[serde(default)]
    pub render: crate::rcm_render::RcmRenderConfig,
}

fn d_insertion_dir() -> [f64; 3] {
    [0.0, 0.0, -1.0]
}

/// A chessboard (board frame: squares in its xy plane, origin at an outer corner).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChessboardConfig {
    /// Board pose in the base frame.
    pub placement: Placement,
    /// Number of squares along x.
    pub cols: u32,
    /// Number of squares along y.
    pub rows: u32,
    /// Square edge (mm).
    pub square_mm: f64,
    /// Bow of the board about its y axis (mm): the board's surface is
    /// `z = bend_mm·(1 − (2x/W − 1)²)` over its width `W = cols·square_mm` (0 = flat).
    #[serde(default)]
    pub bend_mm: f64,
    /// ChArUco markers in the white squares (absent = a plain chessboard). See
    /// [`CharucoConfig`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub charuco: Option<CharucoConfig>,
}

/// ArUco markers printed in the white squares of a [`ChessboardConfig`] (OpenCV's ChArUco
/// layout: square `(0, 0)` dark, markers on the squares with `a + b` odd, ids counted row by
/// row from 0, each marker centred in its square, one-cell black border). The board frame is
/// then OpenCV's ChArUco frame: the markers read correctly seen from the board's −z side (x
/// right, y down as printed), so a camera looks at the printed face along +z.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CharucoConfig {
    /// Marker edge (mm), less than the square edge.
    pub marker_mm: f64,
    /// OpenCV dictionary name (`DICT_4X4_50`, `DICT_5X5_100`, ...).
    pub dictionary: String,
}

/// Passive objects of the cell.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneConfig {
    /// Calibration planes.
    #[serde(default, rename = "plane")]
    pub planes: Vec<PlaneConfig>,
    /// Validation plate.
    #[serde(default)]
    pub plate: Option<PlateConfig>,
    /// Machined block.
    #[serde(default)]
    pub block: Option<BlockConfig>,
    /// RCM instrument.
    #[serde(default)]
    pub instrument: Option<InstrumentConfig>,
    /// Chessboard target.
    #[serde(default)]
    pub chessboard: Option<ChessboardConfig>,
}

/// One simulated cell.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// Scenario name.
    pub name: String,
    /// Free text.
    #[serde(default)]
    pub description: String,
    /// Seed of every random draw (hidden errors, noise).
    pub seed: u64,
    /// Virtual or real time.
    #[serde(default)]
    pub clock: ClockMode,
    /// Arms.
    #[serde(default, rename = "arm")]
    pub arms: Vec<ArmConfig>,
    /// Trackers.
    #[serde(default, rename = "tracker")]
    pub trackers: Vec<TrackerConfig>,
    /// Laser range sensors.
    #[serde(default, rename = "laser")]
    pub lasers: Vec<LaserConfig>,
    /// Cameras.
    #[serde(default, rename = "camera")]
    pub cameras: Vec<CameraConfig>,
    /// Passive objects.
    #[serde(default)]
    pub scene: SceneConfig,
    /// The simulated operator (a scripted hand: pivots a probe, touches fiducials, drags an
    /// arm), for `robocal capture`.
    #[serde(default)]
    pub operator: Option<crate::world::operator::OperatorConfig>,
}

impl Scenario {
    /// Parse TOML text.
    pub fn from_toml(text: &str) -> Result<Self, ScenarioError> {
        let s: Scenario = toml::from_str(text)?;
        s.validate()?;
        Ok(s)
    }

    /// Value checks a simulation needs to terminate and to mean something: every number
    /// finite (a `nan` settling time never settles), rates, caps and times positive and
    /// bounded, image sizes bounded (no panic, no hang). Called by [`Scenario::from_toml`].
    pub fn validate(&self) -> Result<(), ScenarioError> {
        let bad = |m: String| Err(ScenarioError::Invalid(m));
        if let Ok(v) = toml::Value::try_from(self) {
            if let Some(path) = non_finite(&v, String::new()) {
                return bad(format!("{path}: not a finite number"));
            }
        }
        let within = |name: String, v: f64, lo: f64, hi: f64, open_lo: bool| {
            let ok = (if open_lo { v > lo } else { v >= lo }) && v <= hi;
            if ok {
                Ok(())
            } else {
                let l = if open_lo { "(" } else { "[" };
                Err(ScenarioError::Invalid(format!(
                    "{name} = {v} is outside {l}{lo}, {hi}]"
                )))
            }
        };
        for a in &self.arms {
            let n = |k: &str| format!("arm \"{}\" motion.{k}", a.name);
            within(
                n("max_vel_deg_s"),
                a.motion.max_vel_deg_s,
                0.0,
                10_000.0,
                true,
            )?;
            within(
                n("max_acc_deg_s2"),
                a.motion.max_acc_deg_s2,
                0.0,
                100_000.0,
                true,
            )?;
            within(n("settle_s"), a.motion.settle_s, 0.0, 600.0, false)?;
        }
        for t in &self.trackers {
            let n = |k: &str| format!("tracker \"{}\" {k}", t.name);
            within(n("rate_hz"), t.rate_hz, 0.0, 100_000.0, true)?;
            within(n("fit_rms_mm"), t.fit_rms_mm, 0.0, 100.0, false)?;
        }
        for l in &self.lasers {
            let n = |k: &str| format!("laser \"{}\" {k}", l.name);
            within(n("rate_hz"), l.rate_hz, 0.0, 100_000.0, true)?;
            within(n("min_mm"), l.min_mm, 0.0, 100_000.0, false)?;
            within(n("max_mm"), l.max_mm, l.min_mm, 100_000.0, true)?;
        }
        if let Some(c) = self.scene.plate.as_ref().and_then(|p| p.centring.as_ref()) {
            within(
                "scene.plate.centring.capture_mm".into(),
                c.capture_mm,
                0.0,
                1000.0,
                true,
            )?;
            within(
                "scene.plate.centring.sd_mm".into(),
                c.sd_mm,
                0.0,
                100.0,
                false,
            )?;
        }
        if let Some(ch) = self.scene.chessboard.as_ref() {
            if let Some(m) = &ch.charuco {
                crate::world::charuco::Pattern::new(ch.cols, ch.rows, ch.square_mm, m).map_err(
                    |e| ScenarioError::Invalid(format!("scene.chessboard.charuco: {e}")),
                )?;
            }
        }
        for c in &self.cameras {
            if c.width == 0 || c.height == 0 || c.width > 20_000 || c.height > 20_000 {
                return bad(format!(
                    "camera \"{}\": {}×{} pixels is outside 1..20000 each way",
                    c.name, c.width, c.height
                ));
            }
        }
        if let Some(op) = &self.operator {
            let probe = op.steps.iter().any(|s| {
                matches!(
                    s,
                    crate::world::operator::Step::Pivot { .. }
                        | crate::world::operator::Step::Touch { .. }
                )
            });
            if (probe || !op.tracker.is_empty())
                && !self.trackers.iter().any(|t| t.name == op.tracker)
            {
                return bad(format!(
                    "operator.tracker: no tracker named {:?}",
                    op.tracker
                ));
            }
            op.validate(|name| {
                self.arms
                    .iter()
                    .find(|a| a.name == name)
                    .and_then(|a| crate::world::chain::UrdfChain::preset(&a.model).map(|c| c.dof()))
            })
            .map_err(ScenarioError::Invalid)?;
        }
        Ok(())
    }

    /// Read and parse a file.
    pub fn load(path: &Path) -> Result<Self, ScenarioError> {
        let io = |source| ScenarioError::Io {
            path: path.display().to_string(),
            source,
        };
        // A scenario is a small regular file: a FIFO or device would block or never end.
        let meta = std::fs::metadata(path).map_err(io)?;
        if !meta.is_file() || meta.len() > 64 << 20 {
            return Err(io(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                if meta.is_file() {
                    "larger than 64 MiB: not a scenario file"
                } else {
                    "not a regular file (a directory, FIFO or device): give the scenario's TOML file"
                },
            )));
        }
        let text = std::fs::read_to_string(path).map_err(io)?;
        Self::from_toml(&text)
    }

    /// Every device with its protocol, in file order (arms, trackers, lasers, cameras).
    pub fn devices(&self) -> Vec<(String, Protocol)> {
        let mut v: Vec<(String, Protocol)> = Vec::new();
        v.extend(self.arms.iter().map(|a| (a.name.clone(), a.protocol)));
        v.extend(self.trackers.iter().map(|a| (a.name.clone(), a.protocol)));
        v.extend(self.lasers.iter().map(|a| (a.name.clone(), a.protocol)));
        v.extend(self.cameras.iter().map(|a| (a.name.clone(), a.protocol)));
        v
    }

    /// A minimal single-arm scenario: nominal `model` with default hidden geometric errors, one
    /// Optotrak-class tracker 1.8 m away looking at a marker on the flange, no effects, no noise.
    pub fn single_arm(model: &str, seed: u64) -> Self {
        let tracker_in_base = if model == "denso-vs060" {
            // Tracker in front of the arm, looking back at it (−z of the tracker toward −x).
            Placement {
                xyz_mm: [1700.0, 80.0, 650.0],
                rpy_deg: [180.0, -80.0, 0.0],
            }
        } else {
            Placement {
                xyz_mm: [-2200.0, -300.0, 700.0],
                rpy_deg: [180.0, 80.0, 0.0],
            }
        };
        Scenario {
            name: format!("{model}-single"),
            description: String::new(),
            seed,
            clock: ClockMode::Virtual,
            arms: vec![ArmConfig {
                name: "arm".into(),
                model: model.into(),
                protocol: if model.starts_with("ur") {
                    Protocol::Ur
                } else {
                    Protocol::Bcap
                },
                serial: format!("{}-SIM", model.to_uppercase()),
                errors: GeometricErrors::default(),
                masses: Vec::new(),
                payload: None,
                effects: ArmEffects::default(),
                motion: MotionConfig::default(),
                home_deg: None,
                safety: None,
            }],
            trackers: vec![TrackerConfig {
                name: "tracker".into(),
                kind: TrackerKind::NdiOptotrakCertus,
                protocol: Protocol::Optotrak,
                arm: "arm".into(),
                rate_hz: 60.0,
                tracker_in_base,
                marker_on_flange: Placement {
                    xyz_mm: [25.0, -10.0, 110.0],
                    rpy_deg: [0.0, 0.0, 30.0],
                },
                tool: "marker".into(),
                fit_rms_mm: 0.05,
                effects: TrackerEffects::default(),
            }],
            lasers: Vec::new(),
            cameras: Vec::new(),
            scene: SceneConfig::default(),
            operator: None,
        }
    }
}

/// The dotted path of the first non-finite float in a TOML value, if any.
fn non_finite(v: &toml::Value, path: String) -> Option<String> {
    match v {
        toml::Value::Float(f) if !f.is_finite() => Some(path),
        toml::Value::Table(t) => t.iter().find_map(|(k, x)| {
            let p = if path.is_empty() {
                k.clone()
            } else {
                format!("{path}.{k}")
            };
            non_finite(x, p)
        }),
        toml::Value::Array(a) => a
            .iter()
            .enumerate()
            .find_map(|(i, x)| non_finite(x, format!("{path}[{i}]"))),
        _ => None,
    }
}
