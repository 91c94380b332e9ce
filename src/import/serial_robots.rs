//! The `serial_robots_datasets` layout (`pauljac7700/serial_robots_datasets`, MIT licence,
//! P. Jacobi, "A Hybrid Error Compensation Method for Enhancing the Pose Accuracy of Serial
//! Industrial Robots", Master's thesis, Tsinghua University, 2025): a UR5 (6 joints) and a
//! Barrett WAM (7 joints) measured by a GTS3800 laser tracker with a 1.5" SMR on the tool.
//!
//! `,`-separated, decimal point. Columns: `step_order` (acquisition index), `x_t,y_t,z_t`
//! (mm: the target = the nominal forward kinematics of the commanded joints with the tool;
//! for the UR5, UR's CB3 DH table reproduces it to 0.012 mm RMS), `x_dif,y_dif,z_dif` (mm:
//! "the difference between the target position and the actual achieved position", in the
//! robot base frame, the tracker already registered to it by the source), then
//! `joint_1 … joint_N` (deg, commanded). No time stamps, no orientation, no temperature.
//!
//! The measured SMR position is `target + dif` or `target − dif` ([`DifSign`]): the README's
//! words do not fix the sign; `docs/findings.md` ("An unseen real robot", round 8) gives the
//! evidence for the default.
use serde_json::{json, Map};

use super::error::ImportError;
use super::table::Table;
use super::{assemble, check_joint_unit, check_positions, header, marker_obs, robot_dof};
use super::{Imported, Row};
use crate::dataset::RobotBlock;

/// Which way the source's `*_dif` columns point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DifSign {
    /// measured = target + dif (dif = actual − target).
    ActualMinusTarget,
    /// measured = target − dif (dif = target − actual).
    TargetMinusActual,
}

impl std::str::FromStr for DifSign {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "actual-minus-target" | "plus" | "+" => Ok(DifSign::ActualMinusTarget),
            "target-minus-actual" | "minus" | "-" => Ok(DifSign::TargetMinusActual),
            o => Err(format!(
                "\"{o}\": expected actual-minus-target (measured = target + dif) or target-minus-actual (measured = target − dif)"
            )),
        }
    }
}

impl DifSign {
    fn label(self) -> &'static str {
        match self {
            DifSign::ActualMinusTarget => "actual-minus-target (measured = target + dif)",
            DifSign::TargetMinusActual => "target-minus-actual (measured = target - dif)",
        }
    }
    fn factor(self) -> f64 {
        match self {
            DifSign::ActualMinusTarget => 1.0,
            DifSign::TargetMinusActual => -1.0,
        }
    }
}

/// Options of `robocal import serial-robots`.
#[derive(Debug, Clone, PartialEq)]
pub struct SerialRobotsOptions {
    /// Every n-th pose (acquisition order) goes to `validation`; 0 = none.
    pub heldout_every: usize,
    /// The robot (its joint count must match the file's `joint_*` columns).
    pub robot: RobotBlock,
    pub dif: DifSign,
}

impl Default for SerialRobotsOptions {
    fn default() -> Self {
        SerialRobotsOptions {
            heldout_every: 4,
            robot: super::robot::ur5(),
            dif: DifSign::ActualMinusTarget,
        }
    }
}

const TARGET: [&str; 3] = ["x_t", "y_t", "z_t"];
const DIF: [&str; 3] = ["x_dif", "y_dif", "z_dif"];

/// Largest |dif| (mm) accepted: the source's worst arm (the WAM) is off by about 18 mm on
/// average; beyond this the columns are not what this layout says.
pub const MAX_DIF_MM: f64 = 200.0;

