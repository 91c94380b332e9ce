//! Plausibility of a dataset's records against the robot's nominal geometry, its joint
//! limits and the sensors' ranges. The strict reader (`crate::dataset::io`) checks types and
//! structure; these checks catch values that are well-formed but cannot be right: joint
//! angles outside the limits or in radians, marker / flange / pivot positions in metres, a
//! negative laser range, a coordinate of 1e308. Every error names the file, the line, the
//! field and the likely cause.
use std::path::Path;

use nalgebra::Point3;

use crate::dataset::{Dataset, DatasetError, Location, PoseRecord, Record};
use crate::model::KinematicModel;

/// Largest plausible coordinate (mm) of a tracker or robot position: 100 m.
pub const MAX_COORD_MM: f64 = 1.0e5;
/// Largest plausible `t` (s since `created`): ten years.
pub const MAX_T_S: f64 = 3.2e8;
/// How far a measured joint angle may lie outside its limit (deg): encoder overshoot.
pub const JOINT_LIMIT_TOL_DEG: f64 = 0.5;
/// Plausible temperatures (°C) of a calibration cell.
pub const TEMP_RANGE_C: [f64; 2] = [-40.0, 150.0];
/// Largest plausible laser range reading (mm) when the sensor model is unknown.
pub const MAX_RANGE_MM: f64 = 1.0e4;
/// Largest plausible tracker fit RMS (mm).
pub const MAX_RMS_MM: f64 = 100.0;

fn field_err(file: &Path, line: usize, field: impl Into<String>, msg: String) -> DatasetError {
    DatasetError::Field {
        at: Location {
            file: file.to_path_buf(),
            line: Some(line),
        },
        field: field.into(),
        msg,
    }
}

/// A number for a message: plain when moderate, scientific when huge or tiny.
fn num(x: f64) -> String {
    if x != 0.0 && (x.abs() >= 1e6 || x.abs() < 1e-4) {
        format!("{x:e}")
    } else {
        format!("{x}")
    }
}

/// The 1-based line of record `i` (the strict reader allows no blank lines: header = 1).
fn line_of(i: usize) -> usize {
    i + 2
}

/// Measuring window (mm) of a known range sensor, from the header's `range_sensor.kind`.
pub fn sensor_window(kind: &str) -> Option<[f64; 2]> {
    let k = kind.to_ascii_lowercase().replace(['-', '_', ' '], "");
    // KEYENCE IL series: reference distance ± measuring range (catalogue values).
    if k.contains("il600") {
        Some([200.0, 1000.0])
    } else if k.contains("il300") {
        Some([160.0, 450.0])
    } else if k.contains("il100") {
        Some([75.0, 130.0])
    } else {
        None
    }
}

fn range_kind(ds: &Dataset) -> Option<String> {
    ds.header
        .range_sensor
        .as_ref()
        .and_then(|v| v.get("kind"))
        .and_then(|v| v.as_str())
        .map(str::to_string)
}

/// RMS distance of points from their centroid (mm).
/// RMS distance of `pts` from their centroid (mm; 0 when empty).
pub(crate) fn spread(pts: &[Point3<f64>]) -> f64 {
    if pts.is_empty() {
        return 0.0;
    }
    let c = pts
        .iter()
        .fold(nalgebra::Vector3::zeros(), |a, p| a + p.coords)
        / pts.len() as f64;
    (pts.iter()
        .map(|p| (p.coords - c).norm_squared())
        .sum::<f64>()
        / pts.len() as f64)
        .sqrt()
}

fn coord_check(
    file: &Path,
    line: usize,
    field: &str,
    p: &[f64],
    what: &str,
) -> Result<(), DatasetError> {
    for (k, x) in p.iter().enumerate() {
        if !x.is_finite() || x.abs() > MAX_COORD_MM {
            return Err(field_err(
                file,
                line,
                format!("{field}[{k}]"),
                format!(
                    "{x:e} mm is not a plausible {what} (beyond ±{MAX_COORD_MM:e} mm = 100 m): \
                     a corrupted or mistyped value"
                ),
            ));
        }
    }
    Ok(())
}

