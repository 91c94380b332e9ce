//! The `[safety]` block of a device file: what the real cell is, whatever a plan file says
//! (a plan cannot widen it). The table height, the Cartesian envelope, the joint limits and
//! the speed / acceleration caps of the cell, in the robot base frame (mm, degrees, seconds).
//!
//! ```toml
//! [safety]
//! table_z_mm = 0.0                 # the table top in the robot base (mm)
//! table_clearance_mm = 50.0        # least clearance of every arm point above it (mm)
//! envelope = { shape = "box", min = [-900.0, -900.0, 0.0], max = [900.0, 900.0, 1200.0] }
//! # envelope = { shape = "cylinder", center_xy = [0.0, 0.0], radius = 900.0, z_min = 0.0, z_max = 1100.0 }
//! joint_limits_deg = [[-170, 170], [-120, 125], [-125, 155], [-270, 270], [-120, 120], [-360, 360]]
//! max_speed_deg_s = 60.0           # joint speed cap (deg/s)
//! max_accel_deg_s2 = 120.0         # joint acceleration cap (deg/s²)
//! ```
//!
//! Every value is checked when the file is read (finite, in mm / degrees, ordered, joint limits
//! inside the arm preset's own: a device file may be stricter than the robot, never wider).
//! `run --live`, `session --live` and `devices --probe` read it: a plan whose constraints or
//! poses are wider than the block is refused naming the limit ([`crate::plan::recheck`]), the
//! session plans inside it, and the safety wrapper around the arm uses its joint limits.
use serde::{Deserialize, Serialize};

use robocal_drivers::safety::Envelope;

/// The `[safety]` block.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SafetyEntry {
    /// The table top in the robot base (mm): no arm point below it (plus the clearance).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub table_z_mm: Option<f64>,
    /// Least clearance above the table (mm); default 0 when a table is given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub table_clearance_mm: Option<f64>,
    /// The box (or vertical cylinder) every arm point stays in (robot base, mm).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub envelope: Option<Envelope>,
    /// Per joint `[lower, upper]` (deg), one pair per joint of the arm's preset.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub joint_limits_deg: Option<Vec<[f64; 2]>>,
    /// Joint speed cap (deg/s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_speed_deg_s: Option<f64>,
    /// Joint acceleration cap (deg/s²).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_accel_deg_s2: Option<f64>,
}

/// Largest |coordinate| of a table or envelope (mm): 10 m.
const MAX_MM: f64 = 1.0e4;
/// Fastest joint speed a cap may state (deg/s): above every preset arm's hardware.
const MAX_SPEED_DEG_S: f64 = 720.0;
/// Largest acceleration a cap may state (deg/s²).
const MAX_ACCEL_DEG_S2: f64 = 1.0e4;

impl SafetyEntry {
    /// Checks the block: units, finite, ordered, and (when the arm's `model` is a preset)
    /// joint limits inside the preset's. `Err` is the message (the caller names the file).
    pub fn validate(&self, arm_model: Option<&str>) -> Result<(), String> {
        if let Some(z) = self.table_z_mm {
            if !z.is_finite() || z.abs() > MAX_MM {
                return Err(format!(
                    "table_z_mm = {z}: the table top's height in the robot base, millimetres, \
                     |z| ≤ {MAX_MM}"
                ));
            }
        }
        if let Some(c) = self.table_clearance_mm {
            if self.table_z_mm.is_none() {
                return Err(
                    "table_clearance_mm without table_z_mm: give the table's height".into(),
                );
            }
            if !c.is_finite() || !(0.0..=1000.0).contains(&c) {
                return Err(format!(
                    "table_clearance_mm = {c}: millimetres above the table, 0 – 1000"
                ));
            }
        }
        if let Some(e) = &self.envelope {
            check_envelope(e)?;
            if let Some(floor) = self.floor_mm() {
                let top = match e {
                    Envelope::Box { max, .. } => max[2],
                    Envelope::Cylinder { z_max, .. } => *z_max,
                };
                if top <= floor {
                    return Err(format!(
                        "envelope: its top z = {top} mm is not above the table's z = {floor} mm \
                         (table_z_mm + table_clearance_mm): nothing could move"
                    ));
                }
            }
        }
        for (f, v, max, unit) in [
            (
                "max_speed_deg_s",
                self.max_speed_deg_s,
                MAX_SPEED_DEG_S,
                "deg/s",
            ),
            (
                "max_accel_deg_s2",
                self.max_accel_deg_s2,
                MAX_ACCEL_DEG_S2,
                "deg/s²",
            ),
        ] {
            if let Some(v) = v {
                if !(v.is_finite() && v > 0.0 && v <= max) {
                    return Err(format!(
                        "{f} = {v}: a cap in {unit}, finite, > 0 and ≤ {max} (the arms' \
                         hardware; rad typed?)"
                    ));
                }
            }
        }
        if let Some(lims) = &self.joint_limits_deg {
            self.check_joints(lims, arm_model)?;
        }
        Ok(())
    }

