//! One typed serde schema per output file robocal writes: each writer serialises and every
//! reader (`robocal report`, `robocal session`, tests) deserialises the same struct, so a
//! field cannot drift between the two. Every file carries a `format` tag; every number's
//! unit is in its field name (`_mm`, `_deg`, `_s`, `_ppm`) or, for effect parameters, in
//! an explicit `unit` field. Files use mm, degrees, seconds (see `docs/dataset-format.md`).
//!
//! | file | type | format tag |
//! |---|---|---|
//! | `calibration.json` | [`CalibrationFile`] | `robocal-calibration/1` |
//! | `diagnosis.json` | [`DiagnosisFile`] | `robocal-diagnosis/2` |
//! | `summary.json` (run) | [`RunSummaryFile`] | `robocal-run-summary/1` |
//! | `laser_report.json` | [`LaserReportFile`] | `robocal-laser-report/1` |
//! | `scan_report.json` | [`ScanReportFile`] | `robocal-scan-report/1` |
//! | `plan.json` | [`PlanFile`] | `robocal-plan/1` |
//! | `pivot.json` | [`PivotFile`] | `robocal-pivot/1` |
//!
//! Reading is strict: [`read`] checks the format tag first (naming the file, the tag found
//! and the one expected), then deserialises, so an older or foreign file is a clear error.
// Every public item of a schema says what it is and its unit: the schema is the contract of
// the files other tools read.
#![warn(missing_docs)]
use std::path::Path;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

pub mod kind;
pub mod navnet;
pub mod points_csv;

pub use crate::acquire::summary::RunSummary;
pub use crate::dataset::{CalEffect, CalibrationFile};
pub use crate::plan::file::PlanFile;

// Every output format tag of robocal, one place; the modules that read and write each file
// re-export theirs.
/// A dataset (`*.jsonl`, JSON Lines).
pub const DATASET_FORMAT: &str = "robocal-dataset/1";
/// `calibration.json`.
pub const CALIBRATION_FORMAT: &str = "robocal-calibration/1";
/// A pose plan (`robocal plan --out`).
pub const PLAN_FORMAT: &str = "robocal-plan/1";
/// `run.json` of a run directory (how to resume it).
pub const RUN_FORMAT: &str = "robocal-run/1";
/// `session.json`.
pub const SESSION_FORMAT: &str = "robocal-session/1";
/// `registration.json` (CT ↔ tracker).
pub const REGISTRATION_FORMAT: &str = "robocal-registration/1";
/// `robot_world.json` (tracker ↔ robot base).
pub const ROBOT_WORLD_FORMAT: &str = "robocal-robot-world/1";
/// `chain.json` (the navigation error chain CT target → tool tip).
pub const CHAIN_FORMAT: &str = "robocal-chain/1";
/// `camera_report.json` of a camera calibration.
pub const CAMERA_REPORT_FORMAT: &str = "robocal-camera-report/1";
/// `rcm_report.json` of an RCM endoscope calibration.
pub const RCM_REPORT_FORMAT: &str = "robocal-rcm-report/1";
/// `robocal report --json`.
pub const REPORT_FORMAT: &str = "robocal-report/1";

/// `diagnosis.json`.
pub const DIAGNOSIS_FORMAT: &str = "robocal-diagnosis/2";
/// `summary.json` of `robocal run`.
pub const RUN_SUMMARY_FORMAT: &str = "robocal-run-summary/1";
/// `laser_report.json` of `robocal calibrate laser`.
pub const LASER_REPORT_FORMAT: &str = "robocal-laser-report/1";
/// `scan_report.json` of `robocal calibrate laser --scan`.
pub const SCAN_REPORT_FORMAT: &str = "robocal-scan-report/1";
/// `pivot.json` of `robocal calibrate pivot`.
pub const PIVOT_FORMAT: &str = "robocal-pivot/1";

