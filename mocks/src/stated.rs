//! The truth-free face of a simulated cell, for code on the estimating side.
//!
//! A scenario file holds two kinds of facts: what a real cell's device file would state (which
//! arm and tracker, how they are reached, where the tracker stands, its volume, the cell's
//! safety limits, the camera and its board) and what only the simulated world knows (the true
//! geometric errors, hidden effects, noise). Estimators must never see the second kind, so the
//! root crate reaches the simulators only through this module:
//!
//! - [`StatedScenario`]: the stated facts of a scenario, copied into plain types that have no
//!   field for any error, effect or noise;
//! - [`SimCell`]: a running simulated world whose devices are handed out only as the driver
//!   traits (in process, or served over the real wire protocols: [`SimCell::serve`]).
//!
//! Nothing here returns a [`WorldHandle`], a true pose or a hidden parameter.
use std::path::Path;
use std::sync::Arc;

use robocal_drivers::safety::Envelope;
use robocal_drivers::{Arm, Clock, ImageSource, MarkerTracker, RangeSensor};

pub use crate::scenario::Protocol;
pub use crate::scenario::ScenarioError;
use crate::scenario::{ClockMode, Scenario, TrackerKind, VolumeKind};
pub use crate::serve::{Bind, Endpoint, ServeError, Served};
use crate::sim::{SimArm, SimCamera, SimRange, SimTracker};
use crate::world::WorldHandle;

/// A rigid placement as stated: translation (mm), URDF roll-pitch-yaw (deg).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StatedPose {
    /// Translation (mm).
    pub xyz_mm: [f64; 3],
    /// URDF roll-pitch-yaw (deg).
    pub rpy_deg: [f64; 3],
}

impl From<&crate::scenario::Placement> for StatedPose {
    fn from(p: &crate::scenario::Placement) -> Self {
        Self {
            xyz_mm: p.xyz_mm,
            rpy_deg: p.rpy_deg,
        }
    }
}

/// The cell's own safety limits around an arm (robot base frame, mm).
#[derive(Debug, Clone, PartialEq)]
pub struct StatedSafety {
    /// Table plane height (mm).
    pub table_z_mm: Option<f64>,
    /// Least clearance above the table (mm).
    pub table_clearance_mm: Option<f64>,
    /// Cartesian envelope every arm check point stays in.
    pub envelope: Option<Envelope>,
}

/// One arm as stated.
#[derive(Debug, Clone, PartialEq)]
pub struct StatedArm {
    /// Device name.
    pub name: String,
    /// Robot model preset.
    pub model: String,
    /// Serial number.
    pub serial: String,
    /// Wire protocol of its controller.
    pub protocol: Protocol,
    /// Controller speed cap (deg/s).
    pub max_vel_deg_s: f64,
    /// Controller acceleration cap (deg/s²).
    pub max_acc_deg_s2: f64,
    /// Settling time after a move (s).
    pub settle_s: f64,
    /// Home posture (deg).
    pub home_deg: Option<Vec<f64>>,
    /// The cell's safety limits around it.
    pub safety: Option<StatedSafety>,
}

/// A tracker's measurement volume along its −z axis: near and far depth (mm), half-angle
/// tangents across x and y.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StatedVolume {
    /// Nearest depth (mm).
    pub near_mm: f64,
    /// Farthest depth (mm).
    pub far_mm: f64,
    /// tan of the half-angle across x.
    pub tan_x: f64,
    /// tan of the half-angle across y.
    pub tan_y: f64,
}

fn frustum(v: VolumeKind) -> Option<StatedVolume> {
    crate::world::sensors::volume_frustum(v).map(|(near_mm, far_mm, tan_x, tan_y)| StatedVolume {
        near_mm,
        far_mm,
        tan_x,
        tan_y,
    })
}

/// A sphere known to block the tracker's line of sight (base frame, mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StatedOccluder {
    /// Centre (mm).
    pub center_mm: [f64; 3],
    /// Radius (mm).
    pub radius_mm: f64,
}

