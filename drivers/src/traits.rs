//! Small capability traits, one per thing a device can do.
//!
//! All traits are `async` (tokio) through `async_trait`, `Send + Sync`, and object safe, so the
//! acquisition engine holds devices as `Arc<dyn Arm>`, `Arc<dyn MarkerTracker>`, … picked at run
//! time from a device file. Blanket impls make `Arc<T>` and `Box<T>` implement every trait `T` does.
//!
//! Units at this boundary: joint angles in radians, lengths in millimetres, time in seconds.
//! Drivers convert from whatever the wire speaks (UR: rad and m; DENSO: deg and mm; NDI: mm).

use crate::error::DriverResult;
use async_trait::async_trait;
use nalgebra::Isometry3;
use std::sync::Arc;

/// Pose of the arm's flange in the robot base frame (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlangeToBase(pub Isometry3<f64>);

/// Pose of a tracked marker (rigid body) in the tracker frame (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MarkerToTracker(pub Isometry3<f64>);

/// Measured joint state.
#[derive(Debug, Clone, PartialEq)]
pub struct JointState {
    /// Joint positions (rad).
    pub q: Vec<f64>,
    /// Joint velocities (rad/s), when the controller reports them.
    pub qd: Option<Vec<f64>>,
    /// Timestamp (s) on the device's or the simulator's clock.
    pub t: f64,
}

/// Speed and acceleration caps for one joint move (applied to every joint).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MoveSpeed {
    /// Maximum joint speed (rad/s).
    pub max_vel: f64,
    /// Maximum joint acceleration (rad/s²).
    pub max_acc: f64,
}

impl Default for MoveSpeed {
    fn default() -> Self {
        // A cautious calibration speed: 30 °/s, 60 °/s².
        Self {
            max_vel: 30f64.to_radians(),
            max_acc: 60f64.to_radians(),
        }
    }
}

/// The controller's operating mode, vendor independent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum ArmMode {
    /// Powered off / not connected to the motors.
    PoweredOff,
    /// Powered, brakes engaged or motors off.
    Idle,
    /// Ready to accept motion.
    Ready,
    /// Executing a motion.
    Moving,
    /// Anything the driver could not map.
    Unknown,
}

/// The controller's safety state, vendor independent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum SafetyState {
    /// Normal operation.
    Normal,
    /// Reduced mode (speed-limited by the controller).
    Reduced,
    /// Protective stop: recoverable by [`ArmStatus::recover`].
    ProtectiveStop,
    /// Emergency stop: needs a person.
    EmergencyStop,
    /// A fault or violation.
    Fault,
}

/// Mode and safety state at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArmState {
    /// Operating mode.
    pub mode: ArmMode,
    /// Safety state.
    pub safety: SafetyState,
}

/// Reads the measured joint angles.
#[async_trait]
pub trait JointReadout: Send + Sync {
    /// One joint state.
    ///
    /// # Contract
    /// Returns the latest sample the controller streamed (RTDE `actual_q`) or answers a request
    /// (b-CAP `CurJnt`); fails with `Timeout` when no sample arrives within the client's deadline.
    async fn joints(&self) -> DriverResult<JointState>;
}

/// Reads the controller's own forward kinematics of the flange.
#[async_trait]
pub trait FlangePose: Send + Sync {
    /// The flange pose in the robot base frame as the controller computes it.
    async fn flange_pose(&self) -> DriverResult<FlangeToBase>;
}

/// Moves the arm in joint space and reports arrival.
#[async_trait]
pub trait MoveJoints: Send + Sync {
    /// Number of joints this arm has.
    fn dof(&self) -> usize;
    /// Move to `target` (rad) under the speed caps; returns once the controller reports the
    /// motion finished (not merely accepted).
    ///
    /// # Implementation
    /// Real drivers must never be called directly by the engine: wrap them in the safety
    /// decorators of [`crate::safety`].
    async fn move_joints(&self, target: &[f64], speed: MoveSpeed) -> DriverResult<()>;
    /// Stop any motion now (decelerate).
    async fn stop(&self) -> DriverResult<()>;
}

/// Operating mode and safety state.
#[async_trait]
pub trait ArmStatus: Send + Sync {
    /// Current mode and safety state.
    async fn state(&self) -> DriverResult<ArmState>;
    /// Try to recover from a protective stop (e.g. UR dashboard `unlock protective stop`).
    async fn recover(&self) -> DriverResult<()> {
        Err(crate::error::DriverError::new(
            crate::error::ErrorKind::Unsupported,
            "arm",
            "this arm cannot recover from a protective stop remotely",
        ))
    }
    /// How many times the driver has rebuilt a lost link on its own so far (a dropped
    /// connection reopened inside a call that then succeeded). The acquisition records each
    /// one as a `fault` event, so a recovery the caller never saw as an error is still logged.
    fn link_recoveries(&self) -> u64 {
        0
    }
}

/// Everything an arm offers; implemented automatically for any type with all four capabilities.
pub trait Arm: JointReadout + FlangePose + MoveJoints + ArmStatus {}
impl<T: JointReadout + FlangePose + MoveJoints + ArmStatus + ?Sized> Arm for T {}

/// One laser range reading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RangeReading {
    /// A valid distance (mm).
    Distance(f64),
    /// No valid measurement (outside the window, no target, display limit).
    OutOfRange,
}