/// Errors reading or writing a schema file.
#[derive(Debug, thiserror::Error)]
pub enum SchemaError {
    /// The file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// The file is not JSON.
    #[error("{path}: not JSON: {source}")]
    Json {
        /// The file.
        path: String,
        /// The parser's error (line and column).
        #[source]
        source: serde_json::Error,
    },
    /// The file is not JSON as a whole, but is another robocal file (a JSON Lines dataset).
    #[error("{path}: {what} (not one JSON document: {source})")]
    OtherKind {
        /// The file.
        path: String,
        /// What the file is instead ([`kind::other_kind`]).
        what: String,
        /// The parser's error (line and column).
        #[source]
        source: serde_json::Error,
    },
    /// The file's `format` tag is not the expected one.
    #[error("{path}: field \"format\": expected \"{expected}\", got {found} (an older robocal or a different file; re-run the command that wrote it)")]
    Format {
        /// The file.
        path: String,
        /// The tag expected.
        expected: &'static str,
        /// The tag found (or `none`).
        found: String,
    },
    /// The tag is right but a field is missing or of the wrong type.
    #[error("{path}: {source} (a `{expected}` file)")]
    Shape {
        /// The file.
        path: String,
        /// The format expected.
        expected: &'static str,
        /// The deserialiser's error, naming the field.
        #[source]
        source: serde_json::Error,
    },
}

/// A file type of this module: its format tag.
pub trait SchemaFile: Serialize + DeserializeOwned {
    /// The `format` tag the file carries.
    const FORMAT: &'static str;
}

/// Parse `text` as a `T` (tag checked first); `path` names the file in errors.
pub fn parse<T: SchemaFile>(text: &str, path: &str) -> Result<T, SchemaError> {
    let v: serde_json::Value =
        serde_json::from_str(text).map_err(|e| match kind::other_kind(text, T::FORMAT) {
            Some(what) => SchemaError::OtherKind {
                path: path.into(),
                what,
                source: e,
            },
            None => SchemaError::Json {
                path: path.into(),
                source: e,
            },
        })?;
    match v.get("format").and_then(|f| f.as_str()) {
        Some(f) if f == T::FORMAT => {}
        other => {
            return Err(SchemaError::Format {
                path: path.into(),
                expected: T::FORMAT,
                found: other.map_or_else(|| "no format tag".into(), |s| format!("\"{s}\"")),
            })
        }
    }
    serde_json::from_value(v).map_err(|e| SchemaError::Shape {
        path: path.into(),
        expected: T::FORMAT,
        source: e,
    })
}

/// Read a `T` from `path` (see [`parse`]).
pub fn read<T: SchemaFile>(path: &Path) -> Result<T, SchemaError> {
    let text = crate::fsio::read_to_string(path).map_err(|e| SchemaError::Io {
        path: path.display().to_string(),
        source: e,
    })?;
    parse(&text, &path.display().to_string())
}

/// Write `v` to `path` as pretty JSON with a trailing newline (atomically: temp file +
/// rename, so a reader never sees half a file).
pub fn write<T: SchemaFile>(path: &Path, v: &T) -> Result<(), SchemaError> {
    let io = |e| SchemaError::Io {
        path: path.display().to_string(),
        source: e,
    };
    let text = serde_json::to_string_pretty(v).map_err(|e| SchemaError::Json {
        path: path.display().to_string(),
        source: e,
    })? + "\n";
    // The one atomic-write helper (temp + fsync + rename + directory fsync).
    crate::fsio::write_atomic(path, text.as_bytes()).map_err(io)
}

