//! The IPA robot-accuracy layout (`christianlandgraf/ipa-robot-accuracy`, MIT licence,
//! Landgraf et al., "A Hybrid Neural Network Approach for Increasing the Absolute Accuracy
//! of Industrial Robots", IEEE CASE 2021): a UR10 measured by a Leica laser tracker with a
//! T-Mac 6-DoF probe on the flange.
//!
//! `;`-separated, decimal comma. Columns: `Timestamp` (`YYYYMMDDhhmmss`; in Series B/D
//! mangled by a spreadsheet into `2,02011E+13`), `Goal x/y/z` (m) and `Goal roll/pitch/yaw`
//! (rad, SciPy `xyz` extrinsic; the commanded T-Mac TCP in the source's ROS `base_link`),
//! the six UR joint columns (rad), `measurement_temperature` (°C), `measurement_x/y/z` (mm,
//! T-Mac in the tracker frame), `measurement_rx/ry/rz` (deg, SciPy `XYZ` intrinsic, as the
//! source's `dataset.py`), and in some series `measurement_std_*` after each value.
use serde_json::{json, Map, Value};

use super::error::ImportError;
use super::euler::{wxyz, EulerSeq};
use super::table::Table;
use super::{
    assemble, check_joint_unit, check_positions, header, marker_obs, robot_dof, Imported, Row,
};
use crate::dataset::RobotBlock;

/// The joint columns of the IPA files (UR joint names), in chain order.
pub const JOINTS: [&str; 6] = [
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
];

/// Options of `robocal import ipa`.
#[derive(Debug, Clone, PartialEq)]
pub struct IpaOptions {
    /// Every n-th pose (acquisition order) goes to `validation`; 0 = none.
    pub heldout_every: usize,
    /// The robot (default: the UR10 nominal chain).
    pub robot: RobotBlock,
}

impl Default for IpaOptions {
    fn default() -> Self {
        IpaOptions {
            heldout_every: 4,
            robot: super::robot::ur10(),
        }
    }
}

/// Series letter and plan kind from the file path (`Series_B/measurements_joint_configurations.csv`).
pub fn series_of(file: &str) -> (String, &'static str) {
    let kind = if file.contains("grid") {
        "grid"
    } else if file.contains("joint_configurations") {
        "joint-configurations"
    } else if file.contains("random_poses") {
        "random-poses"
    } else if file.contains("iso_cubes") {
        "iso-cubes"
    } else {
        "unknown"
    };
    let series = file
        .find("Series_")
        .and_then(|i| file[i + 7..].chars().next())
        .filter(char::is_ascii_alphabetic)
        .map(|c| c.to_string())
        .unwrap_or_else(|| {
            match kind {
                "grid" => "A",
                "joint-configurations" => "B",
                "random-poses" => "C",
                "iso-cubes" => "D",
                _ => "?",
            }
            .into()
        });
    (series, kind)
}

