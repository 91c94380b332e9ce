//! `robocal session --survey`: before planning, a few safe probe poses locate
//! the tracker (and the marker on the flange) when the cell file states the tracker's pose
//! only roughly, or not at all. The planner then plans from the surveyed pose, so the poses
//! it keeps are the ones the tracker really sees.
//!
//! The probe poses are planned like every other plan (the session's spec, every safety
//! constraint, the path check) but with visibility relaxed to "the marker faces the tracker's
//! stated position" (no measurement-volume check: the volume is where the stated pose is
//! wrong). They are acquired through the same [`super::Cell`] (same run directory, same
//! safety wrappers, consent after the survey plan is shown) into `run-survey/`, and the
//! robot-world problem `A_i X = Y B_i` ([`crate::register::robot_world`]: Shah, then the
//! joint refinement) on the poses where the marker was seen gives `Y` (tracker in the base)
//! and `X` (marker on the flange), with the nominal kinematics for `A_i` (a few mm of arm
//! error are far below what visibility needs). Written: `survey/robot_world.json`
//! (`robocal-robot-world/1`, reads back with `calibrate robot-world --check`) and the summary
//! in `session.json` (`survey`).
use std::path::Path;

use anyhow::{bail, Context as _};
use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

use super::{fit_spec_to_cell, rel, write_atomic, Cell, Log, SessionFile};
use crate::dataset::RobotBlock;
use crate::model::KinematicModel;
use crate::plan::{self, cell::CellGeometry, spec::FrameSpec, PlanOptions, PlanSpec};
use crate::register::robot_world as rw;

/// Probe poses planned (the ones the tracker sees solve the robot-world problem).
pub const PROBES: usize = 12;
/// Fewest probe poses with the marker seen for a survey to count.
pub const MIN_SEEN: usize = 4;
/// The probe poses keep the marker within this angle of the line of sight to the tracker's
/// stated position (deg): a stated pose wrong by a few hundred mm still sees them.
const PROBE_VIEW_DEG: f64 = 55.0;
/// A survey whose fit leaves more than this position RMS (mm) is refused (a marker mixed up,
/// a wrong robot model).
const MAX_RMS_MM: f64 = 15.0;

/// What the survey found (`session.json` → `survey`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SurveySummary {
    /// Probe poses planned / with the marker seen.
    pub probes: usize,
    pub seen: usize,
    /// The tracker pose the cell file stated (none: the plan spec's), and the surveyed one
    /// (mm, URDF rpy deg, robot base).
    pub tracker_stated: Option<FrameSpec>,
    pub tracker_surveyed: FrameSpec,
    /// How far the stated pose was off: origin distance (mm) and rotation angle (deg).
    pub tracker_moved_mm: Option<f64>,
    pub tracker_turned_deg: Option<f64>,
    /// The marker on the flange as stated and as surveyed.
    pub marker_stated: Option<FrameSpec>,
    pub marker_surveyed: FrameSpec,
    /// Fit residuals (nominal kinematics): position RMS (mm), rotation RMS (deg).
    pub rms_pos_mm: f64,
    pub rms_rot_deg: f64,
    /// `survey/robot_world.json`, relative to the session directory.
    pub file: String,
}

/// An isometry (mm, rad) as a frame (mm, URDF rpy deg): the inverse of [`plan::frame_iso`].
pub fn iso_frame(t: &Isometry3<f64>) -> FrameSpec {
    let (r, p, y) = t.rotation.euler_angles();
    FrameSpec {
        xyz: [t.translation.x, t.translation.y, t.translation.z],
        rpy: [r.to_degrees(), p.to_degrees(), y.to_degrees()],
    }
}

