//! The in-process simulated cell: a scenario's world (`robocal_mocks`) adapted to the device
//! traits. With [`super::wire`] and [`super::live`] one of the three ways a cell is opened.
use std::path::Path;
use std::sync::Arc;

use anyhow::{bail, Context as _};
use robocal_drivers::{Arm, ImageSource, MarkerTracker, RangeSensor};
use robocal_mocks::scenario::ClockMode;
use robocal_mocks::sim::SimDevices;
use robocal_mocks::{Scenario, WorldHandle};

use crate::acquire::Devices;

/// What a cell tells the dataset header besides the plan.
#[derive(Debug, Clone, Default)]
pub struct CellInfo {
    /// Arm serial number.
    pub serial: Option<String>,
    /// Tracker kind (`ndi-optotrak-certus`, ...).
    pub tracker_kind: Option<String>,
    /// Range sensor kind (`keyence-il600`).
    pub range_kind: Option<String>,
}

/// The in-process simulated devices of a world (`robocal_mocks::sim`): its first arm,
/// tracker, laser and camera, and its clock. The arm is NOT yet wrapped in the safety
/// decorators. (`robocal run` drops the camera when the run does not record images.)
pub fn sim_cell(world: &WorldHandle) -> anyhow::Result<(Devices, CellInfo)> {
    let scenario = world.scenario();
    let sim = SimDevices::of(world);
    let Some((_, arm)) = sim.arms.into_iter().next() else {
        bail!("scenario {:?} has no arm", scenario.name);
    };
    let tracker = sim
        .trackers
        .into_iter()
        .next()
        .map(|(_, t)| Arc::new(t) as Arc<dyn MarkerTracker>);
    let range = sim
        .lasers
        .into_iter()
        .next()
        .map(|(_, l)| Arc::new(l) as Arc<dyn RangeSensor>);
    let camera = sim
        .cameras
        .into_iter()
        .next()
        .map(|(_, c)| Arc::new(c) as Arc<dyn ImageSource>);
    let info = CellInfo {
        serial: world.arm_identity(0).map(|(_, s)| s),
        tracker_kind: scenario
            .trackers
            .first()
            .map(|t| t.kind.as_str().to_string()),
        range_kind: scenario.lasers.first().map(|l| l.kind.clone()),
    };
    let arm: Arc<dyn Arm> = Arc::new(arm);
    Ok((
        Devices {
            arm,
            tracker,
            range,
            clock: world.clock(),
            camera,
        },
        info,
    ))
}

/// The world of the scenario at `scenario_path`, on a virtual or the real clock.
pub fn sim_world(scenario_path: &Path, virtual_clock: bool) -> anyhow::Result<WorldHandle> {
    let mut scenario = Scenario::load(scenario_path)?;
    scenario.clock = if virtual_clock {
        ClockMode::Virtual
    } else {
        ClockMode::Real
    };
    WorldHandle::from_scenario(&scenario)
        .with_context(|| format!("building the world of {}", scenario_path.display()))
}
