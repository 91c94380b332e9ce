//! A generic delimited table with a column mapping (`robocal import csv`).
use std::str::FromStr;

use nalgebra::UnitQuaternion;
use serde_json::json;

use super::error::ImportError;
use super::euler::{wxyz, EulerSeq, QuatOrder};
use super::table::Table;
use super::{
    assemble, check_joint_unit, check_positions, header, marker_obs, robot_dof, unit_quat,
    Imported, Row,
};
use crate::dataset::RobotBlock;

/// Unit of angles in the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AngleUnit {
    Deg,
    Rad,
}

impl AngleUnit {
    /// The name used on the command line.
    pub fn name(self) -> &'static str {
        match self {
            AngleUnit::Deg => "deg",
            AngleUnit::Rad => "rad",
        }
    }
}

impl FromStr for AngleUnit {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "deg" => Ok(AngleUnit::Deg),
            "rad" => Ok(AngleUnit::Rad),
            _ => Err(format!("angle unit \"{s}\": expected deg or rad")),
        }
    }
}

/// Unit of lengths in the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LengthUnit {
    Mm,
    M,
}

impl FromStr for LengthUnit {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "mm" => Ok(LengthUnit::Mm),
            "m" => Ok(LengthUnit::M),
            _ => Err(format!("length unit \"{s}\": expected mm or m")),
        }
    }
}

impl LengthUnit {
    /// The name used on the command line.
    pub fn name(self) -> &'static str {
        match self {
            LengthUnit::Mm => "mm",
            LengthUnit::M => "m",
        }
    }
    fn to_mm(self) -> f64 {
        match self {
            LengthUnit::Mm => 1.0,
            LengthUnit::M => 1000.0,
        }
    }
}

/// Unit of the time column.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimeUnit {
    S,
    Ms,
}

impl TimeUnit {
    /// The name used on the command line.
    pub fn name(self) -> &'static str {
        match self {
            TimeUnit::S => "s",
            TimeUnit::Ms => "ms",
        }
    }
}

impl FromStr for TimeUnit {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "s" => Ok(TimeUnit::S),
            "ms" => Ok(TimeUnit::Ms),
            _ => Err(format!("time unit \"{s}\": expected s or ms")),
        }
    }
}

/// How an orientation is given.
#[derive(Debug, Clone, PartialEq)]
pub enum Orientation {
    /// Four columns in the given order.
    Quat { cols: Vec<String>, order: QuatOrder },
    /// Three angle columns in sequence order.
    Euler {
        cols: Vec<String>,
        seq: EulerSeq,
        unit: AngleUnit,
    },
}

/// A measured body: position columns and an optional orientation.
#[derive(Debug, Clone, PartialEq)]
pub struct BodyColumns {
    pub pos: Vec<String>,
    pub orientation: Option<Orientation>,
}

/// The column mapping of `robocal import csv`.
#[derive(Debug, Clone, PartialEq)]
pub struct CsvMapping {
    pub robot: RobotBlock,
    pub joints: Vec<String>,
    pub joint_unit: AngleUnit,
    /// The tracked marker (tracker frame).
    pub marker: BodyColumns,
    pub length_unit: LengthUnit,
    pub time: Option<(String, TimeUnit)>,
    pub temp: Option<String>,
    /// Tracker fit RMS (in `length_unit`).
    pub rms: Option<String>,
    /// A reference body fixed in the cell (tracker frame; needs an orientation).
    pub reference: Option<BodyColumns>,
    pub delimiter: u8,
    pub decimal_comma: bool,
    pub heldout_every: usize,
}

struct Body {
    pos: Vec<usize>,
    orient: Option<(Vec<usize>, OrientKind)>,
}

enum OrientKind {
    Quat(QuatOrder),
    Euler(EulerSeq, AngleUnit),
}