fn joints_check(
    file: &Path,
    line: usize,
    field: &str,
    q: &[f64],
    limits_deg: &[(f64, f64)],
    pass: Pass,
) -> Result<(), DatasetError> {
    for (k, (&x, &(lo, hi))) in q.iter().zip(limits_deg).enumerate() {
        let absurd = !x.is_finite() || x.abs() > 1.0e4;
        let outside = x < lo - JOINT_LIMIT_TOL_DEG || x > hi + JOINT_LIMIT_TOL_DEG;
        if absurd || (pass == Pass::Ranges && outside) {
            let cause = if !x.is_finite() || x.abs() > 1.0e4 {
                "not a plausible joint angle: a corrupted or mistyped value"
            } else {
                "the robot cannot reach it: a wrong robot model in the header, a joint offset, \
                 or a mistyped value"
            };
            return Err(field_err(
                file,
                line,
                format!("{field}[{k}]"),
                format!(
                    "joint {} = {}° is outside its limits [{lo:.1}°, {hi:.1}°]: {cause}",
                    k + 1,
                    num(x)
                ),
            ));
        }
    }
    Ok(())
}

/// The passes over the records: absurd values first (so whole-file unit checks never see a
/// 1e308), then the unit checks, then the limits and windows (so values in metres are
/// named as such rather than as "outside the window").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Pass {
    Absurd,
    Ranges,
}

/// Checks every record of `ds` (read from `file`) against the robot's nominal geometry, its
/// joint limits and the sensors' ranges. See the module docs.
pub fn check_dataset(ds: &Dataset, file: &Path) -> Result<(), DatasetError> {
    let model = KinematicModel::from_robot_block(&ds.header.robot).ok();
    let limits_deg: Vec<(f64, f64)> = model
        .as_ref()
        .map(|m| {
            m.joint_limits()
                .iter()
                .map(|&(a, b)| (a.to_degrees(), b.to_degrees()))
                .collect()
        })
        .unwrap_or_default();
    let window = range_kind(ds).as_deref().and_then(sensor_window);
    let first_pose_line = ds
        .records
        .iter()
        .position(|r| matches!(r, Record::Pose(_)))
        .map(line_of)
        .unwrap_or(1);
    records(ds, file, &limits_deg, window, Pass::Absurd)?;
    units(ds, file, model.as_ref(), first_pose_line)?;
    records(ds, file, &limits_deg, window, Pass::Ranges)
}

fn records(
    ds: &Dataset,
    file: &Path,
    limits_deg: &[(f64, f64)],
    window: Option<[f64; 2]>,
    pass: Pass,
) -> Result<(), DatasetError> {
    for (i, rec) in ds.records.iter().enumerate() {
        let line = line_of(i);
        let t = match rec {
            Record::Pose(p) => p.t,
            Record::Pivot(p) => p.t,
            Record::Event(e) => e.t,
        };
        if !t.is_finite() || t.abs() > MAX_T_S {
            return Err(field_err(
                file,
                line,
                "t",
                format!("{t:e} s is not a plausible time since the header's `created` (more than ten years)"),
            ));
        }
        match rec {
            Record::Pose(p) => pose_values(file, line, p, limits_deg, window, pass)?,
            Record::Pivot(p) => {
                if let Some(pp) = &p.marker.p {
                    coord_check(file, line, "marker.p", pp, "tracker coordinate")?;
                }
                if pass == Pass::Ranges {
                    rms_check(file, line, p.marker.rms)?;
                }
            }
            Record::Event(_) => {}
        }
    }
    Ok(())
}

fn rms_check(file: &Path, line: usize, rms: Option<f64>) -> Result<(), DatasetError> {
    if let Some(r) = rms {
        if !(0.0..=MAX_RMS_MM).contains(&r) {
            return Err(field_err(
                file,
                line,
                "marker.rms",
                format!("{r} mm is not a tracker fit RMS (it lies in 0..{MAX_RMS_MM} mm)"),
            ));
        }
    }
    Ok(())
}