/// A finite number or `None` (NaN / ∞ are written as `null`, never as a number).
pub fn fin(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

impl SchemaFile for CalibrationFile {
    const FORMAT: &'static str = CALIBRATION_FORMAT;
}

impl SchemaFile for PlanFile {
    const FORMAT: &'static str = PLAN_FORMAT;
}

/// Equal JSON values, numbers compared as `f64` (an integer and a float of the same value are
/// equal, so are `0` and `-0`). The round-trip check of every file robocal writes: serde_json
/// is built with `float_roundtrip`, so a value written and read back must be bit-exact; no
/// tolerance.
pub fn same_json(a: &serde_json::Value, b: &serde_json::Value) -> bool {
    use serde_json::Value;
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => match (x.as_f64(), y.as_f64()) {
            (Some(x), Some(y)) => x == y,
            _ => x == y,
        },
        (Value::Array(x), Value::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(p, q)| same_json(p, q))
        }
        (Value::Object(x), Value::Object(y)) => {
            x.len() == y.len()
                && x.iter()
                    .all(|(k, v)| y.get(k).is_some_and(|w| same_json(v, w)))
        }
        _ => a == b,
    }
}

// ------------------------------------------------------------------ diagnosis.json

/// Which sensor / problem a diagnosis is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DiagnosisSensor {
    /// Tracked marker on the arm: 3-D point error (mm).
    Kinematic,
    /// Laser range sensor on the flange: point-to-plane distance (mm).
    Laser,
    /// Camera: reprojection / point error.
    Camera,
}

/// RMS of one data set at the stages of a diagnosis. The unit is in the field name: `_mm`
/// for kinematic and laser diagnoses (3-D point / point-to-plane error), `_px` for camera
/// diagnoses (corner reprojection error). A file fills the fields of its sensor's unit; the
/// `_px` fields are absent from kinematic / laser files (files written before they existed
/// load unchanged).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct StageRms {
    /// Before any identification (nominal model with only the registration fitted).
    pub nominal_mm: Option<f64>,
    /// After the base model fit (geometry / plain beam), before effects.
    pub base_model_mm: Option<f64>,
    /// With every accepted effect.
    pub final_mm: Option<f64>,
    /// Camera: the nominal stage (not defined for a camera: always absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nominal_px: Option<f64>,
    /// Camera: after the maximum-likelihood camera + hand-eye fit, before effects (px).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub base_model_px: Option<f64>,
    /// Camera: with every accepted effect (px).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub final_px: Option<f64>,
}

impl StageRms {
    /// `(unit, nominal, base model, final)` in the unit the file uses (`px` when any `_px`
    /// field is set, else `mm`).
    pub fn with_unit(&self) -> (&'static str, Option<f64>, Option<f64>, Option<f64>) {
        if self.nominal_px.is_some() || self.base_model_px.is_some() || self.final_px.is_some() {
            ("px", self.nominal_px, self.base_model_px, self.final_px)
        } else {
            ("mm", self.nominal_mm, self.base_model_mm, self.final_mm)
        }
    }
}

/// One parameter of a diagnosed effect, in file units with its 95 % interval.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EffectParameter {
    /// Parameter name (e.g. `half_lost_motion`, `tau`, `dx`).
    pub name: String,
    /// Unit of `value`, `std` and `ci95` (`deg`, `mm`, `s`, `ppm`, `deg/K`, ...).
    pub unit: String,
    /// Value (file units, see `unit`).
    pub value: f64,
    /// Standard deviation (from the final joint fit), when computable.
    pub std: Option<f64>,
    /// 95 % interval `[value − 1.96 std, value + 1.96 std]`, when `std` is known.
    pub ci95: Option<[f64; 2]>,
}

impl EffectParameter {
    /// A parameter with its interval from `std` (non-finite std → no interval).
    pub fn new(name: &str, unit: &str, value: f64, std: f64) -> Self {
        let std = fin(std);
        EffectParameter {
            name: name.into(),
            unit: unit.into(),
            value,
            std,
            ci95: std.map(|s| [value - 1.96 * s, value + 1.96 * s]),
        }
    }
}

