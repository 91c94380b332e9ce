//! In-process implementations of every device trait over the world, for fast engine tests
//! (no sockets). They honour the world's clock (virtual or real) and its injected faults: a
//! queued [`Fault`] for the device name turns the next call into the matching driver error.

use crate::world::{Fault, WorldError, WorldHandle};
use async_trait::async_trait;
use robocal_drivers::{
    ArmState, ArmStatus, DriverError, DriverResult, ErrorKind, FlangePose, FlangeToBase, Image,
    ImageSource, JointReadout, JointState, MarkerTracker, MoveJoints, MoveSpeed, RangeReading,
    RangeSensor, SafetyState, TrackerFrame,
};

/// Map a queued fault to what an in-process caller would see.
async fn apply_fault(world: &WorldHandle, device: &str) -> DriverResult<()> {
    match world.take_fault(device) {
        None => Ok(()),
        Some(Fault::Delay { secs }) => {
            world.clock().sleep(secs).await;
            Ok(())
        }
        Some(Fault::Silence { secs }) => {
            world.clock().sleep(secs).await;
            Err(DriverError::new(
                ErrorKind::Timeout,
                device,
                "no reply (injected silence)",
            ))
        }
        Some(Fault::DropLink) => Err(DriverError::new(
            ErrorKind::Disconnected,
            device,
            "link dropped (injected)",
        )),
        Some(Fault::ErrorReply { code }) => Err(DriverError::new(
            ErrorKind::DeviceRejected,
            device,
            format!("device error {code} (injected)"),
        )),
        Some(Fault::Garbage { .. }) | Some(Fault::BadCrc) | Some(Fault::Truncated) => Err(
            DriverError::new(ErrorKind::Protocol, device, "corrupt reply (injected)"),
        ),
    }
}

fn world_err(device: &str, e: WorldError) -> DriverError {
    let kind = match e {
        WorldError::ProtectiveStop => ErrorKind::SafetyStop,
        WorldError::InvalidTarget(_) | WorldError::OutOfLimits { .. } => ErrorKind::InvalidArgument,
        _ => ErrorKind::Other,
    };
    DriverError::new(kind, device, e.to_string())
}

/// An arm of the world.
#[derive(Clone)]
pub struct SimArm {
    world: WorldHandle,
    arm: usize,
    name: String,
}

impl SimArm {
    /// Arm `arm` of `world`, named `name` (the name that faults are queued under).
    pub fn new(world: WorldHandle, arm: usize, name: impl Into<String>) -> Self {
        Self {
            world,
            arm,
            name: name.into(),
        }
    }
}

#[async_trait]
impl JointReadout for SimArm {
    async fn joints(&self) -> DriverResult<JointState> {
        apply_fault(&self.world, &self.name).await?;
        Ok(self.world.arm_joint_state(self.arm))
    }
}

#[async_trait]
impl FlangePose for SimArm {
    async fn flange_pose(&self) -> DriverResult<FlangeToBase> {
        apply_fault(&self.world, &self.name).await?;
        Ok(FlangeToBase(self.world.arm_controller_flange(self.arm)))
    }
}

#[async_trait]
impl MoveJoints for SimArm {
    fn dof(&self) -> usize {
        self.world.arm_dof(self.arm)
    }
    async fn move_joints(&self, target: &[f64], speed: MoveSpeed) -> DriverResult<()> {
        apply_fault(&self.world, &self.name).await?;
        self.world
            .arm_start_move(self.arm, target, speed)
            .map_err(|e| world_err(&self.name, e))?;
        self.world.arm_wait_arrival(self.arm).await;
        if self.world.arm_state(self.arm).safety == SafetyState::ProtectiveStop {
            return Err(DriverError::new(
                ErrorKind::SafetyStop,
                &self.name,
                "protective stop during the move",
            ));
        }
        Ok(())
    }
    async fn stop(&self) -> DriverResult<()> {
        self.world.arm_stop(self.arm);
        Ok(())
    }
}