/// One tracker as stated.
#[derive(Debug, Clone, PartialEq)]
pub struct StatedTracker {
    /// Device name.
    pub name: String,
    /// Model name (`ndi-polaris-vega`, ...), as dataset headers write it.
    pub kind: String,
    /// Wire protocol.
    pub protocol: Protocol,
    /// The arm carrying its marker.
    pub arm: String,
    /// Tool name loaded into it.
    pub tool: String,
    /// Frame rate (Hz).
    pub rate_hz: f64,
    /// Where it stands in the robot base frame.
    pub tracker_in_base: StatedPose,
    /// The marker on the flange.
    pub marker_on_flange: StatedPose,
    /// Its measurement volume (`None`: unbounded).
    pub volume: Option<StatedVolume>,
    /// Largest marker view angle (deg).
    pub max_view_angle_deg: Option<f64>,
    /// Known line-of-sight blockers.
    pub occluders: Vec<StatedOccluder>,
}

/// One laser range sensor as stated.
#[derive(Debug, Clone, PartialEq)]
pub struct StatedLaser {
    /// Device name.
    pub name: String,
    /// Model (`keyence-il600`).
    pub kind: String,
    /// Wire protocol.
    pub protocol: Protocol,
    /// The arm carrying it.
    pub arm: String,
}

/// One camera as stated.
#[derive(Debug, Clone, PartialEq)]
pub struct StatedCamera {
    /// Device name.
    pub name: String,
    /// Image width (px).
    pub width: u32,
    /// Image height (px).
    pub height: u32,
    /// The arm carrying it (eye-in-hand); `None`: fixed in the base frame.
    pub arm: Option<String>,
    /// Its own prior intrinsics (px): fx, fy, cx, cy (what an endoscope's data sheet or
    /// earlier calibration states).
    pub intrinsics: [f64; 4],
    /// Its radial distortion k1, k2 (the same prior).
    pub radial: [f64; 2],
}

/// A surgical instrument's shaft as stated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StatedInstrument {
    /// Shaft radius (mm).
    pub radius_mm: f64,
}

/// The calibration board as stated (a printed target: its layout and where it lies).
#[derive(Debug, Clone, PartialEq)]
pub struct StatedBoard {
    /// Squares across.
    pub cols: u32,
    /// Squares down.
    pub rows: u32,
    /// Square side (mm).
    pub square_mm: f64,
    /// ChArUco marker side (mm) and dictionary, for a ChArUco board.
    pub charuco: Option<(f64, String)>,
    /// The board's centre in the robot base frame (mm).
    pub center_mm: [f64; 3],
}

/// What a scenario states about its cell, as a device file would: no error, effect or noise.
#[derive(Debug, Clone, PartialEq)]
pub struct StatedScenario {
    /// Scenario name.
    pub name: String,
    /// Arms.
    pub arms: Vec<StatedArm>,
    /// Trackers.
    pub trackers: Vec<StatedTracker>,
    /// Laser range sensors.
    pub lasers: Vec<StatedLaser>,
    /// Cameras.
    pub cameras: Vec<StatedCamera>,
    /// The calibration board, if the scene has one.
    pub board: Option<StatedBoard>,
    /// The instrument of an RCM cell, if the scene has one.
    pub instrument: Option<StatedInstrument>,
}

impl StatedScenario {
    /// Reads the scenario file at `path` (strict TOML) and keeps its stated facts.
    pub fn load(path: &Path) -> Result<Self, ScenarioError> {
        Ok(Self::of(&Scenario::load(path)?))
    }