/// Statistical evidence for one candidate effect in one selection round.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Evidence {
    /// Candidate label, e.g. `backlash(j2)`.
    pub candidate: String,
    /// Effect kind.
    pub kind: String,
    /// Joint (1-based) of the candidate, where it has one.
    pub joint: Option<usize>,
    /// Degrees of freedom of the candidate block.
    pub df: Option<usize>,
    /// Nested-model F statistic.
    pub f: Option<f64>,
    /// p-value of the F test (before the Bonferroni correction).
    pub p_value: Option<f64>,
    /// Number of tests the p-value was corrected for (Bonferroni).
    pub tests: Option<usize>,
    /// ΔBIC in favour of the effect (positive favours it).
    pub delta_bic: Option<f64>,
    /// Relative gain of the time-blocked cross-validated RMS.
    pub cv_gain: Option<f64>,
    /// Independence from the current model's Jacobian (0..1).
    pub independence: Option<f64>,
    /// Fraction of the kernel benchmark's explained variance this candidate explains.
    pub np_ratio: Option<f64>,
}

/// One accepted effect.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DiagnosedEffect {
    /// Effect kind (the contract's names: `backlash`, `thermal_drift`, `laser_scale`, ...).
    pub kind: String,
    /// Joint (1-based) where the effect has one.
    pub joint: Option<usize>,
    /// Human label, e.g. `thermal_drift(j2, warm-up, time)`.
    pub label: String,
    /// Parameters in file units with intervals.
    pub parameters: Vec<EffectParameter>,
    /// The evidence it was accepted on.
    pub evidence: Evidence,
    /// Train / held-out RMS before and after adding the effect, kinematic / laser (mm).
    pub train_rms_mm_before: Option<f64>,
    /// Training RMS after adding the effect (mm).
    pub train_rms_mm_after: Option<f64>,
    /// Held-out RMS before adding the effect (mm).
    pub heldout_rms_mm_before: Option<f64>,
    /// Held-out RMS after adding the effect (mm).
    pub heldout_rms_mm_after: Option<f64>,
    /// The same for a camera diagnosis (corner reprojection, px); absent otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub train_rms_px_before: Option<f64>,
    /// Camera: training reprojection RMS after adding the effect (px).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub train_rms_px_after: Option<f64>,
    /// Camera: held-out reprojection RMS before adding the effect (px).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub heldout_rms_px_before: Option<f64>,
    /// Camera: held-out reprojection RMS after adding the effect (px).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub heldout_rms_px_after: Option<f64>,
    /// Camera: how far adding the effect moved the hand-eye (mm, deg); absent otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hand_eye_change_mm: Option<f64>,
    /// Camera: how far adding the effect turned the hand-eye (deg).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hand_eye_change_deg: Option<f64>,
    /// The effect as written into `calibration.json` (what `robocal predict` applies).
    pub calibration: CalEffect,
}

impl DiagnosedEffect {
    /// `(unit, train before, train after, held-out before, held-out after)` in the unit the
    /// effect's RMS figures use (`px` for camera effects, else `mm`).
    pub fn rms_with_unit(
        &self,
    ) -> (
        &'static str,
        Option<f64>,
        Option<f64>,
        Option<f64>,
        Option<f64>,
    ) {
        if self.train_rms_px_before.is_some()
            || self.train_rms_px_after.is_some()
            || self.heldout_rms_px_before.is_some()
            || self.heldout_rms_px_after.is_some()
        {
            (
                "px",
                self.train_rms_px_before,
                self.train_rms_px_after,
                self.heldout_rms_px_before,
                self.heldout_rms_px_after,
            )
        } else {
            (
                "mm",
                self.train_rms_mm_before,
                self.train_rms_mm_after,
                self.heldout_rms_mm_before,
                self.heldout_rms_mm_after,
            )
        }
    }
}

/// A pose in file units: `xyz_mm`, `quat` `[w, x, y, z]` (camera diagnoses: the hand-eye).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PoseMmQuat {
    /// Position (mm).
    pub xyz_mm: [f64; 3],
    /// Orientation, unit quaternion `[w, x, y, z]`.
    pub quat: [f64; 4],
}

