//! The acquisition engine: drives the cell through a plan and writes a
//! `robocal-dataset/1` journal.
//!
//! Per planned pose: move under the safety wrappers at the capped speed; wait until the
//! arm and the tracked marker have **settled** (joint velocity and marker position stable
//! within a tolerance over a window, not a fixed sleep); average N tracker frames with
//! outlier rejection (keeping the tracker's fit RMS); read the laser (averaged) where one
//! is configured; record measured and commanded joints, the controller's flange pose,
//! time and temperature; append the record and fsync **before** the next motion starts.
//!
//! Faults are recorded as `event` records: marker not visible → retry k times then skip;
//! laser out of range → `range: null` + event; link drop (`Disconnected` / `Timeout`) →
//! back off and retry (drivers reconnect on their next call), then re-verify the position;
//! protective stop → pause, try to recover, resume; unreachable / refused motion → skip.
//!
//! Camera (when [`Devices::camera`] is set): one image per pose, grabbed after the settle
//! with the other sensors, saved as lossless binary PGM to `<dataset-stem>.images/pose-<id>.pgm`
//! next to the journal (temp file, fsync, rename, directory fsync) **before** the pose record
//! that names it is appended; with feature `opencv` and [`CaptureOptions::board`] set, the
//! chessboard's inner corners are detected into the record's `corners`. A camera link drop is
//! retried like the laser's; any other camera error records the pose without an image plus a
//! `fault` event.
//!
//! Resuming: the poses already recorded (and those skipped for good) are read back from
//! the journal, and the run continues with the remaining poses of the plan.
//!
//! The engine is generic over the device traits of `robocal_drivers` (`Arc<dyn …>`); it
//! never depends on the simulators. Units inside: rad, mm, s; the journal uses deg, mm, s.

pub mod device_check;
pub mod device_safety;
pub mod devices;
pub mod engine;
pub mod probe;
pub mod sample;
pub mod settle;
pub mod summary;
pub mod transfer;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use robocal_drivers::safety::{ArmGeometry, SafetyLimits};
use robocal_drivers::{Arm, Clock, ImageSource, MarkerTracker, MoveSpeed, RangeSensor};
use serde::{Deserialize, Serialize};

pub use engine::{acquire, done_pose_ids, image_file_name, images_dir, AcquireError, Progress};
pub use summary::{RunSummary, SkippedPose, TimeBreakdown};

/// The devices of one run. The arm must already be wrapped in the safety decorators
/// (`robocal_drivers::safety::guard`).
#[derive(Clone)]
pub struct Devices {
    /// The (guarded) arm.
    pub arm: Arc<dyn Arm>,
    /// The optical tracker, if the plan measures a marker.
    pub tracker: Option<Arc<dyn MarkerTracker>>,
    /// The laser range sensor, if the plan reads one.
    pub range: Option<Arc<dyn RangeSensor>>,
    /// Time as the devices see it (wall clock, or the world's virtual clock).
    pub clock: Arc<dyn Clock>,
    /// The camera, if the plan records images (one image per pose; see
    /// [`AcquireOptions::capture`] for what is done with it).
    pub camera: Option<Arc<dyn ImageSource>>,
}

impl std::fmt::Debug for Devices {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Devices")
            .field("tracker", &self.tracker.is_some())
            .field("range", &self.range.is_some())
            .field("camera", &self.camera.is_some())
            .finish()
    }
}

/// One planned pose as the engine consumes it (from a `robocal-plan/1` file).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlannedPose {
    /// Record id (acquisition order, increasing).
    pub id: u64,
    /// Joint target (deg, as in files).
    pub q_deg: Vec<f64>,
    /// Planned target number.
    pub point: Option<u64>,
    /// IK branch.
    pub branch: Option<u64>,
    /// `train`, `validation`, ...
    pub group: Option<String>,
    /// Calibration plane (`P1`...).
    pub plane: Option<String>,
    /// `translate` / `rotate`.
    pub move_kind: Option<String>,
    /// Validation target label.
    pub target: Option<String>,
    /// Seed block number (kept as an extra field of the record).
    pub block: Option<u64>,
    /// Human label of the target (kept as an extra field of the record).
    pub label: Option<String>,
}

