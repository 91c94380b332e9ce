//! What keeps a run safe before anything moves: the safety limits the arm is wrapped in (joint
//! limits, speed caps, the plan's table plane and envelope) and the consent to move real
//! hardware ([`LiveConsent`], made only by [`confirm_live`]).
use std::sync::Arc;

use anyhow::{bail, Context as _};
use robocal_drivers::safety::{ArmGeometry, SafetyLimits};

use crate::acquire::MoveSpeedOpt;
use crate::model::KinematicModel;
use crate::plan::PlanFile;

/// Safety limits of the plan's robot: its joint limits and the run's speed caps.
/// The safety limits of a run: the robot's joint limits, the speed caps, and — from the plan's
/// own constraints — the table plane and the Cartesian envelope, checked along every
/// joint-interpolated move at the flange and the tool point (the planner checks the same).
pub fn safety_limits(
    plan: &PlanFile,
    speed: MoveSpeedOpt,
) -> anyhow::Result<(SafetyLimits, Option<Arc<dyn ArmGeometry>>)> {
    let model = KinematicModel::from_robot_block(&plan.robot).context("the plan's robot")?;
    let (lower, upper) = model.joint_limits().into_iter().unzip();
    // The table and envelope come from the plan's spec (`spec.constraints`): limits that do
    // not read are an error, never a run with fewer checks. A plan without a spec or without
    // constraints (made by hand) runs with the joint limits and speed caps only, and says so.
    let constraints: crate::plan::spec::ConstraintSpec = match &plan.spec {
        serde_json::Value::Null => Default::default(),
        serde_json::Value::Object(m) => match m.get("constraints") {
            None => Default::default(),
            Some(c) => serde_json::from_value(c.clone()).map_err(|e| {
                anyhow::anyhow!(
                    "the plan's safety limits (`spec.constraints`: table plane, envelope) do \
                     not read: {e}; refusing to run without them (fix them or re-make the plan \
                     with `robocal plan`)"
                )
            })?,
        },
        other => bail!(
            "the plan's `spec` is {other}, not an object: its safety limits (table plane, \
             envelope) cannot be read; refusing to run without them"
        ),
    };
    if let Some(sp) = plan.spec.as_object().filter(|m| !m.is_empty()) {
        // A spec that is there must read whole: a typo elsewhere may hide a wrong limit.
        serde_json::from_value::<crate::plan::PlanSpec>(serde_json::Value::Object(sp.clone()))
            .map_err(|e| {
                anyhow::anyhow!(
                    "the plan's `spec` (which holds its safety limits: table plane, envelope) \
                     does not read: {e}; refusing to run without them (re-make the plan with \
                     `robocal plan`)"
                )
            })?;
    }
    if constraints.envelope.is_none() && constraints.table_z_mm.is_none() {
        eprintln!(
            "note: the plan sets no table plane or envelope: only the joint limits and speed \
             caps are checked"
        );
    }
    let (envelope, table) = (
        constraints.envelope.clone(),
        crate::plan::constraints::table_plane(&constraints),
    );
    let geometry: Option<Arc<dyn ArmGeometry>> = match (&envelope, &table) {
        (None, None) => None,
        _ => {
            let tool = plan
                .tool
                .to_iso()
                .unwrap_or_else(nalgebra::Isometry3::identity);
            let m = model.clone();
            Some(Arc::new(move |q: &[f64]| {
                let fl = m.flange_pose(q);
                vec![
                    nalgebra::Point3::from(fl.translation.vector),
                    nalgebra::Point3::from((fl * tool).translation.vector),
                ]
            }))
        }
    };
    Ok((
        SafetyLimits {
            joint_lower: lower,
            joint_upper: upper,
            max_vel: speed.max_vel,
            max_acc: speed.max_acc,
            envelope,
            table,
            path_step: 1f64.to_radians(),
        },
        geometry,
    ))
}

/// Proof that this invocation may move real hardware: it has `--live` and the user
/// confirmed (or gave `--yes`). Only [`confirm_live`] makes one; opening a live cell
/// ([`super::live::live_cell`]) needs it.
#[derive(Debug)]
pub struct LiveConsent(());