/// An effect the data could not test, and why.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Untestable {
    /// The effect (kind or candidate label).
    pub effect: String,
    /// Why the data cannot test it.
    pub reason: String,
}

/// A held-out pose whose prediction depends on a change point the training data cannot
/// place (between the last training pose before and the first after the step).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AmbiguousPose {
    /// Record id of the held-out pose.
    pub id: u64,
    /// Its time (s).
    pub t_s: f64,
    /// The effect whose change point it falls within.
    pub effect: String,
    /// Last training pose time before the step (s).
    pub after_s: f64,
    /// First training pose time after the step (s).
    pub before_s: f64,
}

/// `diagnosis.json`: one shape for every sensor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DiagnosisFile {
    /// Always [`DIAGNOSIS_FORMAT`].
    pub format: String,
    /// The sensor whose residual was diagnosed.
    pub sensor: DiagnosisSensor,
    /// What the RMS figures measure (e.g. `3-D marker point error`).
    pub residual: String,
    /// Number of training poses.
    pub n_train: usize,
    /// Number of held-out poses scored in `heldout_rms` and the effects' held-out RMS.
    pub n_heldout: usize,
    /// Held-out poses left out of every held-out RMS (change-point ambiguous, listed in
    /// `ambiguous_heldout`).
    #[serde(default)]
    pub n_heldout_excluded: usize,
    /// Training RMS at each stage of the diagnosis.
    pub train_rms: StageRms,
    /// Held-out RMS at each stage of the diagnosis.
    pub heldout_rms: StageRms,
    /// The training RMS where the held-out poses are: for every held-out pose the training
    /// poses nearest it in joint space, averaged over the held-out poses. The held-out RMS
    /// against it is the gap the fit makes where the held-out poses lie (kinematic diagnosis
    /// with held-out poses only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub train_rms_near_heldout: Option<NearHeldoutRms>,
    /// Accepted effects in the order they were added.
    pub effects: Vec<DiagnosedEffect>,
    /// Whether a data-driven (nonparametric) correction was added.
    pub nonparametric_used: bool,
    /// Candidates scored per round (round 0 = after the base fit), best first.
    pub rounds: Vec<Vec<Evidence>>,
    /// Significant but absorbed by the model (not identifiable with this data).
    pub not_identifiable: Vec<Evidence>,
    /// Effects the data could not test, with the reason.
    pub untestable: Vec<Untestable>,
    /// Held-out poses inside a change point's uncertainty window (predictions not trusted).
    #[serde(default)]
    pub ambiguous_heldout: Vec<AmbiguousPose>,
    /// Warnings of the diagnosis (missing `q_prev`, dropped torn lines, ...).
    #[serde(default)]
    pub warnings: Vec<String>,
    /// Camera: the hand-eye (camera in the flange, or in the base eye-to-hand) before and
    /// after the accepted effects: what the compensation changes. Absent for other sensors.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hand_eye_before: Option<PoseMmQuat>,
    /// Camera: the hand-eye after the accepted effects.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hand_eye_after: Option<PoseMmQuat>,
}

/// `train_rms_near_heldout` of `diagnosis.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NearHeldoutRms {
    /// Training poses averaged around every held-out pose.
    pub neighbours: usize,
    /// The geometric fit's training RMS near the held-out poses (mm).
    pub base_model_mm: Option<f64>,
    /// The final model's training RMS near the held-out poses (mm).
    pub final_mm: Option<f64>,
    /// Median distance from a held-out pose to its nearest training pose in joint space (deg).
    #[serde(default)]
    pub heldout_spacing_deg: Option<f64>,
    /// Median distance from a training pose to its nearest other training pose (deg).
    #[serde(default)]
    pub train_spacing_deg: Option<f64>,
}