    fn check_joints(&self, lims: &[[f64; 2]], arm_model: Option<&str>) -> Result<(), String> {
        for (k, [lo, hi]) in lims.iter().enumerate() {
            if !lo.is_finite() || !hi.is_finite() || lo.abs() > 720.0 || hi.abs() > 720.0 {
                return Err(format!(
                    "joint_limits_deg[{k}] = [{lo}, {hi}]: degrees, finite, |v| ≤ 720 (joint {})",
                    k + 1
                ));
            }
            if lo >= hi {
                return Err(format!(
                    "joint_limits_deg[{k}] = [{lo}, {hi}]: lower must be below upper (joint {})",
                    k + 1
                ));
            }
        }
        let Some(model) = arm_model else {
            return Err(
                "joint_limits_deg needs the arm's `model` (a robot preset: denso-vs060, ur5e, \
                 ur10e) to check them against the robot's own limits"
                    .into(),
            );
        };
        let preset = crate::model::KinematicModel::preset(model.trim()).map_err(|_| {
            format!(
                "joint_limits_deg: the arm's model {model:?} is not a robot preset (denso-vs060, \
                 ur5e, ur10e): its own limits are unknown"
            )
        })?;
        let pl = preset.joint_limits();
        if pl.len() != lims.len() {
            return Err(format!(
                "joint_limits_deg has {} pairs but the {model} has {} joints",
                lims.len(),
                pl.len()
            ));
        }
        for (k, (&(plo, phi), [lo, hi])) in pl.iter().zip(lims).enumerate() {
            let (plo, phi) = (plo.to_degrees(), phi.to_degrees());
            if *lo < plo - 1e-6 || *hi > phi + 1e-6 {
                return Err(format!(
                    "joint_limits_deg[{k}] = [{lo}, {hi}] is wider than the {model}'s own limit \
                     [{plo:.1}, {phi:.1}] deg for joint {}: a device file may be stricter than \
                     the robot, never wider",
                    k + 1
                ));
            }
        }
        Ok(())
    }

    /// The lowest height an arm point may reach: table + clearance (mm).
    pub fn floor_mm(&self) -> Option<f64> {
        self.table_z_mm
            .map(|z| z + self.table_clearance_mm.unwrap_or(0.0))
    }

    /// The block as the plan re-check's cell limits.
    pub fn cell_safety(&self) -> crate::plan::recheck::CellSafety {
        crate::plan::recheck::CellSafety {
            table_z_mm: self.table_z_mm,
            table_clearance_mm: self.table_clearance_mm.unwrap_or(0.0),
            envelope: self.envelope.clone(),
            joint_limits_deg: self.joint_limits_deg.clone(),
        }
    }