/// Asks for consent to move real hardware: `live` (`--live`) must be on this invocation, then
/// the user types `yes` (or `yes` = `--yes` was given). Fails without opening anything: stdin
/// not a terminal and no `--yes`, or any other answer.
pub fn confirm_live(live: bool, yes: bool, what: &str) -> anyhow::Result<LiveConsent> {
    if !live {
        bail!(
            "nothing moves without --live: add --live (and --yes, or confirm at the prompt) to \
             drive the hardware"
        );
    }
    // The question goes to stderr: stdout carries the run's (or session's) result.
    eprintln!("{what}");
    ask_yes(
        yes,
        "move the arm",
        "re-run with --yes to move the hardware",
        "nothing moved",
    )?;
    Ok(LiveConsent(()))
}

/// The operator's typed `yes` on the terminal (the one confirmation prompt of every command
/// that moves or releases an arm): `yes` (`--yes` given) skips the question; stdin not a
/// terminal fails with "confirmation needed: {needed}"; the prompt is "type `yes` to
/// {action}: " on stderr; any other answer fails with "not confirmed: {refused}".
pub fn ask_yes(yes: bool, action: &str, needed: &str, refused: &str) -> anyhow::Result<()> {
    if yes {
        return Ok(());
    }
    use std::io::{BufRead as _, IsTerminal as _, Write as _};
    if !std::io::stdin().is_terminal() {
        bail!("confirmation needed: {needed}");
    }
    eprint!("type `yes` to {action}: ");
    std::io::stderr().flush().ok();
    let mut answer = String::new();
    std::io::stdin().lock().read_line(&mut answer)?;
    if answer.trim() != "yes" {
        bail!("not confirmed: {refused}");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use robocal_drivers::safety::guard;
    use serde_json::json;
    use std::path::Path;

    /// The run's safety wrapper carries the plan's table and envelope: a move that swings the
    /// flange below the table is refused before it reaches the arm.
    #[test]
    fn run_guard_enforces_the_plans_table_and_envelope() {
        let spec_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("plans/seed001-annulus.toml");
        let mut spec =
            crate::plan::PlanSpec::from_toml_str(&crate::fsio::read_to_string(spec_path).unwrap())
                .unwrap();
        if let Some(a) = spec.annulus.as_mut() {
            a.points = 5;
        }
        let model = KinematicModel::preset("denso-vs060").unwrap();
        let robot = crate::dataset::RobotBlock::named("denso-vs060");
        let plan = crate::plan::build_plan(&spec, robot, &model, &Default::default())
            .unwrap()
            .file;
        let (limits, geometry) = safety_limits(
            &plan,
            MoveSpeedOpt {
                max_vel: 1.0,
                max_acc: 2.0,
            },
        )
        .unwrap();
        assert!(limits.table.is_some() && limits.envelope.is_some());
        let geometry = geometry.expect("a geometry for the path check");
        // Upright (flange high above the table) to folded down over the table edge.
        let up = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let down = [0.0, 100f64.to_radians(), 100f64.to_radians(), 0.0, 0.0, 0.0];
        assert!(model.flange_pose(&down).translation.z < 0.0);
        let fake = robocal_drivers::fake::FakeArm::new(up.to_vec());
        let arm = guard(Arc::new(fake.clone()), limits, Some(geometry));
        let rt = tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap();
        let err = rt
            .block_on(arm.move_joints(&down, robocal_drivers::MoveSpeed::default()))
            .unwrap_err();
        assert_eq!(err.kind(), robocal_drivers::ErrorKind::SafetyViolation);
        assert!(fake.commands().is_empty());
        // Limits that do not read are an error, never a run without them.
        let speed = MoveSpeedOpt {
            max_vel: 1.0,
            max_acc: 2.0,
        };
        let mut bad = plan.clone();
        bad.spec["constraints"]["envelope"] = json!({"shape": "sphere", "r": 5});
        let e = safety_limits(&bad, speed)
            .err()
            .expect("refused")
            .to_string();
        assert!(e.contains("safety limits"), "{e}");
        let mut bad = plan.clone();
        bad.spec["constraints"]["table_z_mm"] = json!("low");
        assert!(safety_limits(&bad, speed).is_err());
        let mut bad = plan.clone();
        bad.spec["typo"] = json!(1);
        assert!(safety_limits(&bad, speed).is_err());
        let mut bad = plan.clone();
        bad.spec = json!([1, 2]);
        assert!(safety_limits(&bad, speed).is_err());
        // A hand-made plan without a spec has joint limits and speed caps only.
        let mut bare = plan.clone();
        bare.spec = json!({});
        let (l, g) = safety_limits(&bare, speed).unwrap();
        assert!(l.table.is_none() && l.envelope.is_none() && g.is_none());
    }
}