impl SchemaFile for DiagnosisFile {
    const FORMAT: &'static str = DIAGNOSIS_FORMAT;
}

impl DiagnosisFile {
    /// Labels of the physical effects found (not the nonparametric correction).
    pub fn physical_effects(&self) -> Vec<&DiagnosedEffect> {
        self.effects
            .iter()
            .filter(|e| e.kind != "nonparametric")
            .collect()
    }
}

// ------------------------------------------------------------------ summary.json

/// `summary.json` of `robocal run`: the [`RunSummary`] with its format tag.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunSummaryFile {
    /// Always [`RUN_SUMMARY_FORMAT`].
    pub format: String,
    /// The run's summary (flattened into the file).
    #[serde(flatten)]
    pub summary: RunSummary,
}

impl SchemaFile for RunSummaryFile {
    const FORMAT: &'static str = RUN_SUMMARY_FORMAT;
}

impl From<RunSummary> for RunSummaryFile {
    fn from(summary: RunSummary) -> Self {
        RunSummaryFile {
            format: RUN_SUMMARY_FORMAT.into(),
            summary,
        }
    }
}

// ------------------------------------------------------------------ laser_report.json

/// One estimator's row of the laser hand-eye comparison.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LaserMethodRow {
    /// Estimator name.
    pub method: String,
    /// Beam origin in the flange frame (mm).
    pub r_mm: [f64; 3],
    /// Beam direction in the flange frame (unit vector).
    pub v: [f64; 3],
    /// Mean 5-direction spread over the validation targets (mm).
    pub spread_mean_mm: Option<f64>,
    /// Standard deviation of that spread over the targets (mm).
    pub spread_std_mm: Option<f64>,
    /// Fiducial registration error (mm), where the method has one.
    pub fre_mm: Option<f64>,
    /// Target registration error (mm), where the method has one.
    pub tre_mm: Option<f64>,
    /// Simulated cells only: spot RMS against the true spots (mm).
    pub spot_rms_vs_truth_mm: Option<f64>,
    /// Records the estimator used.
    pub n_used: usize,
    /// What the estimator assumes or why it failed.
    pub note: String,
}

/// One step of a plane's data selection.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SelectionStep {
    /// Iteration of the selection.
    pub iteration: usize,
    /// Points kept at that iteration.
    pub points: usize,
    /// The selection's score at that iteration (lower is better).
    pub score: Option<f64>,
}

/// The 5-direction spread of one validation target (mm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TargetSpread {
    /// Target label.
    pub target: String,
    /// Its 5-direction spread (mm).
    pub spread_mm: Option<f64>,
}

/// `laser_report.json`: the side-by-side comparison of the laser estimators.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LaserReportFile {
    /// Always [`LASER_REPORT_FORMAT`].
    pub format: String,
    /// One row per estimator.
    pub rows: Vec<LaserMethodRow>,
    /// Data-selection trace per plane label.
    pub selection: std::collections::BTreeMap<String, Vec<SelectionStep>>,
    /// The iteration kept per plane label.
    pub selection_best: std::collections::BTreeMap<String, usize>,
    /// The final beam's spread per validation target.
    pub final_spreads: Vec<TargetSpread>,
    /// Ids of the records the robust final fit flagged as outliers.
    pub outliers: Vec<u64>,
    /// The final fit's RMS distance of the spots to their planes (mm).
    pub final_plane_rms_mm: Option<f64>,
    /// How the final fit ended (converged, iteration limit, ...).
    pub final_termination: String,
    /// Std of the final beam: r (mm, 3) then v (unitless, 3).
    pub final_std: Option<[f64; 6]>,
}

impl SchemaFile for LaserReportFile {
    const FORMAT: &'static str = LASER_REPORT_FORMAT;
}

// ------------------------------------------------------------------ scan_report.json