/// A range (displacement) sensor.
#[async_trait]
pub trait RangeSensor: Send + Sync {
    /// One reading.
    async fn read_range(&self) -> DriverResult<RangeReading>;
    /// Links rebuilt by the driver on its own so far (see [`ArmStatus::link_recoveries`]).
    fn link_recoveries(&self) -> u64 {
        0
    }
}

/// Visibility of one tool in one tracker frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ToolStatus {
    /// Tracked: pose and the tracker's fit RMS (mm).
    Visible {
        /// Marker pose in the tracker frame.
        pose: MarkerToTracker,
        /// Marker fit RMS error (mm).
        rms_mm: f64,
    },
    /// Enabled but not seen in this frame.
    Missing,
    /// Seen partially / outside the characterised measurement volume.
    OutOfVolume,
    /// Not enabled.
    Disabled,
}

/// One tool in one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct ToolObservation {
    /// Tool name or port handle (e.g. `"probe"`, `"0A"`).
    pub tool: String,
    /// What the tracker said about it.
    pub status: ToolStatus,
}

/// One tracker frame.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackerFrame {
    /// The tracker's frame counter.
    pub frame_number: u64,
    /// Timestamp (s).
    pub t: f64,
    /// Every enabled tool.
    pub tools: Vec<ToolObservation>,
}

impl TrackerFrame {
    /// The status of `tool`, or of the first tool when `tool` is `None`.
    pub fn tool(&self, tool: Option<&str>) -> Option<&ToolStatus> {
        match tool {
            Some(name) => self
                .tools
                .iter()
                .find(|t| t.tool == name)
                .map(|t| &t.status),
            None => self.tools.first().map(|t| &t.status),
        }
    }
}

/// An optical tracker.
#[async_trait]
pub trait MarkerTracker: Send + Sync {
    /// The next frame (blocks until the tracker delivers a new one).
    async fn frame(&self) -> DriverResult<TrackerFrame>;
    /// Links rebuilt by the driver on its own so far (see [`ArmStatus::link_recoveries`]).
    fn link_recoveries(&self) -> u64 {
        0
    }
}

/// An 8-bit grey image.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Width (px).
    pub width: u32,
    /// Height (px).
    pub height: u32,
    /// Row-major pixels, `width * height` bytes.
    pub data: Vec<u8>,
    /// Timestamp (s).
    pub t: f64,
}

/// A camera or image folder.
#[async_trait]
pub trait ImageSource: Send + Sync {
    /// One image.
    async fn grab(&self) -> DriverResult<Image>;
}

/// Time as the devices see it: the wall clock on hardware, the world's virtual clock in dry runs.
#[async_trait]
pub trait Clock: Send + Sync {
    /// Seconds since an arbitrary origin.
    fn now(&self) -> f64;
    /// Wait `secs` seconds of this clock.
    async fn sleep(&self, secs: f64);
}

/// The wall clock (tokio timers).
#[derive(Debug, Clone)]
pub struct SystemClock {
    origin: std::time::Instant,
}

impl Default for SystemClock {
    fn default() -> Self {
        Self {
            origin: std::time::Instant::now(),
        }
    }
}

#[async_trait]
impl Clock for SystemClock {
    fn now(&self) -> f64 {
        self.origin.elapsed().as_secs_f64()
    }
    async fn sleep(&self, secs: f64) {
        if secs > 0.0 && secs.is_finite() {
            tokio::time::sleep(std::time::Duration::from_secs_f64(secs)).await;
        }
    }
}

macro_rules! forward_ptr {
    ($($ptr:ident),*) => {$(
        #[async_trait]
        impl<T: JointReadout + ?Sized> JointReadout for $ptr<T> {
            async fn joints(&self) -> DriverResult<JointState> { (**self).joints().await }
        }
        #[async_trait]
        impl<T: FlangePose + ?Sized> FlangePose for $ptr<T> {
            async fn flange_pose(&self) -> DriverResult<FlangeToBase> { (**self).flange_pose().await }
        }
        #[async_trait]
        impl<T: MoveJoints + ?Sized> MoveJoints for $ptr<T> {
            fn dof(&self) -> usize { (**self).dof() }
            async fn move_joints(&self, target: &[f64], speed: MoveSpeed) -> DriverResult<()> {
                (**self).move_joints(target, speed).await
            }
            async fn stop(&self) -> DriverResult<()> { (**self).stop().await }
        }
        #[async_trait]
        impl<T: ArmStatus + ?Sized> ArmStatus for $ptr<T> {
            async fn state(&self) -> DriverResult<ArmState> { (**self).state().await }
            async fn recover(&self) -> DriverResult<()> { (**self).recover().await }
            fn link_recoveries(&self) -> u64 { (**self).link_recoveries() }
        }
        #[async_trait]
        impl<T: RangeSensor + ?Sized> RangeSensor for $ptr<T> {
            async fn read_range(&self) -> DriverResult<RangeReading> { (**self).read_range().await }
            fn link_recoveries(&self) -> u64 { (**self).link_recoveries() }
        }
        #[async_trait]
        impl<T: MarkerTracker + ?Sized> MarkerTracker for $ptr<T> {
            async fn frame(&self) -> DriverResult<TrackerFrame> { (**self).frame().await }
            fn link_recoveries(&self) -> u64 { (**self).link_recoveries() }
        }
        #[async_trait]
        impl<T: ImageSource + ?Sized> ImageSource for $ptr<T> {
            async fn grab(&self) -> DriverResult<Image> { (**self).grab().await }
        }
    )*};
}
forward_ptr!(Arc, Box);