fn pose_values(
    file: &Path,
    line: usize,
    p: &PoseRecord,
    limits_deg: &[(f64, f64)],
    window: Option<[f64; 2]>,
    pass: Pass,
) -> Result<(), DatasetError> {
    if let Some(q) = &p.q {
        joints_check(file, line, "q", q, limits_deg, pass)?;
    }
    if let Some(q) = &p.q_cmd {
        joints_check(file, line, "q_cmd", q, limits_deg, pass)?;
    }
    if let Some(m) = &p.marker {
        if let Some(pp) = &m.p {
            coord_check(file, line, "marker.p", pp, "tracker coordinate")?;
        }
        if pass == Pass::Ranges {
            rms_check(file, line, m.rms)?;
        }
    }
    if let Some(f) = &p.flange {
        coord_check(file, line, "flange.p", &f.p, "flange position")?;
    }
    if let Some(Some(r)) = p.range {
        if !r.is_finite() || !(0.0..=1.0e6).contains(&r) {
            return Err(field_err(
                file,
                line,
                "range",
                format!(
                    "{} mm: a laser range reading is a distance from 0 to 1e6 mm (a reading \
                     relative to the reference distance, the wrong sign, or a corrupted value?); \
                     write null for no reading",
                    num(r)
                ),
            ));
        }
        if pass == Pass::Absurd {
            return Ok(());
        }
        let (lo, hi, what) = match window {
            Some([lo, hi]) => (0.5 * lo, 1.5 * hi, "the sensor's measuring window"),
            None => (0.0, MAX_RANGE_MM, "any laser range sensor's reach"),
        };
        if r < lo || r > hi {
            return Err(field_err(
                file,
                line,
                "range",
                format!(
                    "{} mm is far outside {what} ({lo:.0}..{hi:.0} mm): a corrupted value or \
                     the wrong `range_sensor.kind`",
                    num(r)
                ),
            ));
        }
    }
    if let Some(tc) = p.temp_c {
        if pass == Pass::Ranges && !(TEMP_RANGE_C[0]..=TEMP_RANGE_C[1]).contains(&tc) {
            return Err(field_err(
                file,
                line,
                "temp_c",
                format!(
                    "{} °C is not a plausible cell temperature ({}..{} °C): Kelvin or \
                     Fahrenheit, or a corrupted value?",
                    num(tc),
                    TEMP_RANGE_C[0],
                    TEMP_RANGE_C[1]
                ),
            ));
        }
    }
    Ok(())
}

