//! `robocal import`: turn the measurement files people already have into a
//! `robocal-dataset/1` file (the header says where the data came from).
//!
//! - [`ipa`]: the IPA robot-accuracy layout (UR10 + Leica laser tracker + T-Mac;
//!   `christianlandgraf/ipa-robot-accuracy`, MIT, Landgraf et al., CASE 2021).
//! - [`serial_robots`]: `pauljac7700/serial_robots_datasets` (UR5 / Barrett WAM + laser
//!   tracker; target + positioning error per pose; MIT, Jacobi 2025).
//! - [`generic`]: any delimited table with a column mapping (joints in deg or rad, positions
//!   in mm or m, a quaternion in either order or Euler angles in any SciPy sequence, time,
//!   temperature, tracker RMS, a reference body).
//!
//! Both parse from `&str` (fuzzable) and refuse bad input with an error naming the file, the
//! line (header = line 1), the column and the likely cause; nothing panics. The result is
//! checked by robocal's strict dataset reader before it is returned, so every imported file
//! loads back.
pub mod error;
pub mod euler;
pub mod generic;
pub mod handeye;
pub mod ipa;
pub mod matrices;
pub mod ndi;
pub mod robot;
pub mod serial_robots;
pub mod table;

use nalgebra::{Quaternion, UnitQuaternion};
use serde_json::{Map, Value};

pub use error::ImportError;
pub use euler::{EulerSeq, QuatOrder};
use table::Table;

use crate::dataset::{Dataset, Header, MarkerObs, PoseRecord, Record, RobotBlock, DATASET_FORMAT};

/// A gap (s) between two poses after which `q_prev` is not written (the arm may have been
/// moved by someone else in between).
pub const PAUSE_S: f64 = 600.0;
/// Joints declared in degrees all within this many radians (over at least
/// [`UNIT_CHECK_MIN_ROWS`] rows) look like radians.
pub const RAD_LIMIT: f64 = 2.0 * std::f64::consts::PI * 1.05;
/// Minimum rows before the unit checks judge a column.
pub const UNIT_CHECK_MIN_ROWS: usize = 20;
/// Positions declared in mm all below this (in absolute value) look like metres.
pub const MM_AS_M_LIMIT: f64 = 5.0;
/// How far from 1 a quaternion's norm may be.
pub const QUAT_NORM_TOL: f64 = 1e-3;

/// An imported dataset and what the importer has to say about it.
#[derive(Debug, Clone, PartialEq)]
pub struct Imported {
    pub dataset: Dataset,
    /// Things the user must know (printed on stderr by the CLI).
    pub warnings: Vec<String>,
    /// Whether `t` comes from real timestamps (else `t` = row index).
    pub times_real: bool,
}

impl Imported {
    /// Number of pose records and of those in the `validation` group.
    pub fn counts(&self) -> (usize, usize) {
        let n = self.dataset.poses().count();
        let v = self.dataset.poses_in("validation").count();
        (n, v)
    }
}

/// One imported row before it becomes a record.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Row {
    /// File line (1-based).
    pub line: usize,
    pub q_deg: Vec<f64>,
    /// Time (s) on the file's clock, when it has one.
    pub t: Option<f64>,
    pub marker: MarkerObs,
    pub reference: Option<MarkerObs>,
    pub temp_c: Option<f64>,
    pub extra: Map<String, Value>,
}

pub(crate) fn marker_obs(p: [f64; 3], quat: Option<[f64; 4]>, rms: Option<f64>) -> MarkerObs {
    MarkerObs {
        p: Some(p),
        quat,
        rms,
        visible: true,
        frames: None,
        extra: Map::new(),
    }
}

/// A unit quaternion from file values; a norm far from 1 is an error naming the columns.
pub(crate) fn unit_quat(
    tab: &Table,
    row: usize,
    cols: &[usize],
    q: Quaternion<f64>,
) -> Result<UnitQuaternion<f64>, ImportError> {
    crate::plausible::quat::unit_wxyz(&[q.w, q.i, q.j, q.k]).map_err(|e| {
        let names: Vec<&str> = cols.iter().map(|&c| tab.columns[c].as_str()).collect();
        ImportError::bad(
            &tab.file,
            Some(tab.line(row)),
            Some(&names.join(",")),
            format!("{e} (or the wrong --quat-order)"),
        )
    })
}