/// Flatness of one scanned face.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FaceFlatness {
    /// Face label.
    pub face: String,
    /// Points on the face.
    pub points: usize,
    /// RMS distance of the points to their fitted plane (mm).
    pub rms_mm: f64,
    /// Largest distance to the plane (mm).
    pub max_mm: f64,
}

/// Angle between two scanned faces.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FaceAngle {
    /// First face.
    pub a: String,
    /// Second face.
    pub b: String,
    /// Angle between their fitted planes (deg).
    pub angle_deg: f64,
}

/// `scan_report.json`: a scan reconstructed with a laser calibration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScanReportFile {
    /// Always [`SCAN_REPORT_FORMAT`].
    pub format: String,
    /// The scan dataset.
    pub scan: String,
    /// Points reconstructed.
    pub points: usize,
    /// Flatness of each face.
    pub faces: Vec<FaceFlatness>,
    /// Angles between the faces.
    pub angles: Vec<FaceAngle>,
}

impl SchemaFile for ScanReportFile {
    const FORMAT: &'static str = SCAN_REPORT_FORMAT;
}

// ------------------------------------------------------------------ pivot.json

/// One pivot-calibration method's result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PivotResult {
    /// Method (`algebraic`, `sphere`, `robust-algebraic`, `robust-sphere`).
    pub method: String,
    /// Probe tip in the marker frame (mm).
    pub tip_in_marker_mm: [f64; 3],
    /// Pivot point in the tracker frame (mm).
    pub pivot_point_mm: [f64; 3],
    /// RMS 3-D tip residual over the frames (mm).
    pub rms_mm: f64,
    /// Largest 3-D tip residual (mm).
    pub max_mm: f64,
    /// Frames used.
    pub frames: usize,
    /// Per-axis RMS `√(Σ|e|²/3n)` (scikit-surgerycalibration's `residual_error`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rms_axis_mm: Option<f64>,
    /// 95 % bootstrap intervals `[[lo, hi]; 3]` of the tip (marker frame) and pivot point.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tip_ci95_mm: Option<[[f64; 2]; 3]>,
    /// 95 % bootstrap interval of the pivot point (tracker frame).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pivot_ci95_mm: Option<[[f64; 2]; 3]>,
}

/// The robust part of `pivot.json`: outlier handling and which estimate to trust.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PivotRobust {
    /// Frames read / dropped as outliers.
    pub frames_in: usize,
    /// Frames dropped as outliers.
    pub dropped: usize,
    /// Inlier cut on the 3-D tip residual and the robust per-axis σ (mm).
    pub threshold_mm: f64,
    /// Robust per-axis σ of the residual (mm).
    pub sigma_mm: f64,
    /// Largest tilt of the probe axis from its mean (deg).
    pub spread_deg: f64,
    /// Bootstrap replicates and block length (frames).
    pub bootstrap: usize,
    /// Block length of the moving-block bootstrap (frames).
    pub block: usize,
    /// Whether the methods' tips differ beyond their intervals; which to trust and why.
    pub disagree: bool,
    /// The estimate to trust (`algebraic` or `sphere`).
    pub trust: String,
    /// Why that one.
    pub reason: String,
}

/// `pivot.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PivotFile {
    /// Always [`PIVOT_FORMAT`].
    pub format: String,
    /// The tool calibrated, when the records name one.
    pub tool: Option<String>,
    /// Every method's result (every frame, then robust).
    pub results: Vec<PivotResult>,
    /// Outlier handling and the verdict.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub robust: Option<PivotRobust>,
}