/// Whole-file unit checks: radians instead of degrees, metres instead of millimetres.
fn units(
    ds: &Dataset,
    file: &Path,
    model: Option<&KinematicModel>,
    first_line: usize,
) -> Result<(), DatasetError> {
    let poses: Vec<&PoseRecord> = ds.poses().collect();
    // Joint angles in radians: every |q| ≤ π over many poses while the joints move.
    let qs: Vec<&Vec<f64>> = poses.iter().filter_map(|p| p.q.as_ref()).collect();
    if qs.len() >= 5 {
        let max = qs
            .iter()
            .flat_map(|q| q.iter())
            .fold(0.0f64, |a, x| a.max(x.abs()));
        let wide = model.is_some_and(|m| m.joint_limits().iter().any(|(lo, hi)| hi - lo > 0.5));
        if max <= std::f64::consts::PI + 1e-6 && max > 0.0 && wide {
            return Err(field_err(
                file,
                first_line,
                "q",
                format!(
                    "every joint angle of the {} poses lies within ±π (largest |q| = {max:.4}): \
                     the joint angles look like radians; files use degrees",
                    qs.len()
                ),
            ));
        }
    }
    // Marker positions: the tracker is never within 10 mm of every marker; and the marker
    // moves with the flange, so its spread matches the nominal flange spread within ~×3.
    let with_marker: Vec<(&PoseRecord, Point3<f64>)> = poses
        .iter()
        .filter_map(|p| {
            let m = p.marker.as_ref().filter(|m| m.visible)?;
            m.p.map(|x| (*p, Point3::from(x)))
        })
        .collect();
    metres_abs(
        file,
        first_line,
        "marker.p",
        with_marker.iter().map(|(_, p)| p),
        "marker positions",
    )?;
    let pivots: Vec<Point3<f64>> = ds
        .records
        .iter()
        .filter_map(|r| match r {
            Record::Pivot(p) if p.marker.visible => p.marker.p.map(Point3::from),
            _ => None,
        })
        .collect();
    let first_pivot = ds
        .records
        .iter()
        .position(|r| matches!(r, Record::Pivot(_)))
        .map(line_of)
        .unwrap_or(1);
    metres_abs(
        file,
        first_pivot,
        "marker.p",
        pivots.iter(),
        "pivot marker positions",
    )?;
    if pivots.len() >= 3 {
        let s = spread(&pivots);
        if s < 1.0 {
            return Err(field_err(
                file,
                first_pivot,
                "marker.p",
                format!(
                    "the pivot marker positions spread over only {s:.4} mm around their centre \
                     (a probe pivoting about its tip sweeps tens of mm): they look like metres; \
                     files use mm"
                ),
            ));
        }
    }
    if let Some(m) = model {
        let pairs: Vec<(Point3<f64>, Point3<f64>)> = with_marker
            .iter()
            .filter_map(|(p, x)| {
                let q = p.q.as_ref()?;
                let qr: Vec<f64> = q.iter().map(|d| d.to_radians()).collect();
                Some((*x, Point3::from(m.flange_pose(&qr).translation.vector)))
            })
            .collect();
        if pairs.len() >= 4 {
            let sm = spread(&pairs.iter().map(|p| p.0).collect::<Vec<_>>());
            let sf = spread(&pairs.iter().map(|p| p.1).collect::<Vec<_>>());
            if sf > 20.0 {
                let ratio = sm / sf;
                if ratio < 0.05 {
                    return Err(field_err(
                        file,
                        first_line,
                        "marker.p",
                        format!(
                            "marker positions look like metres: they spread over {sm:.4} around \
                             their centre while the robot's nominal flange moves over {sf:.1} mm \
                             for the same joint angles; files use mm"
                        ),
                    ));
                }
                if ratio > 20.0 {
                    return Err(field_err(
                        file,
                        first_line,
                        "marker.p",
                        format!(
                            "marker positions spread over {sm:.1} mm while the robot's nominal \
                             flange moves over {sf:.1} mm for the same joint angles: the wrong \
                             unit (µm?) or the wrong robot model in the header"
                        ),
                    ));
                }
            }
        }
        // Flange poses against the nominal forward kinematics of the same q.
        let fl: Vec<(Point3<f64>, Point3<f64>)> = poses
            .iter()
            .filter_map(|p| {
                let f = p.flange.as_ref()?;
                let q = p.q.as_ref()?;
                let qr: Vec<f64> = q.iter().map(|d| d.to_radians()).collect();
                Some((
                    Point3::from(f.p),
                    Point3::from(m.flange_pose(&qr).translation.vector),
                ))
            })
            .collect();
        if fl.len() >= 4 {
            let sm = spread(&fl.iter().map(|p| p.0).collect::<Vec<_>>());
            let sf = spread(&fl.iter().map(|p| p.1).collect::<Vec<_>>());
            if sf > 20.0 && sm / sf < 0.05 {
                return Err(field_err(
                    file,
                    first_line,
                    "flange.p",
                    format!(
                        "flange positions look like metres: they spread over {sm:.4} while the \
                         nominal forward kinematics of the same q spreads over {sf:.1} mm; files \
                         use mm"
                    ),
                ));
            }
        }
    }
    quat_order(&poses, file, model, first_line)?;
    let flanges: Vec<Point3<f64>> = poses
        .iter()
        .filter_map(|p| p.flange.as_ref().map(|f| Point3::from(f.p)))
        .collect();
    if flanges.len() >= 3 && flanges.iter().all(|p| p.coords.norm() < 10.0) {
        return Err(field_err(
            file,
            first_line,
            "flange.p",
            format!(
                "every flange position lies within 10 mm of the robot base origin (largest |p| = \
                 {:.4}): they look like metres; files use mm",
                flanges.iter().fold(0.0f64, |a, p| a.max(p.coords.norm()))
            ),
        ));
    }
    let ranges: Vec<f64> = poses.iter().filter_map(|p| p.range.flatten()).collect();
    if ranges.len() >= 3 && ranges.iter().all(|r| *r < 5.0) {
        return Err(field_err(
            file,
            first_line,
            "range",
            format!(
                "every laser range reading is below 5 mm (largest {:.4}): they look like metres; \
                 files use mm",
                ranges.iter().fold(0.0f64, |a, r| a.max(*r))
            ),
        ));
    }
    Ok(())
}