    /// One line for listings: `table z = 0 mm (+50 clearance), envelope box …`.
    pub fn summary(&self) -> String {
        let mut parts = Vec::new();
        if let Some(z) = self.table_z_mm {
            parts.push(format!(
                "table z = {z} mm (+{} mm clearance)",
                self.table_clearance_mm.unwrap_or(0.0)
            ));
        }
        match &self.envelope {
            Some(Envelope::Box { min, max }) => parts.push(format!(
                "envelope box x {}…{}, y {}…{}, z {}…{} mm",
                min[0], max[0], min[1], max[1], min[2], max[2]
            )),
            Some(Envelope::Cylinder {
                center_xy,
                radius,
                z_min,
                z_max,
            }) => parts.push(format!(
                "envelope cylinder r {radius} mm about ({}, {}), z {z_min}…{z_max} mm",
                center_xy[0], center_xy[1]
            )),
            None => {}
        }
        if let Some(l) = &self.joint_limits_deg {
            let v: Vec<String> = l.iter().map(|[a, b]| format!("[{a}, {b}]")).collect();
            parts.push(format!("joint limits {} deg", v.join(" ")));
        }
        if let Some(v) = self.max_speed_deg_s {
            parts.push(format!("speed cap {v} deg/s"));
        }
        if let Some(v) = self.max_accel_deg_s2 {
            parts.push(format!("acceleration cap {v} deg/s²"));
        }
        if parts.is_empty() {
            "nothing stated".into()
        } else {
            parts.join("; ")
        }
    }
}

/// Checks where the arm is now (`q`, rad, as `devices --probe` reads it) against the block:
/// each joint inside `joint_limits_deg`, and, for a preset `arm_model`, the flange above the
/// table + clearance and inside the envelope (the flange only: the plan re-check tests every
/// link point of a planned pose). `Err` names each joint or point outside and what to do.
pub fn check_current_joints(
    block: &SafetyEntry,
    arm_model: Option<&str>,
    q: &[f64],
) -> Result<(), String> {
    let mut out = Vec::new();
    if let Some(lims) = &block.joint_limits_deg {
        if lims.len() != q.len() {
            out.push(format!(
                "the arm reports {} joints, joint_limits_deg has {} pairs",
                q.len(),
                lims.len()
            ));
        }
        for (k, (x, [lo, hi])) in q.iter().zip(lims).enumerate() {
            let d = x.to_degrees();
            if !(d >= lo - 1e-6 && d <= hi + 1e-6) {
                out.push(format!(
                    "joint {} at {d:.2}° is outside joint_limits_deg [{lo}, {hi}]",
                    k + 1
                ));
            }
        }
    }
    let model = arm_model.and_then(|m| crate::model::KinematicModel::preset(m).ok());
    if let Some(m) = model.filter(|m| m.dof() == q.len()) {
        let p = m.flange_pose(q).translation.vector;
        let at = format!("({:.1}, {:.1}, {:.1}) mm", p.x, p.y, p.z);
        if let Some(floor) = block.floor_mm() {
            if p.z < floor {
                out.push(format!(
                    "the flange at {at} is below the table + clearance (z = {floor} mm)"
                ));
            }
        }
        if let Some(e) = &block.envelope {
            if !e.contains(&nalgebra::Point3::from(p)) {
                out.push(format!("the flange at {at} is outside the envelope"));
            }
        }
    }
    if out.is_empty() {
        Ok(())
    } else {
        Err(format!(
            "the arm is outside the cell's [safety] now: {}; bring it inside (teach pendant or \
             hand guiding) before a session moves it",
            out.join("; ")
        ))
    }
}

/// Narrows the safety wrapper's joint limits to the cell's (`joint_limits_deg`), when stated.
pub fn narrow_joint_limits(
    limits: &mut robocal_drivers::safety::SafetyLimits,
    cell: Option<&crate::plan::recheck::CellSafety>,
) {
    let Some(lims) = cell.and_then(|c| c.joint_limits_deg.as_ref()) else {
        return;
    };
    for (k, [lo, hi]) in lims.iter().enumerate() {
        if let (Some(l), Some(u)) = (limits.joint_lower.get_mut(k), limits.joint_upper.get_mut(k)) {
            *l = l.max(lo.to_radians());
            *u = u.min(hi.to_radians());
        }
    }
}