/// Joints declared in degrees that all look like radians (or the reverse) are refused.
pub(crate) fn check_joint_unit(
    tab: &Table,
    cols: &[usize],
    rows: &[Vec<f64>],
    declared_deg: bool,
    flag_hint: &str,
) -> Result<(), ImportError> {
    if rows.is_empty() {
        return Ok(());
    }
    let names: Vec<&str> = cols.iter().map(|&c| tab.columns[c].as_str()).collect();
    let max = rows
        .iter()
        .flat_map(|r| r.iter())
        .fold(0.0f64, |m, v| m.max(v.abs()));
    let last = tab.line(tab.rows.len() - 1);
    if declared_deg && rows.len() >= UNIT_CHECK_MIN_ROWS && max < RAD_LIMIT {
        return Err(ImportError::bad(
            &tab.file,
            None,
            Some(&names.join(",")),
            format!(
                "joints declared in degrees but every value on lines 2–{last} is within ±{max:.3} (< 2π·1.05): they look like radians ({flag_hint} rad)"
            ),
        ));
    }
    if !declared_deg && max > RAD_LIMIT {
        let (i, j) = rows
            .iter()
            .enumerate()
            .find_map(|(i, r)| r.iter().position(|v| v.abs() > RAD_LIMIT).map(|j| (i, j)))
            .unwrap_or((0, 0));
        return Err(ImportError::bad(
            &tab.file,
            Some(tab.line(i)),
            Some(names[j]),
            format!(
                "joint value {} declared in radians is beyond ±2π·1.05: the joints look like degrees ({flag_hint} deg)",
                rows[i][j]
            ),
        ));
    }
    Ok(())
}

/// Positions (mm, after conversion) that all look like metres, or any beyond ±100 m, are
/// refused. `what` names the position (marker / reference), `hint` the unit flag.
pub(crate) fn check_positions(
    tab: &Table,
    cols: &[usize],
    ps: &[[f64; 3]],
    declared_mm: bool,
    hint: &str,
) -> Result<(), ImportError> {
    let names: Vec<&str> = cols.iter().map(|&c| tab.columns[c].as_str()).collect();
    if let Some((i, j)) = ps
        .iter()
        .enumerate()
        .find_map(|(i, p)| p.iter().position(|v| v.abs() > 1e5).map(|j| (i, j)))
    {
        return Err(ImportError::bad(
            &tab.file,
            Some(tab.line(i)),
            Some(names[j]),
            format!(
                "position {:.1} mm is beyond ±100 m{}",
                ps[i][j],
                if declared_mm {
                    ""
                } else {
                    " (declared in metres: are they millimetres? then use --length-unit mm)"
                }
            ),
        ));
    }
    let max = ps
        .iter()
        .flat_map(|p| p.iter())
        .fold(0.0f64, |m, v| m.max(v.abs()));
    if declared_mm && !ps.is_empty() && max < MM_AS_M_LIMIT {
        let last = tab.line(tab.rows.len() - 1);
        return Err(ImportError::bad(
            &tab.file,
            None,
            Some(&names.join(",")),
            format!(
                "positions declared in mm but every value on lines 2–{last} is within ±{max:.3}: they look like metres ({hint} m)"
            ),
        ));
    }
    Ok(())
}