/// Parse one `serial_robots_datasets` file. `file` names it in errors and in the header's
/// `source`.
pub fn parse_serial_robots(
    text: &str,
    file: &str,
    opts: &SerialRobotsOptions,
) -> Result<Imported, ImportError> {
    let tab = Table::parse(text, file, b',', false)?;
    let dof = robot_dof(&opts.robot)?;
    let c_step = tab.col("step_order")?;
    let c_t: Vec<usize> = TARGET
        .iter()
        .map(|c| tab.col(c))
        .collect::<Result<_, _>>()?;
    let c_d: Vec<usize> = DIF.iter().map(|c| tab.col(c)).collect::<Result<_, _>>()?;
    let n_joints = (1..=16)
        .take_while(|k| tab.has(&format!("joint_{k}")).is_some())
        .count();
    if n_joints == 0 {
        return Err(ImportError::Usage(format!(
            "{file}: no joint columns (expected joint_1…joint_{dof} for robot \"{}\", in degrees)",
            opts.robot.model
        )));
    }
    if n_joints != dof {
        return Err(ImportError::Usage(format!(
            "{file}: the file has {n_joints} joint columns (joint_1…joint_{n_joints}) but robot \"{}\" has {dof} joints (give the matching --robot: ur5 for the UR5 files, a chain JSON for the WAM)",
            opts.robot.model
        )));
    }
    let c_q: Vec<usize> = (1..=dof)
        .map(|k| tab.col(&format!("joint_{k}")))
        .collect::<Result<_, _>>()?;
    let mut rows: Vec<(f64, Row)> = Vec::with_capacity(tab.rows.len());
    let mut q_rows = Vec::with_capacity(tab.rows.len());
    let mut ps = Vec::with_capacity(tab.rows.len());
    let mut targets = Vec::with_capacity(tab.rows.len());
    for i in 0..tab.rows.len() {
        let step = tab.num(i, c_step)?;
        if step < 0.0 || step.fract() != 0.0 {
            return Err(ImportError::bad(
                file,
                Some(tab.line(i)),
                Some("step_order"),
                format!("{step} is not a non-negative whole number (the acquisition index)"),
            ));
        }
        let t = tab.num3(i, &c_t)?;
        let d = tab.num3(i, &c_d)?;
        if let Some(j) = d.iter().position(|v| v.abs() > MAX_DIF_MM) {
            return Err(ImportError::bad(
                file,
                Some(tab.line(i)),
                Some(DIF[j]),
                format!(
                    "{} mm is beyond ±{MAX_DIF_MM} mm: not a positioning error (wrong column or unit?)",
                    d[j]
                ),
            ));
        }
        let q: Vec<f64> = c_q
            .iter()
            .map(|&c| tab.num(i, c))
            .collect::<Result<_, _>>()?;
        let s = opts.dif.factor();
        let p = [t[0] + s * d[0], t[1] + s * d[1], t[2] + s * d[2]];
        let mut extra = Map::new();
        extra.insert("step_order".into(), json!(step as u64));
        extra.insert("target_mm".into(), json!(t));
        q_rows.push(q.clone());
        ps.push(p);
        targets.push(t);
        rows.push((
            step,
            Row {
                line: tab.line(i),
                q_deg: q,
                t: None,
                marker: marker_obs(p, None, None),
                reference: None,
                temp_c: None,
                extra,
            },
        ));
    }
    check_joint_unit(
        &tab,
        &c_q,
        &q_rows,
        true,
        "this layout has joints in degrees; for other files use robocal import csv --joint-unit",
    )?;
    check_positions(
        &tab,
        &c_t,
        &targets,
        true,
        "this layout has mm; for other files use robocal import csv --length-unit",
    )?;
    let mut warnings = Vec::new();
    // Acquisition order = step_order; a repeated step is refused (which row is which pose?).
    if rows.windows(2).any(|w| w[1].0 < w[0].0) {
        warnings.push(format!(
            "{file}: step_order is not increasing: rows are put in step_order (the acquisition order); each record keeps its file line in `src_line`"
        ));
        rows.sort_by(|a, b| a.0.total_cmp(&b.0));
    }
    if let Some(w) = rows.windows(2).find(|w| w[1].0 == w[0].0) {
        return Err(ImportError::bad(
            file,
            Some(w[1].1.line),
            Some("step_order"),
            format!(
                "step {} appears twice (also on line {}): the acquisition order is ambiguous",
                w[1].0, w[0].1.line
            ),
        ));
    }
    let kind = if file.contains("random") {
        "random-poses"
    } else if file.contains("grid") {
        "grid"
    } else {
        "unknown"
    };
    let source = json!({
        "dataset": "serial_robots_datasets (hybrid error compensation, UR5 / Barrett WAM)",
        "repo": "pauljac7700/serial_robots_datasets",
        "license": "MIT (Copyright (c) 2025 Paul Jacobi)",
        "citation": "P. Jacobi: A Hybrid Error Compensation Method for Enhancing the Pose Accuracy of Serial Industrial Robots, Master's thesis, Tsinghua University, 2025",
        "file": file,
        "rows": tab.rows.len(),
        "dif": opts.dif.label(),
        "importer": "robocal import serial-robots",
        "time": "row index in step_order (the source has no time stamps)",
    });
    let notes = format!(
        "Real measurements, serial_robots_datasets (MIT, Jacobi 2025), file {file}: robot {}, GTS3800 laser tracker, 1.5-inch SMR on the tool. q = the source's commanded joints (deg). marker.p = the measured SMR centre = target {} (mm, in the robot base frame: the source registered its tracker to the base before recording; robocal still fits that registration). target_mm = the source's x_t,y_t,z_t (the nominal forward kinematics with the source's tool). step_order, src_line = the source's index and line. No orientation, no temperature, no per-point uncertainty.",
        opts.robot.model,
        match opts.dif {
            DifSign::ActualMinusTarget => "+ dif",
            DifSign::TargetMinusActual => "- dif",
        },
    );
    let mut h = header(opts.robot.clone(), source, notes);
    h.tool = Some(json!({"name": "smr-1.5in"}));
    h.tracker = Some(json!({"kind": "gts3800-laser-tracker"}));
    h.plan = Some(json!({"name": format!("serial-robots-{}", opts.robot.model), "kind": kind}));
    assemble(
        h,
        rows.into_iter().map(|(_, r)| r).collect(),
        opts.heldout_every,
        file,
        warnings,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEAD6: &str =
        "step_order,x_t,y_t,z_t,x_dif,y_dif,z_dif,joint_1,joint_2,joint_3,joint_4,joint_5,joint_6";

    /// `n` rows in the UR5 layout (values shaped like the source's first rows).
    fn ur5_rows(n: usize) -> String {
        let mut s = format!("{HEAD6}\n");
        for i in 0..n {
            let f = i as f64;
            s.push_str(&format!(
                "{i},{},-6.27,-98.63,-2.14,{},0.81,{},-43.71,135.39,-94.74,55.41,-5.55\n",
                -430.3 - f,
                -3.5 + 0.01 * f,
                -22.9 + f
            ));
        }
        s
    }

    fn opts(dif: DifSign) -> SerialRobotsOptions {
        SerialRobotsOptions {
            dif,
            ..SerialRobotsOptions::default()
        }
    }

    #[test]
    fn rows_become_measured_positions_joints_and_groups() {
        let imp = parse_serial_robots(
            &ur5_rows(24),
            "UR5/3D_UR5_uncalibrated_grid_cleaned.csv",
            &opts(DifSign::ActualMinusTarget),
        )
        .unwrap();
        assert_eq!(imp.counts(), (24, 6));
        assert!(!imp.times_real);
        assert!(imp.warnings.iter().any(|w| w.contains("no usable time")));
        let poses: Vec<_> = imp.dataset.poses().collect();
        let p0 = poses[0].marker.as_ref().unwrap().p.unwrap();
        assert!((p0[0] - (-430.3 - 2.14)).abs() < 1e-9, "{p0:?}");
        assert!((p0[1] - (-6.27 - 3.5)).abs() < 1e-9, "{p0:?}");
        assert!((p0[2] - (-98.63 + 0.81)).abs() < 1e-9, "{p0:?}");
        let q3 = poses[3].q.as_ref().unwrap();
        assert_eq!(q3.len(), 6);
        assert!((q3[0] - (-19.9)).abs() < 1e-9 && (q3[2] - 135.39).abs() < 1e-9);
        assert_eq!(poses[3].group.as_deref(), Some("validation"));
        assert_eq!(poses[3].t, 3.0);
        assert_eq!(poses[1].q_prev.as_ref(), poses[0].q.as_ref());
        assert_eq!(poses[2].extra["target_mm"][0].as_f64(), Some(-432.3));
        assert_eq!(imp.dataset.header.robot.model, "ur5");
        let src = &imp.dataset.header.extra["source"];
        assert_eq!(src["repo"], "pauljac7700/serial_robots_datasets");
        assert_eq!(imp.dataset.header.plan.as_ref().unwrap()["kind"], "grid");
    }

    #[test]
    fn the_other_sign_subtracts_the_difference() {
        let imp =
            parse_serial_robots(&ur5_rows(3), "x.csv", &opts(DifSign::TargetMinusActual)).unwrap();
        let first = imp.dataset.poses().next().and_then(|r| r.marker.clone());
        let p0 = first.and_then(|m| m.p).unwrap();
        assert!((p0[0] - (-430.3 + 2.14)).abs() < 1e-9, "{p0:?}");
        assert_eq!(
            "target-minus-actual".parse(),
            Ok(DifSign::TargetMinusActual)
        );
        assert_eq!(
            "actual-minus-target".parse(),
            Ok(DifSign::ActualMinusTarget)
        );
        assert!("sideways"
            .parse::<DifSign>()
            .unwrap_err()
            .contains("sideways"));
    }

    #[test]
    fn step_order_sets_the_acquisition_order() {
        let mut lines: Vec<String> = ur5_rows(3).lines().map(str::to_string).collect();
        lines.swap(1, 3);
        let imp = parse_serial_robots(
            &lines.join("\n"),
            "x.csv",
            &opts(DifSign::ActualMinusTarget),
        )
        .unwrap();
        let steps: Vec<u64> = imp
            .dataset
            .poses()
            .map(|p| p.extra["step_order"].as_u64().unwrap())
            .collect();
        assert_eq!(steps, [0, 1, 2]);
        assert!(imp.warnings.iter().any(|w| w.contains("not increasing")));
        lines[3] = lines[2].clone();
        let e = parse_serial_robots(
            &lines.join("\n"),
            "x.csv",
            &opts(DifSign::ActualMinusTarget),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("step_order") && e.contains("twice"), "{e}");
    }

    #[test]
    fn bad_input_names_file_line_and_column() {
        let o = opts(DifSign::ActualMinusTarget);
        // A 7-joint (WAM) file with the 6-joint default robot.
        let wam = "step_order,x_t,y_t,z_t,x_dif,y_dif,z_dif,joint_1,joint_2,joint_3,joint_4,joint_5,joint_6,joint_7\n0,562.9,-307.5,0.38,8.9,-1.66,4.14,111.0,-87.9,-92.9,120.7,-2.2,-61.6,0.4\n";
        let e = parse_serial_robots(wam, "WAM/w.csv", &o)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("7 joint columns") && e.contains("6 joints"),
            "{e}"
        );
        // A number that is not one.
        let bad = ur5_rows(3).replace("-43.71", "n/a");
        let e = parse_serial_robots(&bad, "u.csv", &o)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("u.csv") && e.contains("joint_2") && e.contains('2'),
            "{e}"
        );
        // A difference far beyond a positioning error (metres, or another column).
        let far = ur5_rows(3).replace(",-2.14,", ",-2140.0,");
        let e = parse_serial_robots(&far, "u.csv", &o)
            .unwrap_err()
            .to_string();
        assert!(e.contains("x_dif") && e.contains("beyond"), "{e}");
        // Joints in radians declared as degrees.
        let mut rad = format!("{HEAD6}\n");
        for i in 0..25 {
            rad.push_str(&format!(
                "{i},-430,-6,-98,-2,-3,0.8,-0.4,-0.76,2.36,-1.65,0.97,-0.1\n"
            ));
        }
        let e = parse_serial_robots(&rad, "u.csv", &o)
            .unwrap_err()
            .to_string();
        assert!(e.contains("radians"), "{e}");
        // No joint columns at all.
        let e = parse_serial_robots(&ur5_rows(2).replace("joint_", "q_"), "u.csv", &o)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("no joint columns") && e.contains("joint_6"),
            "{e}"
        );
        // A missing column.
        let e = parse_serial_robots(&ur5_rows(2).replace("z_dif", "z_err"), "u.csv", &o)
            .unwrap_err()
            .to_string();
        assert!(e.contains("z_dif"), "{e}");
        // A negative or fractional step.
        let e = parse_serial_robots(&ur5_rows(2).replacen("\n1,", "\n1.5,", 1), "u.csv", &o)
            .unwrap_err()
            .to_string();
        assert!(e.contains("step_order") && e.contains(":3"), "{e}");
    }
}