/// Narrows a model's joint limits to the cell's (`joint_limits_deg`), for planning.
pub fn narrow_model(
    model: &mut crate::model::KinematicModel,
    cell: Option<&SafetyEntry>,
) -> anyhow::Result<()> {
    let Some(lims) = cell.and_then(|c| c.joint_limits_deg.as_ref()) else {
        return Ok(());
    };
    let now = model.joint_limits();
    anyhow::ensure!(
        now.len() == lims.len(),
        "the cell's [safety] joint_limits_deg has {} pairs, the robot {} joints",
        lims.len(),
        now.len()
    );
    let narrowed: Vec<(f64, f64)> = now
        .iter()
        .zip(lims)
        .map(|(&(l, u), [lo, hi])| (l.max(lo.to_radians()), u.min(hi.to_radians())))
        .collect();
    model.set_joint_limits(&narrowed)?;
    Ok(())
}

/// Fits a session's plan constraints inside the cell's block: the table raised to the cell's
/// (table + clearance), the envelope replaced by the cell's when the spec's is not inside it.
/// Returns what changed, for the session log.
pub fn fit_constraints(
    c: &mut crate::plan::spec::ConstraintSpec,
    cell: &SafetyEntry,
) -> Vec<String> {
    let mut notes = Vec::new();
    if let (Some(tz), Some(floor)) = (cell.table_z_mm, cell.floor_mm()) {
        let plan_floor = c.table_z_mm.map(|z| z + c.table_clearance_mm);
        if plan_floor.is_none_or(|f| f < floor - 1e-9) {
            c.table_z_mm = Some(tz);
            c.table_clearance_mm = cell.table_clearance_mm.unwrap_or(0.0);
            notes.push(format!(
                "table from the cell's [safety]: z = {tz} mm + {} mm clearance",
                c.table_clearance_mm
            ));
        }
    }
    if let Some(ce) = &cell.envelope {
        let inside = c
            .envelope
            .as_ref()
            .is_some_and(|pe| crate::plan::recheck::envelope_within(pe, ce));
        if !inside {
            c.envelope = Some(ce.clone());
            notes.push("envelope from the cell's [safety] (the spec's is wider)".into());
        }
    }
    if cell.joint_limits_deg.is_some() {
        notes.push("joint limits from the cell's [safety]".into());
    }
    notes
}