    fn of(s: &Scenario) -> Self {
        let board = s.scene.chessboard.as_ref().map(|b| {
            let centre = b.placement.isometry()
                * nalgebra::Point3::new(
                    b.cols as f64 * b.square_mm / 2.0,
                    b.rows as f64 * b.square_mm / 2.0,
                    0.0,
                );
            StatedBoard {
                cols: b.cols,
                rows: b.rows,
                square_mm: b.square_mm,
                charuco: b
                    .charuco
                    .as_ref()
                    .map(|c| (c.marker_mm, c.dictionary.clone())),
                center_mm: [centre.x, centre.y, centre.z],
            }
        });
        Self {
            name: s.name.clone(),
            arms: s
                .arms
                .iter()
                .map(|a| StatedArm {
                    name: a.name.clone(),
                    model: a.model.clone(),
                    serial: a.serial.clone(),
                    protocol: a.protocol,
                    max_vel_deg_s: a.motion.max_vel_deg_s,
                    max_acc_deg_s2: a.motion.max_acc_deg_s2,
                    settle_s: a.motion.settle_s,
                    home_deg: a.home_deg.clone(),
                    safety: a.safety.as_ref().map(|s| StatedSafety {
                        table_z_mm: s.table_z_mm,
                        table_clearance_mm: s.table_clearance_mm,
                        envelope: s.envelope.clone(),
                    }),
                })
                .collect(),
            trackers: s
                .trackers
                .iter()
                .map(|t| StatedTracker {
                    name: t.name.clone(),
                    kind: t.kind.as_str().to_string(),
                    protocol: t.protocol,
                    arm: t.arm.clone(),
                    tool: t.tool.clone(),
                    rate_hz: t.rate_hz,
                    tracker_in_base: (&t.tracker_in_base).into(),
                    marker_on_flange: (&t.marker_on_flange).into(),
                    volume: frustum(t.effects.volume.unwrap_or(match t.kind {
                        TrackerKind::NdiOptotrakCertus => VolumeKind::Optotrak,
                        _ => VolumeKind::PolarisPyramid,
                    })),
                    max_view_angle_deg: t.effects.max_view_angle_deg,
                    occluders: t
                        .effects
                        .occluders
                        .iter()
                        .map(|o| StatedOccluder {
                            center_mm: o.center_mm,
                            radius_mm: o.radius_mm,
                        })
                        .collect(),
                })
                .collect(),
            lasers: s
                .lasers
                .iter()
                .map(|l| StatedLaser {
                    name: l.name.clone(),
                    kind: l.kind.clone(),
                    protocol: l.protocol,
                    arm: l.arm.clone(),
                })
                .collect(),
            cameras: s
                .cameras
                .iter()
                .map(|c| StatedCamera {
                    name: c.name.clone(),
                    width: c.width,
                    height: c.height,
                    arm: c.arm.clone(),
                    intrinsics: [c.fx, c.fy, c.cx, c.cy],
                    radial: [c.k1, c.k2],
                })
                .collect(),
            board,
            instrument: s.scene.instrument.as_ref().map(|i| StatedInstrument {
                radius_mm: i.radius_mm,
            }),
        }
    }

    /// The arm named `arm` (default: the first).
    pub fn arm(&self, arm: Option<&str>) -> Option<&StatedArm> {
        match arm {
            Some(n) => self.arms.iter().find(|a| a.name == n),
            None => self.arms.first(),
        }
    }

    /// The cell of one arm: that arm, the trackers and lasers on it, the cameras on it or fixed.
    pub fn one_arm(&self, arm: &str) -> Self {
        let mut one = self.clone();
        one.arms.retain(|a| a.name == arm);
        one.trackers.retain(|t| t.arm == arm);
        one.lasers.retain(|l| l.arm == arm);
        one.cameras
            .retain(|c| c.arm.as_deref().is_none_or(|n| n == arm));
        one
    }
}

/// Which devices of an arm's cell a session keeps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Only {
    /// Every device on the arm (and the fixed cameras).
    All,
    /// The laser range sensors (trackers and cameras removed).
    Ranges,
    /// The cameras (trackers and lasers removed).
    Images,
}

/// The scenario file at `path` cut to one arm (as [`StatedScenario::one_arm`] cuts its stated
/// facts) and to the devices `only` keeps, as TOML text: the file a single-arm session runs on.
pub fn one_arm_scenario_toml(path: &Path, arm: &str, only: Only) -> Result<String, ScenarioError> {
    let mut one = Scenario::load(path)?;
    one.arms.retain(|a| a.name == arm);
    one.trackers.retain(|t| t.arm == arm);
    one.lasers.retain(|l| l.arm == arm);
    one.cameras
        .retain(|c| c.arm.as_deref().is_none_or(|n| n == arm));
    match only {
        Only::All => {}
        Only::Ranges => {
            one.trackers.clear();
            one.cameras.clear();
        }
        Only::Images => {
            one.trackers.clear();
            one.lasers.clear();
        }
    }
    toml::to_string(&one).map_err(|e| ScenarioError::Invalid(e.to_string()))
}