/// Days since 1970-01-01 of a civil date (proleptic Gregorian).
fn days_from_civil(y: i64, m: i64, d: i64) -> i64 {
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let mp = (m + 9) % 12;
    let doy = (153 * mp + 2) / 5 + d - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// A `YYYYMMDDhhmmss` stamp as seconds since 1970 (local clock, zone unknown), `None` when
/// the text is not such a stamp (e.g. spreadsheet-mangled `2,02011E+13`).
pub fn parse_stamp(s: &str) -> Option<f64> {
    if s.len() != 14 || !s.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let n = |a: usize, b: usize| s[a..b].parse::<i64>().ok();
    let (y, mo, d, h, mi, se) = (
        n(0, 4)?,
        n(4, 6)?,
        n(6, 8)?,
        n(8, 10)?,
        n(10, 12)?,
        n(12, 14)?,
    );
    if !(1970..=2200).contains(&y)
        || !(1..=12).contains(&mo)
        || !(1..=31).contains(&d)
        || h > 23
        || mi > 59
        || se > 60
    {
        return None;
    }
    Some((days_from_civil(y, mo, d) * 86_400 + h * 3600 + mi * 60 + se) as f64)
}

fn iso_of(s: &str) -> String {
    format!(
        "{}-{}-{}T{}:{}:{}",
        &s[0..4],
        &s[4..6],
        &s[6..8],
        &s[8..10],
        &s[10..12],
        &s[12..14]
    )
}

/// Parse an IPA measurement file. `file` names it in errors and in the header's `source`.
pub fn parse_ipa(text: &str, file: &str, opts: &IpaOptions) -> Result<Imported, ImportError> {
    let tab = Table::parse(text, file, b';', true)?;
    let dof = robot_dof(&opts.robot)?;
    if dof != JOINTS.len() {
        return Err(ImportError::Usage(format!(
            "robot \"{}\" has {dof} joints; the IPA files have 6 ({})",
            opts.robot.model,
            JOINTS.join(", ")
        )));
    }
    let c_time = tab.col("Timestamp")?;
    let c_q: Vec<usize> = JOINTS
        .iter()
        .map(|j| tab.col(j))
        .collect::<Result<_, _>>()?;
    let c_temp = tab.col("measurement_temperature")?;
    let c_p: Vec<usize> = ["measurement_x", "measurement_y", "measurement_z"]
        .iter()
        .map(|c| tab.col(c))
        .collect::<Result<_, _>>()?;
    let c_r: Vec<usize> = ["measurement_rx", "measurement_ry", "measurement_rz"]
        .iter()
        .map(|c| tab.col(c))
        .collect::<Result<_, _>>()?;
    let std_p: Option<Vec<usize>> = [
        "measurement_std_x",
        "measurement_std_y",
        "measurement_std_z",
    ]
    .iter()
    .map(|c| tab.has(c))
    .collect();
    let std_r: Option<Vec<usize>> = [
        "measurement_std_rx",
        "measurement_std_ry",
        "measurement_std_rz",
    ]
    .iter()
    .map(|c| tab.has(c))
    .collect();
    let goal: Option<Vec<usize>> = [
        "Goal x",
        "Goal y",
        "Goal z",
        "Goal roll",
        "Goal pitch",
        "Goal yaw",
    ]
    .iter()
    .map(|c| tab.has(c))
    .collect();
    let seq_meas: EulerSeq = EulerSeq {
        axes: [0, 1, 2],
        intrinsic: true,
    };
    let seq_goal: EulerSeq = EulerSeq {
        axes: [0, 1, 2],
        intrinsic: false,
    };
    let mut warnings = Vec::new();
    // Time stamps: real only when every row has a valid YYYYMMDDhhmmss stamp.
    let stamps: Vec<Option<f64>> = (0..tab.rows.len())
        .map(|i| parse_stamp(tab.text(i, c_time)))
        .collect();
    let n_bad = stamps.iter().filter(|s| s.is_none()).count();
    let times_real = n_bad == 0;
    if !times_real {
        let i = stamps.iter().position(Option::is_none).unwrap_or(0);
        warnings.push(format!(
            "{file}:{}: column \"Timestamp\": \"{}\" is not a YYYYMMDDhhmmss stamp ({n_bad} of {} rows; a spreadsheet turned them into rounded numbers): times are not invented",
            tab.line(i),
            tab.text(i, c_time),
            tab.rows.len()
        ));
    }
    let mut rows = Vec::with_capacity(tab.rows.len());
    let mut q_rad_rows = Vec::with_capacity(tab.rows.len());
    let mut ps = Vec::with_capacity(tab.rows.len());
    for i in 0..tab.rows.len() {
        let q_rad: Vec<f64> = c_q
            .iter()
            .map(|&c| tab.num(i, c))
            .collect::<Result<_, _>>()?;
        let p = tab.num3(i, &c_p)?;
        let r = tab.num3(i, &c_r)?;
        let quat = wxyz(&seq_meas.rotation(r.map(f64::to_radians)));
        let temp = tab.num(i, c_temp)?;
        if !(-40.0..=150.0).contains(&temp) {
            return Err(ImportError::bad(
                file,
                Some(tab.line(i)),
                Some("measurement_temperature"),
                format!("{temp} °C is outside −40…150 °C (wrong column?)"),
            ));
        }
        let mut extra = Map::new();
        let mut rms = None;
        if let Some(sp) = &std_p {
            let s = [tab.num(i, sp[0])?, tab.num(i, sp[1])?, tab.num(i, sp[2])?];
            if let Some(j) = s.iter().position(|v| *v < 0.0) {
                return Err(ImportError::bad(
                    file,
                    Some(tab.line(i)),
                    Some(&tab.columns[sp[j]]),
                    format!("negative standard deviation {}", s[j]),
                ));
            }
            rms = Some((s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt());
            let mut std = Map::new();
            std.insert("xyz_mm".into(), json!(s));
            if let Some(sr) = &std_r {
                let r = [tab.num(i, sr[0])?, tab.num(i, sr[1])?, tab.num(i, sr[2])?];
                std.insert("rxyz_deg".into(), json!(r));
            }
            extra.insert("std".into(), Value::Object(std));
        }
        if let Some(g) = &goal {
            let v: Vec<f64> = g.iter().map(|&c| tab.num(i, c)).collect::<Result<_, _>>()?;
            let q = wxyz(&seq_goal.rotation([v[3], v[4], v[5]]));
            extra.insert(
                "goal_tcp".into(),
                json!({"p": [v[0] * 1000.0, v[1] * 1000.0, v[2] * 1000.0], "quat": q,
                       "frame": "source (ROS base_link)"}),
            );
        }
        q_rad_rows.push(q_rad.clone());
        ps.push(p);
        rows.push(Row {
            line: tab.line(i),
            q_deg: q_rad.iter().map(|v| v.to_degrees()).collect(),
            t: stamps.get(i).copied().flatten().filter(|_| times_real),
            marker: marker_obs(p, Some(quat), rms),
            reference: None,
            temp_c: Some(temp),
            extra,
        });
    }
    check_joint_unit(
        &tab,
        &c_q,
        &q_rad_rows,
        false,
        "the IPA layout has joints in radians; for other files use robocal import csv --joint-unit",
    )?;
    check_positions(
        &tab,
        &c_p,
        &ps,
        true,
        "the IPA layout has mm; for other files use robocal import csv --length-unit",
    )?;
    let (series, kind) = series_of(file);
    let first_stamp = if times_real {
        (0..tab.rows.len())
            .min_by(|&a, &b| {
                stamps[a]
                    .unwrap_or(0.0)
                    .total_cmp(&stamps[b].unwrap_or(0.0))
            })
            .map(|i| iso_of(tab.text(i, c_time)))
    } else {
        None
    };
    let source = json!({
        "dataset": "IPA robot-accuracy dataset",
        "repo": "christianlandgraf/ipa-robot-accuracy",
        "license": "MIT (Copyright (c) 2021 Christian Landgraf)",
        "citation": "Landgraf, Ernst, Schleth, Fabritius, Huber: A Hybrid Neural Network Approach for Increasing the Absolute Accuracy of Industrial Robots, IEEE CASE 2021",
        "file": file,
        "series": series,
        "rows": tab.rows.len(),
        "importer": "robocal import ipa",
        "time": if times_real { "timestamps (local clock of the source, zone not stated)" } else { "row index (the file's timestamps are not usable)" },
    });
    let notes = format!(
        "Real measurements, IPA robot-accuracy dataset Series {series} (MIT, Landgraf et al., CASE 2021), file {file}: UR10 (CB3), Leica laser tracker, T-Mac 6-DoF probe on the flange. q = the source's joint columns (rad -> deg). marker = T-Mac pose in the tracker frame (mm; angles read as SciPy 'XYZ' intrinsic, as the source's dataset.py){}. temp_c = measurement_temperature. q_prev = the previous pose's q{}. goal_tcp = the source's Goal pose (commanded T-Mac TCP, mm, [w,x,y,z], in the source's ROS base_link frame). src_line = line in the source file.",
        if std_p.is_some() { "; marker.rms = sqrt(std_x² + std_y² + std_z²) of the source's std columns (the RMS 3-D position error), std = the source's stds (xyz mm, rxyz deg)" } else { "; the source has no per-measurement std here (no marker.rms)" },
        if times_real { " (omitted after pauses > 600 s); t = seconds from the first time stamp" } else { "" },
    );
    let mut h = header(opts.robot.clone(), source, notes);
    h.created = first_stamp;
    h.tool = Some(json!({"name": "leica-t-mac"}));
    h.tracker = Some(json!({"kind": "leica-laser-tracker-t-mac"}));
    h.plan = Some(json!({"name": format!("ipa-series-{series}"), "kind": kind}));
    assemble(h, rows, opts.heldout_every, file, warnings)
}
