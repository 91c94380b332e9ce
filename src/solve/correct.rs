//! Corrected joint targets (the deploy path for controllers that cannot load a new
//! kinematic model): desired tool poses in the robot base → joints through the **identified**
//! model's inverse kinematics, next to what the controller's nominal kinematics would command
//! for the same pose, the error that nominal command would leave on the calibrated robot, and
//! the compensated Cartesian target (the pose to hand the controller's own IK so that it lands
//! on the desired pose). mm / rad inside; the table is mm / degrees.
//!
//! Targets table (`csv`, header row, any column order): `name,x_mm,y_mm,z_mm,qw,qx,qy,qz`
//! (tool pose in the robot base, unit quaternion scalar first), optional `branch` (0–7, see
//! `model::ik`) to pin an IK branch.
use std::path::Path;

use anyhow::{bail, Context as _};
use nalgebra::{Isometry3, Translation3, Vector3};

use crate::dataset::CalibrationFile;
use crate::model::{KinematicModel, ParamGroup};

/// One desired tool pose.
#[derive(Debug, Clone, PartialEq)]
pub struct Target {
    pub name: String,
    /// Tool pose in the robot base (mm).
    pub pose: Isometry3<f64>,
    /// Pin this IK branch (else: every branch within the joint limits).
    pub branch: Option<u8>,
}

#[derive(Debug, serde::Deserialize)]
struct TargetRow {
    name: String,
    x_mm: f64,
    y_mm: f64,
    z_mm: f64,
    qw: f64,
    qx: f64,
    qy: f64,
    qz: f64,
    #[serde(default)]
    branch: Option<u8>,
}

/// Parse a targets table (`file` names it in errors: file, line, field, likely cause).
pub fn parse_targets(file: &str, text: &str) -> anyhow::Result<Vec<Target>> {
    let mut rd = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .comment(Some(b'#'))
        .from_reader(text.as_bytes());
    let head = rd
        .headers()
        .with_context(|| format!("{file}:1: reading the header"))?
        .clone();
    for need in ["name", "x_mm", "y_mm", "z_mm", "qw", "qx", "qy", "qz"] {
        if !head.iter().any(|h| h == need) {
            bail!(
                "{file}:1: no column `{need}`: the header must name name,x_mm,y_mm,z_mm,qw,qx,qy,qz \
                 (tool pose in the robot base, mm, quaternion scalar first) [,branch]"
            );
        }
    }
    let mut out = Vec::new();
    for rec in rd.records() {
        let rec = rec.with_context(|| format!("{file}: reading a row"))?;
        let line = rec.position().map_or(0, |p| p.line());
        let row: TargetRow = rec
            .deserialize(Some(&head))
            .map_err(|e| anyhow::anyhow!("{file}:{line}: {e}"))?;
        let v = [
            ("x_mm", row.x_mm),
            ("y_mm", row.y_mm),
            ("z_mm", row.z_mm),
            ("qw", row.qw),
            ("qx", row.qx),
            ("qy", row.qy),
            ("qz", row.qz),
        ];
        for (f, x) in v {
            if !x.is_finite() {
                bail!("{file}:{line}: field `{f}` = {x} is not finite");
            }
        }
        let p = Vector3::new(row.x_mm, row.y_mm, row.z_mm);
        if p.norm() > 1e5 {
            bail!(
                "{file}:{line}: field `x_mm`..`z_mm`: the target is {:.0} mm from the base: \
                 metres × 1000 twice, or tracker coordinates instead of robot-base ones?",
                p.norm()
            );
        }
        let q = crate::plausible::quat::unit_wxyz(&[row.qw, row.qx, row.qy, row.qz])
            .map_err(|e| anyhow::anyhow!("{file}:{line}: field `qw`..`qz`: {e}"))?;
        if let Some(b) = row.branch {
            if b > 7 {
                bail!("{file}:{line}: field `branch` = {b}: IK branches are 0–7");
            }
        }
        out.push(Target {
            name: row.name,
            pose: Isometry3::from_parts(Translation3::from(p), q),
            branch: row.branch,
        });
    }
    if out.is_empty() {
        bail!("{file}: no target rows");
    }
    // Every target within 5 mm of the base origin (inside the robot's base): positions in
    // metres read as mm.
    let far = out
        .iter()
        .map(|t| t.pose.translation.vector.norm())
        .fold(0.0, f64::max);
    if far < 5.0 {
        bail!(
            "{file}: field `x_mm`..`z_mm`: every target is within {far:.3} mm of the robot's \
             base origin (inside the base): positions in metres instead of mm?"
        );
    }
    Ok(out)
}