#[async_trait]
impl ArmStatus for SimArm {
    async fn state(&self) -> DriverResult<ArmState> {
        apply_fault(&self.world, &self.name).await?;
        Ok(self.world.arm_state(self.arm))
    }
    async fn recover(&self) -> DriverResult<()> {
        self.world
            .arm_recover(self.arm)
            .map_err(|e| world_err(&self.name, e))
    }
}

/// A tracker of the world.
#[derive(Clone)]
pub struct SimTracker {
    world: WorldHandle,
    tracker: usize,
    name: String,
}

impl SimTracker {
    /// Tracker `tracker` of `world`, named `name`.
    pub fn new(world: WorldHandle, tracker: usize, name: impl Into<String>) -> Self {
        Self {
            world,
            tracker,
            name: name.into(),
        }
    }
}

#[async_trait]
impl MarkerTracker for SimTracker {
    async fn frame(&self) -> DriverResult<TrackerFrame> {
        apply_fault(&self.world, &self.name).await?;
        if !self.world.is_virtual() {
            let rate = self.world.tracker_info(self.tracker).map_or(60.0, |i| i.1);
            self.world.clock().sleep(1.0 / rate).await;
        }
        Ok(self.world.tracker_frame_of(self.tracker))
    }
}

/// A laser range sensor of the world.
#[derive(Clone)]
pub struct SimRange {
    world: WorldHandle,
    laser: usize,
    name: String,
}

impl SimRange {
    /// Laser `laser` of `world`, named `name`.
    pub fn new(world: WorldHandle, laser: usize, name: impl Into<String>) -> Self {
        Self {
            world,
            laser,
            name: name.into(),
        }
    }
}

#[async_trait]
impl RangeSensor for SimRange {
    async fn read_range(&self) -> DriverResult<RangeReading> {
        apply_fault(&self.world, &self.name).await?;
        Ok(self.world.laser_reading_of(self.laser))
    }
}

/// A camera of the world.
#[derive(Clone)]
pub struct SimCamera {
    world: WorldHandle,
    camera: usize,
    name: String,
}

impl SimCamera {
    /// Camera `camera` of `world`, named `name`.
    pub fn new(world: WorldHandle, camera: usize, name: impl Into<String>) -> Self {
        Self {
            world,
            camera,
            name: name.into(),
        }
    }
}

#[async_trait]
impl ImageSource for SimCamera {
    async fn grab(&self) -> DriverResult<Image> {
        apply_fault(&self.world, &self.name).await?;
        Ok(self.world.render_camera_of(self.camera))
    }
}

/// Every device of a world as trait objects, by scenario name.
pub struct SimDevices {
    /// Arms.
    pub arms: Vec<(String, SimArm)>,
    /// Trackers.
    pub trackers: Vec<(String, SimTracker)>,
    /// Lasers.
    pub lasers: Vec<(String, SimRange)>,
    /// Cameras.
    pub cameras: Vec<(String, SimCamera)>,
}

impl SimDevices {
    /// Build one `Sim*` per device of the world's scenario.
    pub fn of(world: &WorldHandle) -> Self {
        let s = world.scenario();
        Self {
            arms: s
                .arms
                .iter()
                .enumerate()
                .map(|(i, a)| (a.name.clone(), SimArm::new(world.clone(), i, &a.name)))
                .collect(),
            trackers: s
                .trackers
                .iter()
                .enumerate()
                .map(|(i, a)| (a.name.clone(), SimTracker::new(world.clone(), i, &a.name)))
                .collect(),
            lasers: s
                .lasers
                .iter()
                .enumerate()
                .map(|(i, a)| (a.name.clone(), SimRange::new(world.clone(), i, &a.name)))
                .collect(),
            cameras: s
                .cameras
                .iter()
                .enumerate()
                .map(|(i, a)| (a.name.clone(), SimCamera::new(world.clone(), i, &a.name)))
                .collect(),
        }
    }
}
