//! Re-check of a plan file against its safety constraints and the cell's own limits.
//!
//! A plan file is a user-editable JSON file: its poses, its robot block (joint limits) and
//! its spec (table plane, envelope) can all be changed after `robocal plan` wrote it.
//! [`recheck`] therefore trusts nothing the planner decided: the spec must parse and
//! validate, the robot must be the cell's robot and its joint limits may not be wider than
//! the built-in preset's, and every pose is checked again against the joint limits (with the
//! spec's margin), the table plane, the envelope and self-collision — the checks the
//! planner applied, with the same code (`constraints::arm_check`).
use super::constraints;
use super::file::PlanFile;
use super::spec::PlanSpec;
use super::PlanError;
use crate::model::KinematicModel;

/// What the cell (scenario or device file) says about its robot.
#[derive(Debug, Clone, Default)]
pub struct CellRobot {
    /// Where this comes from (`scenario lab.toml, arm "vs060"`), for messages.
    pub source: String,
    /// The arm's model name (a preset name such as `denso-vs060`) when known.
    pub model: Option<String>,
}

fn bad(message: String) -> PlanError {
    PlanError::PlanFile { message }
}

/// The plan's spec, parsed and validated; an error when it cannot be read (a plan whose
/// safety limits cannot be read is never run with fewer checks).
pub fn plan_spec(plan: &PlanFile) -> Result<PlanSpec, PlanError> {
    let spec: PlanSpec = serde_json::from_value(plan.spec.clone()).map_err(|e| {
        bad(format!(
            "field \"spec\": the plan's constraints (table, envelope, timing) cannot be read: {e}"
        ))
    })?;
    spec.validate()
        .map_err(|e| bad(format!("field \"spec\": {e}")))?;
    Ok(spec)
}

/// Re-checks every pose of `plan` (see the module docs). `cell` adds the cell's robot.
/// Returns the number of poses checked.
pub fn recheck(plan: &PlanFile, cell: Option<&CellRobot>) -> Result<usize, PlanError> {
    plan.validate()?;
    let spec = plan_spec(plan)?;
    let model = KinematicModel::from_robot_block(&plan.robot)
        .map_err(|e| bad(format!("field \"robot\": {e}")))?;
    if let Some(c) = cell {
        if let Some(m) = &c.model {
            if m.trim() != plan.robot.model.trim() {
                return Err(bad(format!(
                    "field \"robot.model\": the plan is for robot model \"{}\" but the cell's arm \
                     ({}) is a \"{m}\": a plan made for another robot",
                    plan.robot.model, c.source
                )));
            }
        }
    }
    // Joint limits may not be wider than the preset's (the robot's own limits).
    if let Ok(preset) = KinematicModel::preset(&plan.robot.model) {
        let pl = preset.joint_limits();
        let fl = model.joint_limits();
        if pl.len() == fl.len() {
            for (k, (&(plo, phi), &(flo, fhi))) in pl.iter().zip(&fl).enumerate() {
                let tol = 1e-6;
                if flo < plo - tol || fhi > phi + tol {
                    return Err(bad(format!(
                        "field \"robot.chain[{k}].limits\": [{:.1}°, {:.1}°] is wider than the \
                         {} preset's limits [{:.1}°, {:.1}°] for joint {}: edited joint limits",
                        flo.to_degrees(),
                        fhi.to_degrees(),
                        plan.robot.model,
                        plo.to_degrees(),
                        phi.to_degrees(),
                        k + 1
                    )));
                }
            }
        }
    }
    let tool = plan
        .tool
        .to_iso()
        .ok_or_else(|| bad("field \"tool\": not finite / not a unit quaternion".into()))?;
    for p in &plan.poses {
        let q: Vec<f64> = p.q_deg.iter().map(|x| x.to_radians()).collect();
        if let Some(r) = constraints::arm_check(&spec.constraints, &model, &q, &tool) {
            return Err(bad(format!(
                "pose {} ({}): {r} (constraint `{}` of the plan's spec); the file was edited \
                 after planning or its constraints changed: re-plan",
                p.id,
                p.label,
                r.key()
            )));
        }
    }
    Ok(plan.poses.len())
}