/// The first arm, tracker, laser and camera of a simulated cell as driver trait objects.
pub struct SimDeviceSet {
    /// The first arm.
    pub arm: Arc<dyn Arm>,
    /// The first tracker.
    pub tracker: Option<Arc<dyn MarkerTracker>>,
    /// The first laser range sensor.
    pub range: Option<Arc<dyn RangeSensor>>,
    /// The first camera.
    pub camera: Option<Arc<dyn ImageSource>>,
}

/// A running simulated cell, seen only through its devices.
#[derive(Clone)]
pub struct SimCell {
    world: WorldHandle,
    stated: StatedScenario,
}

impl std::fmt::Debug for SimCell {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimCell")
            .field("scenario", &self.stated.name)
            .finish_non_exhaustive()
    }
}

impl SimCell {
    /// Builds the world of the scenario file at `path`, on a virtual or the wall clock.
    pub fn open(path: &Path, virtual_clock: bool) -> Result<Self, ScenarioError> {
        let mut s = Scenario::load(path)?;
        s.clock = if virtual_clock {
            ClockMode::Virtual
        } else {
            ClockMode::Real
        };
        Ok(Self::of(&WorldHandle::from_scenario(&s)?))
    }

    /// The cell of a world built elsewhere (a test that injects faults keeps the world).
    pub fn of(world: &WorldHandle) -> Self {
        Self {
            world: world.clone(),
            stated: StatedScenario::of(&world.scenario()),
        }
    }

    /// What the scenario states.
    pub fn stated(&self) -> &StatedScenario {
        &self.stated
    }

    /// The cell's clock (virtual or wall).
    pub fn clock(&self) -> Arc<dyn Clock> {
        self.world.clock()
    }

    /// Whether the cell runs on a virtual clock (time jumps at every wait).
    pub fn is_virtual(&self) -> bool {
        self.world.is_virtual()
    }

    /// The serial number the first arm's controller reports.
    pub fn arm_serial(&self) -> Option<String> {
        self.world.arm_identity(0).map(|(_, s)| s)
    }

    /// The first arm's joint count.
    pub fn arm_dof(&self) -> usize {
        self.world.arm_dof(0)
    }

    /// The first arm, tracker, laser and camera, in process (no wire).
    pub fn in_process(&self) -> Option<SimDeviceSet> {
        let s = &self.stated;
        let arm = s.arms.first()?;
        Some(SimDeviceSet {
            arm: self.arm_in_process(&arm.name),
            tracker: s.trackers.first().map(|t| self.tracker_in_process(&t.name)),
            range: s.lasers.first().map(|l| self.range_in_process(&l.name)),
            camera: s.cameras.first().map(|c| self.camera_in_process(&c.name)),
        })
    }

    /// The first arm, in process (named `name`).
    pub fn arm_in_process(&self, name: &str) -> Arc<dyn Arm> {
        Arc::new(SimArm::new(self.world.clone(), 0, name))
    }

    /// The first tracker, in process (named `name`).
    pub fn tracker_in_process(&self, name: &str) -> Arc<dyn MarkerTracker> {
        Arc::new(SimTracker::new(self.world.clone(), 0, name))
    }

    /// The first laser, in process (named `name`).
    pub fn range_in_process(&self, name: &str) -> Arc<dyn RangeSensor> {
        Arc::new(SimRange::new(self.world.clone(), 0, name))
    }

    /// The first camera, in process (named `name`).
    pub fn camera_in_process(&self, name: &str) -> Arc<dyn ImageSource> {
        Arc::new(SimCamera::new(self.world.clone(), 0, name))
    }

    /// Serves every device over its real wire protocol (see [`crate::serve::serve_all`]).
    pub async fn serve(&self, bind: &Bind) -> Result<Served, ServeError> {
        crate::serve::serve_all(&self.world, bind).await
    }
}
