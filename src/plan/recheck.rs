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
use super::spec::{ConstraintSpec, PlanSpec};
use super::PlanError;
use crate::model::KinematicModel;

/// What the cell (scenario or device file) says about its robot.
#[derive(Debug, Clone, Default)]
pub struct CellRobot {
    /// Where this comes from (`scenario lab.toml, arm "vs060"`), for messages.
    pub source: String,
    /// The arm's model name (a preset name such as `denso-vs060`) when known.
    pub model: Option<String>,
    /// The cell's own safety limits (table plane, envelope) when it states them.
    pub safety: Option<CellSafety>,
}

/// A cell's safety limits (robot base frame, mm): a plan may be stricter, never wider.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CellSafety {
    /// Table height (mm) and least clearance above it (mm).
    pub table_z_mm: Option<f64>,
    pub table_clearance_mm: f64,
    /// Envelope every arm check point stays in.
    pub envelope: Option<robocal_drivers::safety::Envelope>,
    /// Per joint `[lower, upper]` (deg) when the cell states them (a device file's
    /// `[safety]`): every pose of a plan stays inside.
    pub joint_limits_deg: Option<Vec<[f64; 2]>>,
}

/// Whether envelope `a` lies inside envelope `b` (both convex: their extreme points decide).
pub(crate) fn envelope_within(
    a: &robocal_drivers::safety::Envelope,
    b: &robocal_drivers::safety::Envelope,
) -> bool {
    use robocal_drivers::safety::Envelope as E;
    let tol = 1e-6;
    match (a, b) {
        (
            E::Cylinder {
                center_xy: ca,
                radius: ra,
                z_min: za,
                z_max: zb,
            },
            E::Cylinder {
                center_xy: cb,
                radius: rb,
                z_min: zc,
                z_max: zd,
            },
        ) => {
            let d = ((ca[0] - cb[0]).powi(2) + (ca[1] - cb[1]).powi(2)).sqrt();
            d + ra <= rb + tol && za >= &(zc - tol) && zb <= &(zd + tol)
        }
        _ => {
            // A box's corners; a cylinder inside a box iff its bounding box is.
            let (lo, hi) = match a {
                E::Box { min, max } => (*min, *max),
                E::Cylinder {
                    center_xy,
                    radius,
                    z_min,
                    z_max,
                } => (
                    [center_xy[0] - radius, center_xy[1] - radius, *z_min],
                    [center_xy[0] + radius, center_xy[1] + radius, *z_max],
                ),
            };
            let inside = |p: [f64; 3]| match b {
                E::Box { min, max } => (0..3).all(|i| p[i] >= min[i] - tol && p[i] <= max[i] + tol),
                E::Cylinder { .. } => b.contains(&nalgebra::Point3::from(p)),
            };
            (0..8).all(|k| {
                inside([
                    if k & 1 == 0 { lo[0] } else { hi[0] },
                    if k & 2 == 0 { lo[1] } else { hi[1] },
                    if k & 4 == 0 { lo[2] } else { hi[2] },
                ])
            })
        }
    }
}

/// Checks that the plan's constraints are no wider than the cell's: a plan
/// file is editable, the cell is not. Names the limit and where the cell states it.
pub fn within_cell(c: &ConstraintSpec, cell: &CellSafety, source: &str) -> Result<(), PlanError> {
    if let Some(tz) = cell.table_z_mm {
        let floor = tz + cell.table_clearance_mm;
        let plan_floor = c.table_z_mm.map(|z| z + c.table_clearance_mm);
        if plan_floor.is_none_or(|f| f < floor - 1e-6) {
            return Err(bad(format!(
                "field \"spec.constraints.table_z_mm\": the plan allows the arm down to {} but \
                 the cell's table is at z = {tz} mm with {} mm clearance ({source}): a plan may be \
                 stricter than the cell, never wider (an edited plan; re-plan)",
                plan_floor.map_or("any height (no table)".into(), |f| format!(
                    "z = {f} mm (table_z_mm + table_clearance_mm)"
                )),
                cell.table_clearance_mm
            )));
        }
    }
    if let Some(ce) = &cell.envelope {
        let ok = c
            .envelope
            .as_ref()
            .is_some_and(|pe| envelope_within(pe, ce));
        if !ok {
            return Err(bad(format!(
                "field \"spec.constraints.envelope\": {} is not inside the cell's envelope \
                 {ce:?} ({source}): a plan may be stricter than the cell, never wider (an edited \
                 plan; re-plan)",
                c.envelope
                    .as_ref()
                    .map_or("no envelope".into(), |e| format!("{e:?}"))
            )));
        }
    }
    Ok(())
}