fn resolve_body(tab: &Table, b: &BodyColumns, what: &str) -> Result<Body, ImportError> {
    if b.pos.len() != 3 {
        return Err(ImportError::Usage(format!(
            "{what} position: give 3 columns (x,y,z), got {}",
            b.pos.len()
        )));
    }
    let pos = b.pos.iter().map(|c| tab.col(c)).collect::<Result<_, _>>()?;
    let orient = match &b.orientation {
        None => None,
        Some(Orientation::Quat { cols, order }) => {
            if cols.len() != 4 {
                return Err(ImportError::Usage(format!(
                    "{what} quaternion: give 4 columns, got {}",
                    cols.len()
                )));
            }
            let c = cols.iter().map(|c| tab.col(c)).collect::<Result<_, _>>()?;
            Some((c, OrientKind::Quat(*order)))
        }
        Some(Orientation::Euler { cols, seq, unit }) => {
            if cols.len() != 3 {
                return Err(ImportError::Usage(format!(
                    "{what} Euler angles: give 3 columns, got {}",
                    cols.len()
                )));
            }
            let c = cols.iter().map(|c| tab.col(c)).collect::<Result<_, _>>()?;
            Some((c, OrientKind::Euler(*seq, *unit)))
        }
    };
    Ok(Body { pos, orient })
}

fn read_body(
    tab: &Table,
    i: usize,
    b: &Body,
    scale: f64,
) -> Result<([f64; 3], Option<UnitQuaternion<f64>>), ImportError> {
    let p = [
        tab.num(i, b.pos[0])? * scale,
        tab.num(i, b.pos[1])? * scale,
        tab.num(i, b.pos[2])? * scale,
    ];
    let q = match &b.orient {
        None => None,
        Some((c, OrientKind::Quat(order))) => {
            let v = [
                tab.num(i, c[0])?,
                tab.num(i, c[1])?,
                tab.num(i, c[2])?,
                tab.num(i, c[3])?,
            ];
            Some(unit_quat(tab, i, c, order.quaternion(v))?)
        }
        Some((c, OrientKind::Euler(seq, unit))) => {
            let mut a = [tab.num(i, c[0])?, tab.num(i, c[1])?, tab.num(i, c[2])?];
            if *unit == AngleUnit::Deg {
                a = a.map(f64::to_radians);
            }
            Some(seq.rotation(a))
        }
    };
    Ok((p, q))
}

