//! One interface over the two kinds of cell a run opens: a simulated one (a scenario file,
//! `super::simulated`, feature `sim`) and a real one (a device file, [`super::live`]). Each says what its
//! file states ([`StatedCell`]: the arm's limits and safety block, the camera and its board)
//! and opens its devices ([`OpenCell`]); the run never asks which kind it has beyond that.
use std::path::Path;

use crate::acquire::Devices;
use crate::dataset::{CameraHeader, TargetHeader};
use crate::plan::recheck::CellRobot;
use crate::plausible::limits::CellLimit;

use super::safety::LiveConsent;

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

/// The arm as its cell file states it: model, safety block and motion limits (deg/s, deg/s²),
/// each with where it comes from (for messages).
#[derive(Debug, Clone)]
pub struct StatedArm {
    /// Model and safety block.
    pub robot: CellRobot,
    /// Speed limit.
    pub vel: Option<CellLimit>,
    /// Acceleration limit.
    pub acc: Option<CellLimit>,
}

/// The camera as its cell file states it.
#[derive(Debug, Clone)]
pub struct StatedCamera {
    /// Device name.
    pub name: String,
    /// The dataset header's `camera` block; width and height 0 when only the first image
    /// tells them (a real camera).
    pub header: CameraHeader,
    /// The board, inner corners (the header's `target` block).
    pub target: Option<TargetHeader>,
    /// The chessboard (inner corners) a run detects while it records, when the cell states one
    /// the capture-time detector can label.
    pub detect: Option<(u32, u32)>,
}

/// What a cell file states about the cell (as a real cell's device file would).
#[derive(Debug, Clone)]
pub struct StatedCell {
    /// The arm a run drives.
    pub arm: StatedArm,
    /// Its first camera.
    pub camera: Option<StatedCamera>,
}

/// A cell's devices opened for a run. The arm is NOT yet wrapped in the safety decorators.
pub struct OpenCell {
    /// The devices.
    pub devices: Devices,
    /// What the header records about them.
    pub info: CellInfo,
    /// Stops what the cell started for the run (a simulated cell's protocol servers).
    pub stop: Option<Box<dyn FnOnce() + Send>>,
}

/// A cell a run can open: a scenario's simulated cell or a device file's hardware.
pub trait CellSource {
    /// What the cell file states, for arm `arm` (default: the one a run drives).
    fn stated(&self, arm: Option<&str>) -> anyhow::Result<StatedCell>;
    /// Opens the devices on `rt`. A real cell needs `consent` (only
    /// [`super::confirm_live`] makes one); a simulated cell ignores it.
    fn open(
        &self,
        rt: &tokio::runtime::Runtime,
        consent: Option<&LiveConsent>,
    ) -> anyhow::Result<OpenCell>;
}

/// How a run opens its cell.
#[derive(Debug, Clone, Copy, Default)]
pub struct OpenOptions {
    /// Simulated cells: simulated time jumps instead of passing.
    pub virtual_clock: bool,
    /// Simulated cells: in-process devices instead of the wire protocols.
    pub in_process: bool,
    /// Real cells: the arm's joint count (the plan's).
    pub dof: usize,
    /// Open the camera.
    pub camera: bool,
}

/// The cell of a run directory's `mode` (`sim`: the scenario file at `path`; `live`: the
/// device file at `path`).
pub fn source(mode: &str, path: &Path, opts: OpenOptions) -> anyhow::Result<Box<dyn CellSource>> {
    Ok(match mode {
        #[cfg(feature = "sim")]
        "sim" => Box::new(super::simulated::ScenarioCell::new(path, opts)),
        #[cfg(not(feature = "sim"))]
        "sim" => {
            let _ = opts;
            return Err(super::without_simulators(&format!(
                "scenario {}",
                path.display()
            )));
        }
        "live" => Box::new(super::live::DeviceFileCell::new(path, opts)),
        other => anyhow::bail!("unknown cell mode {other:?} (sim or live)"),
    })
}