/// Quaternion order ([`super::quat::check_order`]): the markers' and the flange blocks'
/// rotations against the robot's (the flange block, else the nominal FK of `q`).
fn quat_order(
    poses: &[&PoseRecord],
    file: &Path,
    model: Option<&KinematicModel>,
    first_line: usize,
) -> Result<(), DatasetError> {
    let fk = |p: &PoseRecord| {
        let (m, q) = (model?, p.q.as_ref()?);
        (q.len() == m.dof()).then(|| {
            let qr: Vec<f64> = q.iter().map(|d| d.to_radians()).collect();
            m.flange_pose(&qr).rotation
        })
    };
    let flange_rot = |p: &PoseRecord| {
        p.flange
            .as_ref()
            .and_then(|f| super::quat::unit_wxyz(&f.quat).ok())
            .or_else(|| fk(p))
    };
    let markers: (Vec<_>, Vec<_>) = poses
        .iter()
        .filter_map(|p| {
            let q = p.marker.as_ref().filter(|m| m.visible)?.quat?;
            Some((flange_rot(p)?, q))
        })
        .unzip();
    let flanges: (Vec<_>, Vec<_>) = poses
        .iter()
        .filter_map(|p| Some((fk(p)?, p.flange.as_ref()?.quat)))
        .unzip();
    for ((robot, quats), what) in [(markers, "marker.quat"), (flanges, "flange.quat")] {
        super::quat::check_order(&robot, &quats, what)
            .map_err(|e| field_err(file, first_line, what, e))?;
    }
    Ok(())
}

/// A tracker never sits within 10 mm of every marker it sees: all |p| < 10 means metres.
fn metres_abs<'a>(
    file: &Path,
    line: usize,
    field: &str,
    pts: impl Iterator<Item = &'a Point3<f64>>,
    what: &str,
) -> Result<(), DatasetError> {
    let v: Vec<f64> = pts.map(|p| p.coords.norm()).collect();
    if v.len() >= 3 && v.iter().all(|n| *n < 10.0) {
        return Err(field_err(
            file,
            line,
            field,
            format!(
                "{what} look like metres: every one lies within 10 mm of the tracker (largest \
                 |p| = {:.4}); files use mm",
                v.iter().fold(0.0f64, |a, x| a.max(*x))
            ),
        ));
    }
    Ok(())
}

/// Whether two robot blocks describe the same robot model: equal `model` names and, when
/// both carry a chain, the same number of joints.
pub fn same_robot(a: &crate::dataset::RobotBlock, b: &crate::dataset::RobotBlock) -> bool {
    if a.model.trim() != b.model.trim() {
        return false;
    }
    match (a.dof(), b.dof()) {
        (Some(x), Some(y)) => x == y,
        _ => true,
    }
}

/// Refuses a second file (`what`: "held-out file", "calibration") made for another robot.
pub fn check_same_robot(
    main: &crate::dataset::RobotBlock,
    main_file: &Path,
    other: &crate::dataset::RobotBlock,
    other_file: &Path,
    what: &str,
) -> Result<(), DatasetError> {
    if same_robot(main, other) {
        return Ok(());
    }
    Err(DatasetError::Field {
        at: Location {
            file: other_file.to_path_buf(),
            line: None,
        },
        field: "robot.model".into(),
        msg: format!(
            "this {what} is for robot model \"{}\"{}, but {} is for \"{}\"{}: a file from another \
             robot or cell",
            other.model,
            other
                .dof()
                .map(|d| format!(" ({d} joints)"))
                .unwrap_or_default(),
            main_file.display(),
            main.model,
            main.dof()
                .map(|d| format!(" ({d} joints)"))
                .unwrap_or_default(),
        ),
    })
}