/// Assembles the dataset: acquisition order (sorted by time when times are real), ids,
/// `t`, `q_prev`, groups; then checks it through robocal's strict reader.
pub(crate) fn assemble(
    mut header: Header,
    mut rows: Vec<Row>,
    heldout_every: usize,
    file: &str,
    mut warnings: Vec<String>,
) -> Result<Imported, ImportError> {
    let times_real = rows.iter().all(|r| r.t.is_some());
    if times_real {
        let back = rows
            .windows(2)
            .filter(|w| w[1].t.unwrap_or(0.0) < w[0].t.unwrap_or(0.0))
            .count();
        if back > 0 {
            let first = rows
                .windows(2)
                .find(|w| w[1].t.unwrap_or(0.0) < w[0].t.unwrap_or(0.0))
                .map_or(0, |w| w[1].line);
            warnings.push(format!(
                "{file}: time goes backwards {back} time(s) (first at line {first}): rows are put in time order (the acquisition order); each record keeps its file line in `src_line`"
            ));
            rows.sort_by(|a, b| a.t.unwrap_or(0.0).total_cmp(&b.t.unwrap_or(0.0)));
        }
    } else {
        warnings.push(format!(
            "{file}: no usable time stamps: t = the row index (acquisition order), not seconds; time-based effects cannot be tested on this dataset (drift over time, warm-up, latency)"
        ));
        let note = "t is the row index, not a time (the file has no usable time stamps); time-based effects cannot be tested.";
        header.notes = Some(match header.notes.take() {
            Some(n) => format!("{n} {note}"),
            None => note.into(),
        });
    }
    let t0 = rows.first().and_then(|r| r.t).unwrap_or(0.0);
    let mut records = Vec::with_capacity(rows.len());
    let mut prev: Option<(f64, Vec<f64>)> = None;
    let mut pauses = 0usize;
    for (i, r) in rows.into_iter().enumerate() {
        let t = if times_real {
            r.t.unwrap_or(t0) - t0
        } else {
            i as f64
        };
        let q_prev = match prev.take() {
            Some((tp, q)) if !times_real || t - tp <= PAUSE_S => Some(q),
            Some(_) => {
                pauses += 1;
                None
            }
            None => None,
        };
        prev = Some((t, r.q_deg.clone()));
        let group = if heldout_every > 0 && (i + 1) % heldout_every == 0 {
            "validation"
        } else {
            "train"
        };
        let mut extra = r.extra;
        extra.insert("src_line".into(), Value::from(r.line as u64));
        records.push(Record::Pose(PoseRecord {
            id: i as u64,
            t,
            point: None,
            branch: None,
            group: Some(group.into()),
            q_cmd: None,
            q: Some(r.q_deg),
            q_prev,
            flange: None,
            marker: Some(r.marker),
            reference: r.reference,
            range: None,
            temp_c: r.temp_c,
            plane: None,
            move_kind: None,
            target: None,
            image: None,
            corners: None,
            tip: None,
            extra,
        }));
    }
    if pauses > 0 {
        warnings.push(format!(
            "{file}: {pauses} pause(s) longer than {PAUSE_S} s: the pose after each has no q_prev"
        ));
    }
    header.format = DATASET_FORMAT.into();
    let ds = Dataset { header, records };
    // Every file robocal writes loads back: run the strict reader on the text.
    let text = ds.to_jsonl();
    let loaded = crate::dataset::parse_dataset(text.as_bytes(), std::path::Path::new(file))
        .map_err(|e| {
            ImportError::bad(
                file,
                None,
                None,
                format!("the imported dataset does not pass robocal's reader: {e}"),
            )
        })?;
    Ok(Imported {
        dataset: loaded.dataset,
        warnings,
        times_real,
    })
}

/// A header with the robot and a `source` block.
pub(crate) fn header(robot: RobotBlock, source: Value, notes: String) -> Header {
    let mut extra = Map::new();
    extra.insert("source".into(), source);
    Header {
        format: DATASET_FORMAT.into(),
        created: None,
        robot,
        tool: None,
        tracker: None,
        range_sensor: None,
        plan: None,
        notes: Some(notes),
        extra,
    }
}

/// Joint count of the robot, or an error naming it.
pub(crate) fn robot_dof(robot: &RobotBlock) -> Result<usize, ImportError> {
    robot.dof().ok_or_else(|| {
        ImportError::Usage(format!(
            "robot \"{}\": unknown number of joints (give a chain)",
            robot.model
        ))
    })
}

#[cfg(test)]
mod tests;