/// The fastest joint speed (rad/s) a URScript `movej` of `robocal correct` may ask for: the
/// wrist joints of UR e-Series arms turn at most 360 °/s.
pub const UR_MAX_SPEED_RAD_S: f64 = std::f64::consts::TAU;
/// The largest joint acceleration (rad/s²) a URScript `movej` of `robocal correct` may ask for.
pub const UR_MAX_ACCEL_RAD_S2: f64 = 40.0;

/// Checks the motion options of a robot program before anything is computed: URScript
/// `--speed` (rad/s) and `--accel` (rad/s²) within what a UR arm can do (a larger value is
/// most likely in degrees), PacScript `--speed` a percentage in (0, 100].
pub fn check_script_motion(urscript: bool, speed: f64, accel: f64) -> anyhow::Result<()> {
    if urscript {
        if speed > UR_MAX_SPEED_RAD_S {
            bail!(
                "--speed {speed}: a URScript joint speed is in rad/s and at most \
                 {UR_MAX_SPEED_RAD_S:.3} (360 °/s); degrees per second given as rad/s?"
            );
        }
        if accel > UR_MAX_ACCEL_RAD_S2 {
            bail!(
                "--accel {accel}: a URScript joint acceleration is in rad/s² and at most \
                 {UR_MAX_ACCEL_RAD_S2}; degrees per second² given as rad/s²?"
            );
        }
    } else if speed > 100.0 {
        bail!("--speed {speed}: a PacScript speed is a percentage in (0, 100]");
    }
    Ok(())
}

/// Read a targets table.
pub fn read_targets(path: &Path) -> anyhow::Result<Vec<Target>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    parse_targets(&path.display().to_string(), &text)
}

/// The calibrated model of a kinematic calibration file, and the controller's nominal model:
/// the nominal arm of the same robot block with the calibration's base and tool (so the two
/// differ only in what the identification changed in the arm).
pub fn models_of(cal: &CalibrationFile) -> anyhow::Result<(KinematicModel, KinematicModel)> {
    let mut calibrated = KinematicModel::from_robot_block(&cal.robot)
        .context("building the kinematic model of the calibration's robot block")?;
    let mut nominal = calibrated.clone();
    calibrated
        .apply_cal_params(&cal.params)
        .context("applying the calibration's params")?;
    nominal.set_base(&calibrated.base());
    nominal.set_tool(&calibrated.tool());
    if calibrated.ik_family().is_none() {
        bail!(
            "the calibration's robot has no closed-form IK family (UR or VS060 geometry): \
             corrected targets need every IK branch"
        );
    }
    Ok((calibrated, nominal))
}

/// Whether any arm (joint) parameter differs between the two models.
pub fn arm_changed(a: &KinematicModel, b: &KinematicModel) -> bool {
    a.params()
        .iter()
        .zip(b.params())
        .any(|(p, q)| matches!(p.group, ParamGroup::Joint(_)) && (p.value - q.value).abs() > 0.0)
}

/// One corrected target on one IK branch.
#[derive(Debug, Clone, PartialEq)]
pub struct Corrected {
    pub name: String,
    pub branch: u8,
    pub branch_label: String,
    /// Joints from the identified model's IK (rad).
    pub q_corrected: Vec<f64>,
    /// Joints the controller's nominal IK gives for the same pose on the same branch (rad).
    pub q_nominal: Option<Vec<f64>>,
    /// Where the calibrated robot puts the tool when commanded the nominal joints: position
    /// (mm) and orientation (deg) error against the desired pose.
    pub nominal_pos_err_mm: Option<f64>,
    pub nominal_rot_err_deg: Option<f64>,
    /// The pose to give the controller's own (nominal) IK so the real robot lands on the
    /// target: nominal FK of the corrected joints (robot base, mm).
    pub compensated: Isometry3<f64>,
}