impl PlannedPose {
    /// A pose with only an id and a joint target.
    pub fn new(id: u64, q_deg: Vec<f64>) -> PlannedPose {
        PlannedPose {
            id,
            q_deg,
            point: None,
            branch: None,
            group: None,
            plane: None,
            move_kind: None,
            target: None,
            block: None,
            label: None,
        }
    }
}

impl From<&crate::plan::file::PlanPose> for PlannedPose {
    fn from(p: &crate::plan::file::PlanPose) -> Self {
        PlannedPose {
            id: p.id,
            q_deg: p.q_deg.clone(),
            point: Some(p.point),
            branch: Some(u64::from(p.branch)),
            group: Some(p.group.clone()),
            plane: p.plane.clone(),
            move_kind: p.move_kind.clone(),
            target: p.target.clone(),
            block: p.block,
            label: Some(p.label.clone()).filter(|l| !l.is_empty()),
        }
    }
}

/// Settling detection: the arm and marker are settled when, over the last `window`
/// polls, every joint moved less than `q_tol_rad`, the reported joint speeds stay below
/// `qd_tol_rad_s`, and the marker position moved less than `pos_tol_mm`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SettleOptions {
    /// Time between polls (s).
    pub poll_s: f64,
    /// Number of consecutive polls that must agree.
    pub window: usize,
    /// Joint position band (rad).
    pub q_tol_rad: f64,
    /// Joint speed bound (rad/s).
    pub qd_tol_rad_s: f64,
    /// Marker position band (mm).
    pub pos_tol_mm: f64,
    /// Give up waiting after this long (s): the pose is measured anyway and a `note`
    /// event says it did not settle.
    pub timeout_s: f64,
}

impl Default for SettleOptions {
    fn default() -> Self {
        SettleOptions {
            poll_s: 0.02,
            window: 6,
            q_tol_rad: 2e-5,
            qd_tol_rad_s: 1e-3,
            pos_tol_mm: 0.05,
            timeout_s: 5.0,
        }
    }
}

/// Tracker and laser sampling.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SampleOptions {
    /// Tracker frames averaged per pose.
    pub frames: usize,
    /// Minimum visible frames for a valid measurement.
    pub min_frames: usize,
    /// Outlier threshold in robust standard deviations.
    pub outlier_k: f64,
    /// Outlier threshold floor (mm): samples closer than this to the median are kept.
    pub outlier_floor_mm: f64,
    /// The tracked tool (`None`: the first tool of each frame).
    pub tool: Option<String>,
    /// Laser readings averaged per pose.
    pub laser_readings: usize,
}

impl Default for SampleOptions {
    fn default() -> Self {
        SampleOptions {
            frames: 30,
            min_frames: 10,
            outlier_k: 4.0,
            outlier_floor_mm: 0.1,
            tool: None,
            laser_readings: 5,
        }
    }
}

/// Fault handling.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FaultOptions {
    /// Marker not visible: retries before the pose is skipped.
    pub marker_retries: u32,
    /// Wait before a marker retry (s).
    pub marker_retry_wait_s: f64,
    /// Link drop: attempts (with exponential backoff) before the run aborts.
    pub link_attempts: u32,
    /// First backoff (s); doubles each attempt up to `backoff_max_s`.
    pub backoff_initial_s: f64,
    /// Largest backoff (s).
    pub backoff_max_s: f64,
    /// Protective stop: recovery attempts before the run aborts.
    pub stop_recoveries: u32,
    /// Wait between recovery attempts (s).
    pub stop_wait_s: f64,
    /// After a link drop the arm must be within this of the target (rad), else it moves again.
    pub position_tol_rad: f64,
}

impl Default for FaultOptions {
    fn default() -> Self {
        FaultOptions {
            marker_retries: 3,
            marker_retry_wait_s: 0.5,
            link_attempts: 6,
            backoff_initial_s: 0.5,
            backoff_max_s: 8.0,
            stop_recoveries: 5,
            stop_wait_s: 2.0,
            position_tol_rad: 1e-3,
        }
    }
}