/// The session's spec fitted to the cell, and the tracker geometry the survey starts from:
/// the cell file's, else the plan spec's tracker.
fn stated(dir: &Path, s: &SessionFile) -> anyhow::Result<(PlanSpec, CellGeometry)> {
    let spec_path = dir.join(&s.setup.spec_file);
    let mut spec = PlanSpec::from_file(&spec_path)
        .with_context(|| format!("reading {}", spec_path.display()))?;
    let spec_tracker = spec.tracker.clone();
    fit_spec_to_cell(&mut spec, &s.cell, &s.setup);
    let geometry = match (&s.cell.geometry, spec_tracker) {
        (Some(g), _) => g.clone(),
        (None, Some(t)) => {
            let f = crate::plan::constraints::Frustum::of(t.kind);
            CellGeometry {
                tracker_pose: t.pose.clone(),
                volume: Some(crate::plan::cell::VolumeFrustum {
                    near_mm: f.near_mm,
                    far_mm: f.far_mm,
                    tan_x: f.half_x.tan(),
                    tan_y: f.half_y.tan(),
                }),
                max_view_angle_deg: Some(t.max_angle_deg),
                occluders: vec![],
                margin_mm: 25.0,
                margin_deg: 3.0,
            }
        }
        (None, None) => bail!(
            "--survey: neither the cell file (`tracker_in_base`) nor the plan spec ([tracker]) \
             says roughly where the tracker stands: the probe poses need a direction to face"
        ),
    };
    Ok((spec, geometry))
}

/// Plans `plan/survey.json`: [`PROBES`] poses of the session's spec that face the tracker's
/// stated position (every safety constraint of the spec kept).
fn plan_probes(dir: &Path, s: &SessionFile) -> anyhow::Result<()> {
    let (mut spec, g) = stated(dir, s)?;
    let max = g.max_view_angle_deg.unwrap_or(75.0);
    spec.cell = Some(CellGeometry {
        volume: None,
        max_view_angle_deg: Some(max.min(90.0)),
        margin_deg: (max - PROBE_VIEW_DEG).max(0.0),
        ..g
    });
    spec.tracker = None;
    spec.name = format!("{}-survey", spec.name);
    spec.group = "survey".into();
    let robot = RobotBlock {
        model: s.cell.robot_model.clone(),
        serial: s.cell.robot_serial.clone(),
        chain: None,
        flange: None,
        extra: Default::default(),
    };
    let mut model = KinematicModel::from_robot_block(&robot).context("the cell's robot")?;
    crate::acquire::device_safety::narrow_model(&mut model, s.cell.safety.as_ref())?;
    let out = plan::build_plan(
        &spec,
        robot,
        &model,
        &PlanOptions {
            select: Some(PROBES),
        },
    )
    .context("planning the survey's probe poses")?;
    if out.file.poses.len() < MIN_SEEN {
        bail!(
            "--survey: only {} probe poses of the plan spec face the tracker's stated position \
             (need {MIN_SEEN}): check `tracker_in_base` in the cell file",
            out.file.poses.len()
        );
    }
    if out.file.summary.path_violations > 0 {
        bail!(
            "--survey: {} moves of the probe plan fail the safety path check: nothing moved",
            out.file.summary.path_violations
        );
    }
    write_atomic(
        &dir.join("plan").join("survey.json"),
        serde_json::to_string_pretty(&out.file)?.as_bytes(),
    )
}