/// Correct every target: every IK branch of the identified model within the joint limits
/// (or the pinned one). A target no branch reaches is an error naming it.
pub fn correct_targets(
    calibrated: &KinematicModel,
    nominal: &KinematicModel,
    targets: &[Target],
) -> anyhow::Result<Vec<Corrected>> {
    let mut out = Vec::new();
    for t in targets {
        let sols = calibrated
            .ik_for_tool(&t.pose)
            .with_context(|| format!("target `{}`: identified-model IK", t.name))?;
        let nom = nominal.ik_for_tool(&t.pose).unwrap_or_default();
        let mut n = 0;
        for s in sols.iter().filter(|s| s.within_limits) {
            if t.branch.is_some_and(|b| b != s.branch) {
                continue;
            }
            n += 1;
            let qn = nom
                .iter()
                .find(|x| x.branch == s.branch && x.within_limits)
                .map(|x| x.q.clone());
            let err = qn.as_ref().map(|q| {
                let got = calibrated.tool_pose_in_base(q);
                (
                    (got.translation.vector - t.pose.translation.vector).norm(),
                    got.rotation.angle_to(&t.pose.rotation).to_degrees(),
                )
            });
            out.push(Corrected {
                name: t.name.clone(),
                branch: s.branch,
                branch_label: s.label.to_string(),
                q_corrected: s.q.clone(),
                nominal_pos_err_mm: err.map(|e| e.0),
                nominal_rot_err_deg: err.map(|e| e.1),
                q_nominal: qn,
                compensated: nominal.tool_pose_in_base(&s.q),
            });
        }
        if n == 0 {
            bail!(
                "target `{}` ({:.1}, {:.1}, {:.1}) mm: no IK branch{} of the identified model \
                 within the joint limits",
                t.name,
                t.pose.translation.x,
                t.pose.translation.y,
                t.pose.translation.z,
                t.branch.map(|b| format!(" {b}")).unwrap_or_default()
            );
        }
    }
    Ok(out)
}

/// The corrected table: `name,branch,branch_label,q1_deg..,nominal_q1_deg..,
/// nominal_pos_err_mm,nominal_rot_err_deg,comp_x_mm,comp_y_mm,comp_z_mm,comp_qw..comp_qz`.
pub fn to_csv(rows: &[Corrected]) -> anyhow::Result<String> {
    let dof = rows.first().map_or(0, |r| r.q_corrected.len());
    let mut w = csv::Writer::from_writer(Vec::new());
    let mut head: Vec<String> = vec!["name".into(), "branch".into(), "branch_label".into()];
    head.extend((1..=dof).map(|i| format!("q{i}_deg")));
    head.extend((1..=dof).map(|i| format!("nominal_q{i}_deg")));
    head.extend(
        [
            "nominal_pos_err_mm",
            "nominal_rot_err_deg",
            "comp_x_mm",
            "comp_y_mm",
            "comp_z_mm",
            "comp_qw",
            "comp_qx",
            "comp_qy",
            "comp_qz",
        ]
        .map(String::from),
    );
    w.write_record(&head)?;
    let opt = |x: Option<f64>| x.map(|v| format!("{v:.6}")).unwrap_or_default();
    for r in rows {
        let mut row = vec![r.name.clone(), r.branch.to_string(), r.branch_label.clone()];
        row.extend(
            r.q_corrected
                .iter()
                .map(|x| format!("{:.6}", x.to_degrees())),
        );
        match &r.q_nominal {
            Some(q) => row.extend(q.iter().map(|x| format!("{:.6}", x.to_degrees()))),
            None => row.extend((0..dof).map(|_| String::new())),
        }
        row.push(opt(r.nominal_pos_err_mm));
        row.push(opt(r.nominal_rot_err_deg));
        let t = r.compensated.translation.vector;
        let q = r.compensated.rotation.quaternion();
        row.extend([t.x, t.y, t.z, q.w, q.i, q.j, q.k].map(|v| format!("{v:.6}")));
        w.write_record(&row)?;
    }
    Ok(String::from_utf8(
        w.into_inner().map_err(|e| anyhow::anyhow!("{e}"))?,
    )?)
}