impl SchemaFile for PivotFile {
    const FORMAT: &'static str = PIVOT_FORMAT;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn diagnosis_round_trip_and_tag_check() {
        let d = DiagnosisFile {
            format: DIAGNOSIS_FORMAT.into(),
            sensor: DiagnosisSensor::Laser,
            residual: "point-to-plane distance".into(),
            n_train: 10,
            n_heldout: 0,
            n_heldout_excluded: 0,
            train_rms: StageRms {
                nominal_mm: None,
                base_model_mm: Some(0.2),
                final_mm: Some(0.1),
                ..Default::default()
            },
            heldout_rms: StageRms::default(),
            train_rms_near_heldout: None,
            effects: vec![DiagnosedEffect {
                kind: "laser_scale".into(),
                joint: None,
                label: "laser_scale".into(),
                parameters: vec![EffectParameter::new("scale", "ppm", 120.0, 5.0)],
                evidence: Evidence::default(),
                train_rms_mm_before: Some(0.2),
                train_rms_mm_after: Some(0.1),
                heldout_rms_mm_before: None,
                heldout_rms_mm_after: None,
                train_rms_px_before: None,
                train_rms_px_after: None,
                heldout_rms_px_before: None,
                heldout_rms_px_after: None,
                hand_eye_change_mm: None,
                hand_eye_change_deg: None,
                calibration: CalEffect {
                    kind: "laser_scale".into(),
                    joint: None,
                    params: Default::default(),
                    extra: Default::default(),
                },
            }],
            nonparametric_used: false,
            rounds: vec![],
            not_identifiable: vec![],
            untestable: vec![],
            ambiguous_heldout: vec![],
            warnings: vec![],
            hand_eye_before: None,
            hand_eye_after: None,
        };
        let text = serde_json::to_string(&d).unwrap();
        let back: DiagnosisFile = parse(&text, "mem").unwrap();
        assert_eq!(back, d);
        assert_eq!(
            back.effects[0].parameters[0].ci95,
            Some([120.0 - 9.8, 120.0 + 9.8])
        );
        // Units: a kinematic / laser file has no `_px` fields (older files load unchanged).
        assert_eq!(back.train_rms.with_unit().0, "mm");
        assert_eq!(back.effects[0].rms_with_unit().0, "mm");
        assert!(
            !text.contains("_px") && !text.contains("hand_eye"),
            "{text}"
        );
        let mut cam = d.clone();
        cam.sensor = DiagnosisSensor::Camera;
        cam.train_rms = StageRms {
            base_model_px: Some(0.5),
            final_px: Some(0.05),
            ..Default::default()
        };
        cam.effects[0].train_rms_mm_before = None;
        cam.effects[0].train_rms_mm_after = None;
        cam.effects[0].train_rms_px_before = Some(0.5);
        cam.effects[0].train_rms_px_after = Some(0.05);
        cam.hand_eye_before = Some(PoseMmQuat {
            xyz_mm: [0.0, 50.0, 40.0],
            quat: [1.0, 0.0, 0.0, 0.0],
        });
        let text = serde_json::to_string(&cam).unwrap();
        let back: DiagnosisFile = parse(&text, "mem").unwrap();
        assert_eq!(back, cam);
        assert_eq!(
            back.train_rms.with_unit(),
            ("px", None, Some(0.5), Some(0.05))
        );
        assert_eq!(back.effects[0].rms_with_unit().0, "px");
        let old = r#"{"format":"robocal-diagnosis/1","chain":[]}"#;
        let e = parse::<DiagnosisFile>(old, "d.json")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("d.json") && e.contains("robocal-diagnosis/2"),
            "{e}"
        );
        let e = parse::<DiagnosisFile>(r#"{"format":"robocal-diagnosis/2"}"#, "d.json")
            .unwrap_err()
            .to_string();
        assert!(e.contains("missing field"), "{e}");
    }

    #[test]
    fn run_summary_flattened_with_tag() {
        let f = RunSummaryFile::from(RunSummary {
            planned: 3,
            ..RunSummary::default()
        });
        let text = serde_json::to_string(&f).unwrap();
        assert!(
            text.contains("\"format\":\"robocal-run-summary/1\""),
            "{text}"
        );
        assert!(text.contains("\"planned\":3"), "{text}");
        let back: RunSummaryFile = parse(&text, "s.json").unwrap();
        assert_eq!(back, f);
    }
}