/// Runs the survey (or continues it) and puts the surveyed tracker and marker poses into the
/// session's cell description. Does nothing once `session.json` holds a survey.
pub fn run(dir: &Path, s: &mut SessionFile, cell: &mut dyn Cell, log: Log) -> anyhow::Result<()> {
    if s.survey.is_some() {
        return Ok(());
    }
    let plan_path = dir.join("plan").join("survey.json");
    if !plan_path.is_file() {
        log("survey: probe poses that locate the tracker and the marker");
        plan_probes(dir, s)?;
    }
    let run_dir = dir.join("run-survey");
    let summary = cell.acquire_probes(&plan_path, &run_dir).with_context(|| {
        format!(
            "the survey's probe poses (continue with `robocal session --resume {}`)",
            dir.display()
        )
    })?;
    if let Some(reason) = &summary.aborted {
        bail!(
            "survey stopped: {reason} (continue with `robocal session --resume {}`)",
            dir.display()
        );
    }
    let ds_path = run_dir.join("dataset.jsonl");
    let ds = crate::dataset::Dataset::load(&ds_path)
        .with_context(|| format!("reading {}", ds_path.display()))?;
    let (obs, skipped) = rw::observations_from_dataset(&ds)?;
    let probes = obs.len() + skipped.len();
    if obs.len() < MIN_SEEN {
        bail!(
            "survey: the tracker saw the marker at {} of {probes} probe poses (need {MIN_SEEN}; \
             {}): the tracker stands far from where the cell file says, or does not see the \
             marker's side — correct `tracker_in_base` roughly (a tape measure will do) and \
             start the session again",
            obs.len(),
            rw::skip_summary(&skipped)
        );
    }
    let start = rw::shah(&obs).context("survey: robot-world closed form")?;
    let fit = rw::refine(&obs, start, &rw::RefineOptions::default())
        .context("survey: robot-world refinement")?;
    if fit.rms_pos_mm.is_nan() || fit.rms_pos_mm > MAX_RMS_MM {
        bail!(
            "survey: the probe poses do not agree on one tracker pose (position RMS {:.1} mm > \
             {MAX_RMS_MM} mm): is the tracked tool the one on the flange, and the arm's model \
             `{}`?",
            fit.rms_pos_mm,
            s.cell.robot_model
        );
    }
    let file = dir.join("survey").join("robot_world.json");
    std::fs::create_dir_all(dir.join("survey"))?;
    rw::RobotWorldFile::new(&fit, obs.len(), &[("shah", start)], None)
        .save(&file)
        .context("writing the survey's robot_world.json")?;
    let old = s.cell.geometry.as_ref().map(|g| g.tracker_pose.clone());
    let (_, g) = stated(dir, s)?;
    let (moved, turned) = old
        .as_ref()
        .map(|o| {
            let o = plan::frame_iso(o);
            (
                (o.translation.vector - fit.y.translation.vector).norm(),
                o.rotation.angle_to(&fit.y.rotation).to_degrees(),
            )
        })
        .unzip();
    let summary = SurveySummary {
        probes,
        seen: obs.len(),
        tracker_stated: old,
        tracker_surveyed: iso_frame(&fit.y),
        tracker_moved_mm: moved,
        tracker_turned_deg: turned,
        marker_stated: s.cell.marker_on_flange.clone(),
        marker_surveyed: iso_frame(&fit.x),
        rms_pos_mm: fit.rms_pos_mm,
        rms_rot_deg: fit.rms_rot_deg,
        file: rel(dir, &file),
    };
    log(&format!("  {}", words(&summary)));
    // The planner uses the surveyed pose (known to a few mm: the margins of an exact pose).
    s.cell.geometry = Some(CellGeometry {
        tracker_pose: summary.tracker_surveyed.clone(),
        margin_mm: 25.0,
        margin_deg: 3.0,
        ..g
    });
    s.cell.marker_on_flange = Some(summary.marker_surveyed.clone());
    s.survey = Some(summary);
    s.save(&dir.join("session.json"))
}

/// The survey in one sentence.
pub fn words(v: &SurveySummary) -> String {
    let t = &v.tracker_surveyed;
    let moved = match (v.tracker_moved_mm, v.tracker_turned_deg) {
        (Some(m), Some(a)) => format!(" ({m:.0} mm and {a:.1}° from the cell file's)"),
        _ => String::new(),
    };
    format!(
        "survey: the tracker saw the marker at {} of {} probe poses; it stands at \
         ({:.0}, {:.0}, {:.0}) mm, rpy ({:.1}, {:.1}, {:.1})°{moved}; marker on the flange at \
         ({:.1}, {:.1}, {:.1}) mm; fit RMS {:.2} mm / {:.2}° (nominal arm)",
        v.seen,
        v.probes,
        t.xyz[0],
        t.xyz[1],
        t.xyz[2],
        t.rpy[0],
        t.rpy[1],
        t.rpy[2],
        v.marker_surveyed.xyz[0],
        v.marker_surveyed.xyz[1],
        v.marker_surveyed.xyz[2],
        v.rms_pos_mm,
        v.rms_rot_deg
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn iso_frame_inverts_frame_iso() {
        let f = FrameSpec {
            xyz: [1700.0, 80.0, 650.0],
            rpy: [170.0, -70.0, 12.0],
        };
        let back = iso_frame(&plan::frame_iso(&f));
        let d = plan::frame_iso(&back).inverse() * plan::frame_iso(&f);
        assert!(d.translation.vector.norm() < 1e-9);
        assert!(d.rotation.angle() < 1e-9);
    }
}