/// The corrected joints as a plan-shaped pose list, so the plan's URScript / PacScript
/// exporters write them (one pose per target and branch, in order).
pub fn as_plan_poses(rows: &[Corrected]) -> Vec<crate::plan::file::PlanPose> {
    rows.iter()
        .enumerate()
        .map(|(i, r)| crate::plan::file::PlanPose {
            id: i as u64,
            point: i as u64,
            branch: r.branch,
            label: r.name.clone(),
            branch_label: r.branch_label.clone(),
            q_deg: r.q_corrected.iter().map(|x| x.to_degrees()).collect(),
            flange: crate::plan::file::PlanFilePose::from_iso(&r.compensated),
            group: "corrected".into(),
            plane: None,
            move_kind: None,
            block: None,
            target: Some(r.name.clone()),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::RobotBlock;

    /// A UR5e calibration whose arm differs from nominal by a few tenths of a mm / degree.
    fn cal() -> CalibrationFile {
        let mut m = KinematicModel::preset("ur5e").unwrap();
        for (n, dv) in [("phi2", 0.004), ("a3", 0.6), ("d4", -0.4), ("phi5", -0.003)] {
            let v = m.params().iter().find(|p| p.name == n).unwrap().value;
            m.set_param(n, v + dv).unwrap();
        }
        m.set_tool(&Isometry3::translation(5.0, -3.0, 120.0));
        let robot = RobotBlock::named("ur5e");
        crate::solve::calfile::kinematic_file(&robot, &m)
    }

    #[test]
    fn corrected_joints_reach_the_target_on_the_calibrated_robot() {
        let (cal_m, nom_m) = models_of(&cal()).unwrap();
        assert!(arm_changed(&cal_m, &nom_m));
        let q = [0.3, -1.2, 1.4, -1.6, -1.5, 0.4];
        let target = Target {
            name: "T1".into(),
            pose: cal_m.tool_pose_in_base(&q),
            branch: None,
        };
        let rows = correct_targets(&cal_m, &nom_m, std::slice::from_ref(&target)).unwrap();
        assert!(
            rows.len() >= 2,
            "several branches expected, got {}",
            rows.len()
        );
        for r in &rows {
            let got = cal_m.tool_pose_in_base(&r.q_corrected);
            assert!((got.translation.vector - target.pose.translation.vector).norm() < 1e-6);
            assert!(got.rotation.angle_to(&target.pose.rotation) < 1e-8);
            // The nominal command misses by the arm's deviation: about a millimetre here.
            let e = r.nominal_pos_err_mm.unwrap();
            assert!(e > 0.2 && e < 10.0, "branch {}: {e}", r.branch);
            // Handing the compensated pose to the nominal IK gives back the corrected joints.
            let back = nom_m.ik_for_tool(&r.compensated).unwrap();
            let same = back.iter().find(|s| s.branch == r.branch).unwrap();
            let d = same
                .q
                .iter()
                .zip(&r.q_corrected)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            assert!(d < 1e-6, "branch {}: {d}", r.branch);
        }
        let pinned = Target {
            branch: Some(rows[0].branch),
            ..target
        };
        assert_eq!(correct_targets(&cal_m, &nom_m, &[pinned]).unwrap().len(), 1);
        let far = Target {
            name: "far".into(),
            pose: Isometry3::translation(5000.0, 0.0, 0.0),
            branch: None,
        };
        let e = correct_targets(&cal_m, &nom_m, &[far]).unwrap_err();
        assert!(format!("{e:#}").contains("far"), "{e:#}");
        let csv = to_csv(&rows).unwrap();
        assert_eq!(csv.lines().count(), rows.len() + 1);
    }

    #[test]
    fn bad_target_rows_name_line_and_field() {
        let h = "name,x_mm,y_mm,z_mm,qw,qx,qy,qz\n";
        let e = parse_targets("t.csv", &format!("{h}A,1,2,3,1,0,0,0\nB,1,2,3,0.5,0,0,0\n"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("t.csv:3") && e.contains("qw"), "{e}");
        let e = parse_targets("t.csv", "name,x,y,z\nA,1,2,3\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("no column `x_mm`"), "{e}");
        let e = parse_targets("t.csv", &format!("{h}A,1,x,3,1,0,0,0\n"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("t.csv:2"), "{e}");
        let ok = parse_targets(
            "t.csv",
            "name,x_mm,y_mm,z_mm,qw,qx,qy,qz,branch\nA,400,0,300,0,1,0,0,3\n",
        )
        .unwrap();
        assert_eq!(ok[0].branch, Some(3));
    }
}
