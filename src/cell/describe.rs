//! What a cell file says about the cell, for planning a session: a device file (or, through
//! `super::simulated`, a scenario: one arm of it) read into a [`CellDescription`] (robot, controller, tracker, where it
//! stands and what it sees, the camera and its board) and the kind of session it makes.
use std::path::Path;

use anyhow::{bail, Context as _};

use crate::plan::cell::{CellGeometry, VolumeFrustum};
use crate::plan::spec::FrameSpec;
use crate::session::{self, CellDescription, SessionKind};

#[cfg(feature = "sim")]
pub use super::simulated::describe_scenario;

/// A protocol's name as the file spells it.
fn protocol_name<T: serde::Serialize>(p: &T) -> String {
    serde_json::to_value(p)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_else(|| "?".into())
}

/// The cell as a device file states it (no geometry: visibility from the plan spec), and the
/// kind of session it makes: kinematic with a tracker, camera with a camera and no tracker.
pub fn describe_devices(path: &Path) -> anyhow::Result<(CellDescription, SessionKind)> {
    use crate::acquire::devices::{DevicesFile, Role};
    let f = DevicesFile::read(path)?;
    let arm = f
        .devices
        .iter()
        .find(|d| d.role == Role::Arm)
        .with_context(|| format!("{}: no device with role = \"arm\"", path.display()))?;
    let tracker = f.devices.iter().find(|d| d.role == Role::Tracker);
    let model = arm.model.clone().with_context(|| {
        format!(
            "{}: device {:?}: add `model = \"denso-vs060\"` (the robot preset) for a session",
            path.display(),
            arm.name
        )
    })?;
    let camera = f.devices.iter().find(|d| d.role == Role::Camera);
    let kind = match (tracker, camera) {
        (Some(_), _) => SessionKind::Kinematic,
        (None, Some(_)) => SessionKind::Camera,
        (None, None) => bail!(
            "{}: neither a tracker (kinematic session) nor a camera (camera session): add a \
             device with role = \"tracker\" or role = \"camera\"",
            path.display()
        ),
    };
    let camera = match (kind, camera) {
        (SessionKind::Camera, Some(c)) => {
            let b = f.board.as_ref().with_context(|| {
                format!(
                    "{}: a camera session needs the cell's board: add a [board] table (kind, \
                     cols, rows = inner corners, square_mm, center_mm = its centre in the robot \
                     base)",
                    path.display()
                )
            })?;
            let center_mm = b.center_mm.with_context(|| {
                format!(
                    "{}: [board] has no center_mm: give the board's centre in the robot base \
                     (mm), where the session's viewpoints look",
                    path.display()
                )
            })?;
            Some(session::camera::CameraCell {
                name: c.name.clone(),
                // Known from the first image (the dataset header records it).
                width: 0,
                height: 0,
                mount: c.mount.clone().unwrap_or_else(|| "flange".into()),
                board: Some(session::camera::BoardCell {
                    kind: b.kind.clone(),
                    cols: b.cols,
                    rows: b.rows,
                    square_mm: b.square_mm,
                    center_mm,
                }),
            })
        }
        _ => None,
    };
    let cell = CellDescription {
        camera,
        robot_model: model,
        // The arm reports its serial number when it connects (dataset header).
        robot_serial: None,
        controller: Some(protocol_name(&arm.protocol)),
        tracker: tracker.map(|t| format!("{} ({})", t.vendor, protocol_name(&t.protocol))),
        tracker_serial: tracker.map(|t| t.name.clone()),
        sensors: f
            .devices
            .iter()
            .filter(|d| matches!(d.role, Role::Laser | Role::Camera))
            .map(|d| format!("{:?} {}", d.role, d.name))
            .collect(),
        marker_on_flange: tracker.and_then(|t| t.marker_on_flange).map(pose_frame),
        geometry: tracker.and_then(device_geometry),
        safety: f.safety.clone(),
        ..Default::default()
    };
    Ok((cell, kind))
}

fn pose_frame(p: crate::acquire::devices::PoseEntry) -> FrameSpec {
    FrameSpec {
        xyz: p.xyz_mm,
        rpy: p.rpy_deg,
    }
}

/// Where a device file's tracker stands (`tracker_in_base`, rough) and its volume: the
/// planner keeps the poses it can see, with wider margins than a scenario's exact pose.
fn device_geometry(t: &crate::acquire::devices::DeviceEntry) -> Option<CellGeometry> {
    let pose = t.tracker_in_base?;
    let optotrak = t.protocol == crate::acquire::devices::Protocol::OptotrakOapi;
    Some(CellGeometry {
        tracker_pose: pose_frame(pose),
        volume: vendor_volume(t.volume.as_deref(), optotrak),
        // Passive markers are seen up to about 75° off the tracker's axis.
        max_view_angle_deg: Some(75.0),
        occluders: vec![],
        // A pose measured roughly: keep further from the volume's edges.
        margin_mm: 50.0,
        margin_deg: 5.0,
    })
}

/// The vendor's measurement volume (datasheet figures) named by a device file's `volume`
/// (`polaris-pyramid`, the default; `polaris-extended`; `optotrak`, the default of an Optotrak;
/// `unbounded`: `None`), along the tracker's line of sight: depth (mm) and half-angle tangents.
fn vendor_volume(name: Option<&str>, optotrak: bool) -> Option<VolumeFrustum> {
    let (near_mm, far_mm, tan_x, tan_y) = match name {
        Some("unbounded") => return None,
        Some("polaris-extended") => (950.0, 3000.0, 0.33, 0.28),
        Some("optotrak") => (1000.0, 6000.0, 0.55, 0.45),
        None if optotrak => (1000.0, 6000.0, 0.55, 0.45),
        _ => (950.0, 2400.0, 0.33, 0.28),
    };
    Some(VolumeFrustum {
        near_mm,
        far_mm,
        tan_x,
        tan_y,
    })
}