/// Reads a dataset with the strict reader and checks its plausibility (see the module docs).
pub fn load_checked(path: &Path) -> Result<Dataset, DatasetError> {
    let ds = Dataset::load(path)?;
    check_dataset(&ds, path)?;
    Ok(ds)
}

/// Reads the main dataset and an optional held-out dataset: both strictly and checked for
/// plausibility, the held-out file first checked to be for the same robot model.
pub fn load_with_heldout(
    data: &Path,
    heldout: Option<&Path>,
) -> Result<(Dataset, Option<Dataset>), DatasetError> {
    let ds = load_checked(data)?;
    let held = match heldout {
        Some(h) => {
            let hd = Dataset::load(h)?;
            check_same_robot(&ds.header.robot, data, &hd.header.robot, h, "held-out file")?;
            check_dataset(&hd, h)?;
            Some(hd)
        }
        None => None,
    };
    Ok((ds, held))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::parse_dataset;

    fn file(rel: &str) -> String {
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)).unwrap()
    }

    fn check(text: &str) -> Result<(), DatasetError> {
        let p = Path::new("t.jsonl");
        let ds = parse_dataset(text.as_bytes(), p).unwrap().dataset;
        check_dataset(&ds, p)
    }

    /// Applies `f` to every pose record line (JSON values) of `text`.
    fn map_poses(text: &str, f: impl Fn(&mut serde_json::Value)) -> String {
        let mut out = String::new();
        for (i, l) in text.lines().enumerate() {
            let mut v: serde_json::Value = serde_json::from_str(l).unwrap();
            if i > 0 && v["kind"] == "pose" {
                f(&mut v);
            }
            out.push_str(&v.to_string());
            out.push('\n');
        }
        out
    }

    #[test]
    fn the_project_datasets_are_plausible() {
        for f in [
            "tests/data/kin-geometric/train.jsonl",
            "tests/data/kin-geometric/heldout.jsonl",
            "tests/data/kin-compliance-j2/train.jsonl",
            "tests/data/laser-planes/train.jsonl",
            "tests/data/laser-planes/heldout.jsonl",
        ] {
            check(&file(f)).unwrap_or_else(|e| panic!("{f}: {e}"));
        }
    }

    #[test]
    fn metres_radians_and_out_of_range_values_are_named() {
        let geo = file("tests/data/kin-geometric/heldout.jsonl");
        let scale = |v: &mut serde_json::Value, k: &str, s: f64| {
            let p: Vec<f64> = v[k]
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap() * s)
                .collect();
            v[k] = serde_json::json!(p);
        };
        let m = map_poses(&geo, |v| {
            let mut mk = v["marker"].clone();
            scale(&mut mk, "p", 1e-3);
            v["marker"] = mk;
        });
        let e = check(&m).unwrap_err().to_string();
        assert!(
            e.contains("t.jsonl:2") && e.contains("look like metres"),
            "{e}"
        );
        let r = map_poses(&geo, |v| {
            scale(v, "q", std::f64::consts::PI / 180.0);
            scale(v, "q_cmd", std::f64::consts::PI / 180.0);
        });
        let e = check(&r).unwrap_err().to_string();
        assert!(e.contains("look like radians"), "{e}");
        let mut lines: Vec<String> = geo.lines().map(String::from).collect();
        let mut v: serde_json::Value = serde_json::from_str(&lines[3]).unwrap();
        v["q"][2] = serde_json::json!(160.0); // joint 3 limits [-125, 155]
        lines[3] = v.to_string();
        let e = check(&(lines.join("\n") + "\n")).unwrap_err();
        assert_eq!(e.line(), Some(4));
        assert_eq!(e.field(), Some("q[2]"));
        assert!(
            e.to_string()
                .contains("outside its limits [-125.0°, 155.0°]"),
            "{e}"
        );
    }
}