/// Checks an envelope: finite, in mm (not metres), ordered.
fn check_envelope(e: &Envelope) -> Result<(), String> {
    let (vals, what): (Vec<f64>, String) = match e {
        Envelope::Box { min, max } => {
            let v: Vec<f64> = min.iter().chain(max).copied().collect();
            (v, format!("box min {min:?} max {max:?}"))
        }
        Envelope::Cylinder {
            center_xy,
            radius,
            z_min,
            z_max,
        } => (
            vec![center_xy[0], center_xy[1], *radius, *z_min, *z_max],
            format!("cylinder r {radius} about {center_xy:?}, z {z_min}…{z_max}"),
        ),
    };
    if vals.iter().any(|v| !v.is_finite() || v.abs() > MAX_MM) {
        return Err(format!(
            "envelope ({what}): millimetres, finite, |v| ≤ {MAX_MM}"
        ));
    }
    match e {
        Envelope::Box { min, max } => {
            for (i, axis) in ["x", "y", "z"].iter().enumerate() {
                if min[i] >= max[i] {
                    return Err(format!(
                        "envelope ({what}): min {axis} = {} is not below max {axis} = {}: the \
                         corners are swapped or equal",
                        min[i], max[i]
                    ));
                }
            }
            let span = (0..3).map(|i| max[i] - min[i]).fold(f64::MAX, f64::min);
            if (0..3).all(|i| max[i] - min[i] < 20.0) {
                return Err(format!(
                    "envelope ({what}): at most {span} mm across: millimetres are expected \
                     (metres typed?)"
                ));
            }
        }
        Envelope::Cylinder {
            radius,
            z_min,
            z_max,
            ..
        } => {
            if *radius <= 0.0 || z_min >= z_max {
                return Err(format!(
                    "envelope ({what}): needs radius > 0 and z_min below z_max"
                ));
            }
            if *radius < 20.0 && z_max - z_min < 20.0 {
                return Err(format!(
                    "envelope ({what}): under 20 mm across: millimetres are expected (metres \
                     typed?)"
                ));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(text: &str) -> SafetyEntry {
        toml::from_str(text).unwrap()
    }

    #[test]
    fn each_refusal_names_the_field() {
        let ok = entry(
            "table_z_mm = 0.0\ntable_clearance_mm = 50.0\nenvelope = { shape = \"box\", min = \
             [-900.0, -900.0, 0.0], max = [900.0, 900.0, 1200.0] }\njoint_limits_deg = [[-160, \
             160], [-120, 120], [-120, 150], [-270, 270], [-120, 120], [-360, 360]]\n\
             max_speed_deg_s = 60.0\nmax_accel_deg_s2 = 120.0\n",
        );
        ok.validate(Some("denso-vs060")).unwrap();
        assert_eq!(ok.floor_mm(), Some(50.0));
        assert!(
            ok.summary().contains("speed cap 60 deg/s"),
            "{}",
            ok.summary()
        );
        let cases: Vec<(SafetyEntry, &str)> = vec![
            (
                SafetyEntry {
                    table_z_mm: Some(f64::NAN),
                    ..ok.clone()
                },
                "table_z_mm",
            ),
            (
                SafetyEntry {
                    table_z_mm: None,
                    ..ok.clone()
                },
                "table_clearance_mm without table_z_mm",
            ),
            (
                SafetyEntry {
                    envelope: Some(Envelope::Box {
                        min: [900.0, -900.0, 0.0],
                        max: [-900.0, 900.0, 1200.0],
                    }),
                    ..ok.clone()
                },
                "min x = 900 is not below max x = -900",
            ),
            (
                SafetyEntry {
                    envelope: Some(Envelope::Box {
                        min: [-0.9, -0.9, 0.0],
                        max: [0.9, 0.9, 1.2],
                    }),
                    table_z_mm: Some(0.0),
                    table_clearance_mm: Some(0.0),
                    ..ok.clone()
                },
                "metres typed?",
            ),
            (
                SafetyEntry {
                    envelope: Some(Envelope::Box {
                        min: [-900.0, -900.0, 0.0],
                        max: [900.0, 900.0, 40.0],
                    }),
                    ..ok.clone()
                },
                "not above the table",
            ),
            (
                SafetyEntry {
                    max_speed_deg_s: Some(-1.0),
                    ..ok.clone()
                },
                "max_speed_deg_s = -1",
            ),
            (
                SafetyEntry {
                    max_accel_deg_s2: Some(f64::INFINITY),
                    ..ok.clone()
                },
                "max_accel_deg_s2",
            ),
            (
                SafetyEntry {
                    joint_limits_deg: Some(vec![[10.0, -10.0]; 6]),
                    ..ok.clone()
                },
                "lower must be below upper",
            ),
            (
                SafetyEntry {
                    joint_limits_deg: Some(vec![[-100.0, 100.0]; 5]),
                    ..ok.clone()
                },
                "has 5 pairs but the denso-vs060 has 6 joints",
            ),
            (
                SafetyEntry {
                    joint_limits_deg: Some(vec![[-200.0, 100.0]; 6]),
                    ..ok.clone()
                },
                "wider than the denso-vs060's own limit",
            ),
        ];
        for (e, want) in cases {
            let msg = e.validate(Some("denso-vs060")).unwrap_err();
            assert!(msg.contains(want), "{msg} (want {want})");
        }
        let msg = ok.validate(None).unwrap_err();
        assert!(msg.contains("needs the arm's `model`"), "{msg}");
        let msg = ok.validate(Some("kuka-kr6")).unwrap_err();
        assert!(msg.contains("not a robot preset"), "{msg}");
    }
}