/// What the engine does with the camera's image at each pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CaptureOptions {
    /// Inner corners `(cols, rows)` of the chessboard to detect in each image (feature
    /// `opencv`; without it only the images are saved). `None`: no detection.
    pub board: Option<(u32, u32)>,
}

/// Everything the engine needs besides devices, plan and journal.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct AcquireOptions {
    /// Speed caps of every move (the safety wrapper clamps them further).
    pub speed: MoveSpeedOpt,
    /// Settling detection.
    pub settle: SettleOptions,
    /// Sampling.
    pub sample: SampleOptions,
    /// Fault handling.
    pub faults: FaultOptions,
    /// Stop after this many poses of this invocation (`None`: run to the end).
    pub max_poses: Option<usize>,
    /// Camera images and chessboard detection.
    pub capture: CaptureOptions,
    /// The run's safety limits and arm geometry — the same the arm's safety wrappers check —
    /// for planning safe transfers (see [`engine`]). `None`: every move goes straight to its
    /// target (the wrappers still refuse unsafe paths).
    pub transfer: Option<TransferSafety>,
    /// Set it (Ctrl-C) to stop after the current pose's record is durable.
    pub stop: StopFlag,
}

/// The safety limits and arm geometry transfers are planned against (pure checks with
/// [`robocal_drivers::safety::check_move`], the function the safety wrappers call).
#[derive(Clone)]
pub struct TransferSafety {
    /// Joint limits, envelope, table.
    pub limits: Arc<SafetyLimits>,
    /// Points on the arm to check, when the limits have an envelope or a table.
    pub geometry: Option<Arc<dyn ArmGeometry>>,
}

impl std::fmt::Debug for TransferSafety {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TransferSafety")
            .field("limits", &self.limits)
            .field("geometry", &self.geometry.is_some())
            .finish()
    }
}

impl PartialEq for TransferSafety {
    fn eq(&self, other: &Self) -> bool {
        self.limits == other.limits
            && match (&self.geometry, &other.geometry) {
                (None, None) => true,
                (Some(a), Some(b)) => Arc::ptr_eq(a, b),
                _ => false,
            }
    }
}

/// A request to stop a run between poses (set from a Ctrl-C handler).
#[derive(Debug, Clone, Default)]
pub struct StopFlag(Arc<AtomicBool>);

impl StopFlag {
    /// Asks the run to stop after the current pose.
    pub fn request(&self) {
        self.0.store(true, Ordering::SeqCst);
    }
    /// Whether a stop was requested.
    pub fn requested(&self) -> bool {
        self.0.load(Ordering::SeqCst)
    }
}

impl PartialEq for StopFlag {
    fn eq(&self, other: &Self) -> bool {
        Arc::ptr_eq(&self.0, &other.0)
    }
}

/// Serializable move speed (rad/s, rad/s²).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MoveSpeedOpt {
    /// Maximum joint speed (rad/s).
    pub max_vel: f64,
    /// Maximum joint acceleration (rad/s²).
    pub max_acc: f64,
}

impl Default for MoveSpeedOpt {
    fn default() -> Self {
        let s = MoveSpeed::default();
        MoveSpeedOpt {
            max_vel: s.max_vel,
            max_acc: s.max_acc,
        }
    }
}

impl From<MoveSpeedOpt> for MoveSpeed {
    fn from(s: MoveSpeedOpt) -> Self {
        MoveSpeed {
            max_vel: s.max_vel,
            max_acc: s.max_acc,
        }
    }
}

/// Current UTC time as `YYYY-MM-DDTHH:MM:SSZ` (for a header's `created`).
pub fn utc_now_iso() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs() as i64)
        .unwrap_or(0);
    let days = secs.div_euclid(86_400);
    let sod = secs.rem_euclid(86_400);
    // Civil from days (H. Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let y = yoe + era * 400;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = if m <= 2 { y + 1 } else { y };
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        sod / 3600,
        (sod % 3600) / 60,
        sod % 60
    )
}