/// Parse a delimited table with the mapping `map`; `file` names it in errors and in the
/// header's `source`.
pub fn parse_csv(text: &str, file: &str, map: &CsvMapping) -> Result<Imported, ImportError> {
    let dof = robot_dof(&map.robot)?;
    if map.joints.len() != dof {
        return Err(ImportError::Usage(format!(
            "--joints names {} columns but robot \"{}\" has {dof} joints",
            map.joints.len(),
            map.robot.model
        )));
    }
    let tab = Table::parse(text, file, map.delimiter, map.decimal_comma)?;
    let c_q: Vec<usize> = map
        .joints
        .iter()
        .map(|c| tab.col(c))
        .collect::<Result<_, _>>()?;
    let marker = resolve_body(&tab, &map.marker, "marker")?;
    let reference = match &map.reference {
        Some(r) => {
            if r.orientation.is_none() {
                return Err(ImportError::Usage(
                    "the reference body needs an orientation (--ref-quat or --ref-euler): its frame is what the marker is expressed in".into(),
                ));
            }
            Some(resolve_body(&tab, r, "reference")?)
        }
        None => None,
    };
    let c_time = map
        .time
        .as_ref()
        .map(|(c, u)| tab.col(c).map(|i| (i, *u)))
        .transpose()?;
    let c_temp = map.temp.as_ref().map(|c| tab.col(c)).transpose()?;
    let c_rms = map.rms.as_ref().map(|c| tab.col(c)).transpose()?;
    let scale = map.length_unit.to_mm();
    let mut rows = Vec::with_capacity(tab.rows.len());
    let mut q_file = Vec::with_capacity(tab.rows.len());
    let mut ps = Vec::new();
    let mut ref_ps = Vec::new();
    for i in 0..tab.rows.len() {
        let q: Vec<f64> = c_q
            .iter()
            .map(|&c| tab.num(i, c))
            .collect::<Result<_, _>>()?;
        let (p, quat) = read_body(&tab, i, &marker, scale)?;
        let reference = match &reference {
            Some(b) => {
                let (rp, rq) = read_body(&tab, i, b, scale)?;
                ref_ps.push(rp);
                Some(marker_obs(rp, rq.as_ref().map(wxyz), None))
            }
            None => None,
        };
        let t = match c_time {
            Some((c, u)) => Some(tab.num(i, c)? * if u == TimeUnit::Ms { 1e-3 } else { 1.0 }),
            None => None,
        };
        let temp_c = match c_temp {
            Some(c) => {
                let v = tab.num(i, c)?;
                if !(-40.0..=150.0).contains(&v) {
                    return Err(ImportError::bad(
                        file,
                        Some(tab.line(i)),
                        Some(&tab.columns[c]),
                        format!("{v} °C is outside −40…150 °C (wrong column, or °F / K?)"),
                    ));
                }
                Some(v)
            }
            None => None,
        };
        let rms = match c_rms {
            Some(c) => {
                let v = tab.num(i, c)?;
                if v < 0.0 {
                    return Err(ImportError::bad(
                        file,
                        Some(tab.line(i)),
                        Some(&tab.columns[c]),
                        format!("negative RMS {v}"),
                    ));
                }
                Some(v * scale)
            }
            None => None,
        };
        let q_deg = match map.joint_unit {
            AngleUnit::Deg => q.clone(),
            AngleUnit::Rad => q.iter().map(|v| v.to_degrees()).collect(),
        };
        q_file.push(q);
        ps.push(p);
        rows.push(Row {
            line: tab.line(i),
            q_deg,
            t,
            marker: marker_obs(p, quat.as_ref().map(wxyz), rms),
            reference,
            temp_c,
            extra: Default::default(),
        });
    }
    let declared_deg = map.joint_unit == AngleUnit::Deg;
    check_joint_unit(&tab, &c_q, &q_file, declared_deg, "use --joint-unit")?;
    let declared_mm = map.length_unit == LengthUnit::Mm;
    check_positions(&tab, &marker.pos, &ps, declared_mm, "use --length-unit")?;
    if let Some(b) = &reference {
        check_positions(&tab, &b.pos, &ref_ps, declared_mm, "use --length-unit")?;
    }
    let describe = |b: &BodyColumns| -> serde_json::Value {
        json!({
            "pos": b.pos,
            "orientation": match &b.orientation {
                None => json!(null),
                Some(Orientation::Quat { cols, order }) => json!({"quat": cols, "order": order.name()}),
                Some(Orientation::Euler { cols, seq, unit }) => json!({"euler": cols, "seq": seq.to_string(), "unit": unit.name()}),
            }
        })
    };
    let source = json!({
        "file": file,
        "rows": tab.rows.len(),
        "importer": "robocal import csv",
        "mapping": {
            "joints": map.joints, "joint_unit": map.joint_unit.name(),
            "marker": describe(&map.marker),
            "length_unit": map.length_unit.name(),
            "time": map.time.as_ref().map(|(c, u)| json!({"column": c, "unit": u.name()})),
            "temp": map.temp, "rms": map.rms,
            "reference": map.reference.as_ref().map(describe),
            "delimiter": (map.delimiter as char).to_string(), "decimal_comma": map.decimal_comma,
        },
    });
    let notes = format!(
        "Imported by robocal import csv from {file} ({} rows): q = columns {} ({}), marker = columns {} ({}, tracker frame){}.",
        tab.rows.len(),
        map.joints.join(","),
        map.joint_unit.name(),
        map.marker.pos.join(","),
        map.length_unit.name(),
        if map.reference.is_some() { "; reference = a body fixed in the cell, re-measured at every pose" } else { "" }
    );
    let h = header(map.robot.clone(), source, notes);
    assemble(h, rows, map.heldout_every, file, Vec::new())
}