/// Checks every pose of `plan` against the cell's joint limits (a device file's `[safety]`
/// `joint_limits_deg`), naming the pose, the joint and the limit.
pub fn poses_within_cell_joints(
    plan: &PlanFile,
    cell: &CellSafety,
    source: &str,
) -> Result<(), PlanError> {
    let Some(lims) = &cell.joint_limits_deg else {
        return Ok(());
    };
    for p in &plan.poses {
        for (k, (q, [lo, hi])) in p.q_deg.iter().zip(lims).enumerate() {
            if *q < lo - 1e-9 || *q > hi + 1e-9 {
                return Err(bad(format!(
                    "pose {} ({}): joint {} at {q:.2}° is outside the cell's joint limit [{lo}, \
                     {hi}]° (`joint_limits_deg` of {source}): a plan may be stricter than the \
                     cell, never wider (re-plan on this cell)",
                    p.id,
                    p.label,
                    k + 1
                )));
            }
        }
    }
    Ok(())
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
    // `"spec": {}` (a hand-written plan) states no constraints: joint limits only (checked
    // by `validate` and below). Any other spec must parse and validate.
    let no_spec = plan.spec.as_object().is_some_and(|o| o.is_empty());
    let spec = if no_spec {
        None
    } else {
        Some(plan_spec(plan)?)
    };
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
    let constraints = spec
        .map(|s| s.constraints)
        .unwrap_or_else(|| ConstraintSpec {
            self_collision: false,
            ..ConstraintSpec::default()
        });
    if let Some((safety, source)) = cell.and_then(|c| c.safety.as_ref().map(|s| (s, &c.source))) {
        within_cell(&constraints, safety, source)?;
        poses_within_cell_joints(plan, safety, source)?;
    }
    for p in &plan.poses {
        let q: Vec<f64> = p.q_deg.iter().map(|x| x.to_radians()).collect();
        if let Some(r) = constraints::arm_check(&constraints, &model, &q, &tool) {
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

#[cfg(test)]
mod tests {
    use super::*;
    use robocal_drivers::safety::Envelope;

    #[test]
    fn a_plan_may_be_stricter_than_the_cell_never_wider() {
        let cyl = |r: f64, z0: f64| Envelope::Cylinder {
            center_xy: [0.0, 0.0],
            radius: r,
            z_min: z0,
            z_max: 1100.0,
        };
        let cell = CellSafety {
            table_z_mm: Some(0.0),
            table_clearance_mm: 50.0,
            envelope: Some(cyl(900.0, 0.0)),
            joint_limits_deg: None,
        };
        let plan = |z: Option<f64>, clear: f64, env: Option<Envelope>| ConstraintSpec {
            table_z_mm: z,
            table_clearance_mm: clear,
            envelope: env,
            ..ConstraintSpec::default()
        };
        // Equal and stricter pass.
        within_cell(&plan(Some(0.0), 50.0, Some(cyl(900.0, 0.0))), &cell, "c").unwrap();
        within_cell(&plan(Some(100.0), 50.0, Some(cyl(500.0, 10.0))), &cell, "c").unwrap();
        let b = Envelope::Box {
            min: [-500.0, -500.0, 0.0],
            max: [500.0, 500.0, 900.0],
        };
        within_cell(&plan(Some(0.0), 60.0, Some(b)), &cell, "c").unwrap();
        // Wider: lower table, less clearance, no table, no / larger / offset envelope.
        for p in [
            plan(Some(-1000.0), 50.0, Some(cyl(900.0, 0.0))),
            plan(Some(0.0), 0.0, Some(cyl(900.0, 0.0))),
            plan(None, 50.0, Some(cyl(900.0, 0.0))),
            plan(Some(0.0), 50.0, None),
            plan(Some(0.0), 50.0, Some(cyl(901.0, 0.0))),
            plan(Some(0.0), 50.0, Some(cyl(900.0, -10.0))),
            plan(
                Some(0.0),
                50.0,
                Some(Envelope::Box {
                    min: [-700.0, -700.0, 0.0],
                    max: [700.0, 700.0, 900.0],
                }),
            ),
        ] {
            let e = within_cell(&p, &cell, "lab.toml").unwrap_err().to_string();
            assert!(e.contains("never wider") && e.contains("lab.toml"), "{e}");
        }
    }
}
