//! What a cell file says about the cell, for planning a session: a scenario (one arm of it)
//! or a device file read into a [`CellDescription`] (robot, controller, tracker, where it
//! stands and what it sees, the camera and its board) and the kind of session it makes.
use std::path::Path;

use anyhow::{bail, Context as _};
use robocal_mocks::Scenario;

use crate::plan::cell::{CellGeometry, Occluder, VolumeFrustum};
use crate::plan::spec::FrameSpec;
use crate::session::{self, CellDescription, SessionKind};

fn frame(p: &robocal_mocks::scenario::Placement) -> FrameSpec {
    FrameSpec {
        xyz: p.xyz_mm,
        rpy: p.rpy_deg,
    }
}

/// The cell as the scenario file states it, for arm `arm` (index), and the single-arm
/// scenario the session runs on.
pub fn describe_scenario(
    sc: &Scenario,
    arm: Option<&str>,
) -> anyhow::Result<(CellDescription, Scenario)> {
    let a = match arm {
        Some(n) => sc
            .arms
            .iter()
            .find(|a| a.name == n)
            .with_context(|| format!("scenario {:?} has no arm named {n:?}", sc.name))?,
        None => sc
            .arms
            .first()
            .with_context(|| format!("scenario {:?} has no arm", sc.name))?,
    };
    let mut one = sc.clone();
    one.arms = vec![a.clone()];
    one.trackers.retain(|t| t.arm == a.name);
    one.lasers.retain(|l| l.arm == a.name);
    one.cameras
        .retain(|c| c.arm.as_deref().is_none_or(|n| n == a.name));
    let t = one.trackers.first();
    let geometry = t.map(|t| {
        let vol = t.effects.volume.unwrap_or(match t.kind {
            robocal_mocks::scenario::TrackerKind::NdiOptotrakCertus => {
                robocal_mocks::scenario::VolumeKind::Optotrak
            }
            _ => robocal_mocks::scenario::VolumeKind::PolarisPyramid,
        });
        CellGeometry {
            tracker_pose: frame(&t.tracker_in_base),
            volume: robocal_mocks::world::sensors::volume_frustum(vol).map(
                |(near_mm, far_mm, tan_x, tan_y)| VolumeFrustum {
                    near_mm,
                    far_mm,
                    tan_x,
                    tan_y,
                },
            ),
            max_view_angle_deg: t.effects.max_view_angle_deg,
            occluders: t
                .effects
                .occluders
                .iter()
                .map(|o| Occluder {
                    center_mm: o.center_mm,
                    radius_mm: o.radius_mm,
                })
                .collect(),
            margin_mm: 25.0,
            margin_deg: 3.0,
        }
    });
    let mut sensors: Vec<String> = one
        .lasers
        .iter()
        .map(|l| format!("laser {} ({})", l.name, l.kind))
        .collect();
    sensors.extend(one.cameras.iter().map(|c| format!("camera {}", c.name)));
    let camera = one.cameras.first().map(|c| {
        let board = one.scene.chessboard.as_ref().map(|b| {
            let centre = b.placement.isometry()
                * nalgebra::Point3::new(
                    b.cols as f64 * b.square_mm / 2.0,
                    b.rows as f64 * b.square_mm / 2.0,
                    0.0,
                );
            session::camera::BoardCell {
                kind: "chessboard".into(),
                cols: b.cols.saturating_sub(1),
                rows: b.rows.saturating_sub(1),
                square_mm: b.square_mm,
                center_mm: [centre.x, centre.y, centre.z],
            }
        });
        session::camera::CameraCell {
            name: c.name.clone(),
            width: c.width,
            height: c.height,
            mount: if c.arm.is_some() { "flange" } else { "base" }.into(),
            board,
        }
    });
    Ok((
        CellDescription {
            robot_model: a.model.clone(),
            robot_serial: Some(a.serial.clone()),
            controller: Some(protocol_name(&a.protocol)),
            tracker: t.map(|t| format!("{} ({})", t.kind.as_str(), protocol_name(&t.protocol))),
            tracker_serial: t.map(|t| t.name.clone()),
            sensors,
            marker_on_flange: t.map(|t| frame(&t.marker_on_flange)),
            home_deg: a.home_deg.clone(),
            geometry,
            tracker_rate_hz: t.map(|t| t.rate_hz),
            settle_s: Some(a.motion.settle_s),
            camera,
            endoscope: endoscope(&one),
        },
        one,
    ))
}

/// An RCM cell's stated endoscope (a camera fixed in the base: its intrinsics as the
/// endoscope's own prior calibration) and instrument shaft, when the scene has an instrument.
fn endoscope(sc: &Scenario) -> Option<session::rcm::EndoscopeCell> {
    let inst = sc.scene.instrument.as_ref()?;
    let c = sc.cameras.iter().find(|c| c.arm.is_none())?;
    Some(session::rcm::EndoscopeCell {
        name: c.name.clone(),
        camera: crate::dataset::endoscope::EndoscopeCamera {
            kind: "endoscope".into(),
            width: c.width,
            height: c.height,
            fx: c.fx,
            fy: c.fy,
            cx: c.cx,
            cy: c.cy,
            dist: [c.k1, c.k2, 0.0, 0.0, 0.0],
        },
        shaft_radius_mm: inst.radius_mm,
    })
}

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
    use robocal_mocks::scenario::VolumeKind;
    let pose = t.tracker_in_base?;
    let vol = match t.volume.as_deref() {
        Some("polaris-extended") => VolumeKind::PolarisExtended,
        Some("optotrak") => VolumeKind::Optotrak,
        Some("unbounded") => VolumeKind::Unbounded,
        None if t.protocol == crate::acquire::devices::Protocol::OptotrakOapi => {
            VolumeKind::Optotrak
        }
        _ => VolumeKind::PolarisPyramid,
    };
    Some(CellGeometry {
        tracker_pose: pose_frame(pose),
        volume: robocal_mocks::world::sensors::volume_frustum(vol).map(
            |(near_mm, far_mm, tan_x, tan_y)| VolumeFrustum {
                near_mm,
                far_mm,
                tan_x,
                tan_y,
            },
        ),
        // Passive markers are seen up to about 75° off the tracker's axis.
        max_view_angle_deg: Some(75.0),
        occluders: vec![],
        // A pose measured roughly: keep further from the volume's edges.
        margin_mm: 50.0,
        margin_deg: 5.0,
    })
}
