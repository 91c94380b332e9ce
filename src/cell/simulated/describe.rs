//! A scenario (one arm of it) read into the session's [`CellDescription`]: what the scenario
//! states, as a device file would (robot, controller, tracker, where it stands and what it
//! sees, the camera and its board).
use std::path::Path;

use anyhow::Context as _;
use robocal_mocks::stated::{StatedPose, StatedScenario};

use crate::plan::cell::{CellGeometry, Occluder, VolumeFrustum};
use crate::plan::spec::FrameSpec;
use crate::session::{self, CellDescription};

fn frame(p: &StatedPose) -> FrameSpec {
    FrameSpec {
        xyz: p.xyz_mm,
        rpy: p.rpy_deg,
    }
}

/// The cell as the scenario file at `path` states it, for arm `arm` (default: the first), and
/// the stated facts of that arm's single-arm cell (its trackers, lasers and cameras).
pub fn describe_scenario(
    path: &Path,
    arm: Option<&str>,
) -> anyhow::Result<(CellDescription, StatedScenario)> {
    let sc = super::stated_scenario(path)?;
    let a = match arm {
        Some(n) => sc
            .arm(Some(n))
            .with_context(|| format!("scenario {:?} has no arm named {n:?}", sc.name))?,
        None => sc
            .arm(None)
            .with_context(|| format!("scenario {:?} has no arm", sc.name))?,
    };
    let one = sc.one_arm(&a.name);
    let t = one.trackers.first();
    let geometry = t.map(|t| CellGeometry {
        tracker_pose: frame(&t.tracker_in_base),
        volume: t.volume.map(|v| VolumeFrustum {
            near_mm: v.near_mm,
            far_mm: v.far_mm,
            tan_x: v.tan_x,
            tan_y: v.tan_y,
        }),
        max_view_angle_deg: t.max_view_angle_deg,
        occluders: t
            .occluders
            .iter()
            .map(|o| Occluder {
                center_mm: o.center_mm,
                radius_mm: o.radius_mm,
            })
            .collect(),
        margin_mm: 25.0,
        margin_deg: 3.0,
    });
    let mut sensors: Vec<String> = one
        .lasers
        .iter()
        .map(|l| format!("laser {} ({})", l.name, l.kind))
        .collect();
    sensors.extend(one.cameras.iter().map(|c| format!("camera {}", c.name)));
    let camera = one.cameras.first().map(|c| {
        let board = one.board.as_ref().map(|b| session::camera::BoardCell {
            kind: "chessboard".into(),
            cols: b.cols.saturating_sub(1),
            rows: b.rows.saturating_sub(1),
            square_mm: b.square_mm,
            center_mm: b.center_mm,
        });
        session::camera::CameraCell {
            name: c.name.clone(),
            width: c.width,
            height: c.height,
            mount: if c.arm.is_some() { "flange" } else { "base" }.into(),
            board,
        }
    });
    let description = CellDescription {
        robot_model: a.model.clone(),
        robot_serial: Some(a.serial.clone()),
        controller: Some(a.protocol.as_str().to_string()),
        tracker: t.map(|t| format!("{} ({})", t.kind, t.protocol.as_str())),
        tracker_serial: t.map(|t| t.name.clone()),
        sensors,
        marker_on_flange: t.map(|t| frame(&t.marker_on_flange)),
        home_deg: a.home_deg.clone(),
        geometry,
        tracker_rate_hz: t.map(|t| t.rate_hz),
        settle_s: Some(a.settle_s),
        camera,
        endoscope: endoscope(&one),
        // The scenario's `[arm.safety]`, as a device file's `[safety]` states it: the session
        // plans inside it (not only the run's re-check refusing a plan wider than it).
        safety: a
            .safety
            .as_ref()
            .map(|s| crate::acquire::device_safety::SafetyEntry {
                table_z_mm: s.table_z_mm,
                table_clearance_mm: s.table_clearance_mm,
                envelope: s.envelope.clone(),
                ..Default::default()
            }),
    };
    Ok((description, one))
}

/// An RCM cell's stated endoscope (a camera fixed in the base: its intrinsics as the
/// endoscope's own prior calibration) and instrument shaft, when the scene has an instrument.
fn endoscope(sc: &StatedScenario) -> Option<session::rcm::EndoscopeCell> {
    let inst = sc.instrument.as_ref()?;
    let c = sc.cameras.iter().find(|c| c.arm.is_none())?;
    let [fx, fy, cx, cy] = c.intrinsics;
    Some(session::rcm::EndoscopeCell {
        name: c.name.clone(),
        camera: crate::dataset::endoscope::EndoscopeCamera {
            kind: "endoscope".into(),
            width: c.width,
            height: c.height,
            fx,
            fy,
            cx,
            cy,
            dist: [c.radial[0], c.radial[1], 0.0, 0.0, 0.0],
        },
        shaft_radius_mm: inst.radius_mm,
    })
}
