//! Reader and writer of `robocal-dataset/1` (JSON Lines).
//!
//! The reader is strict: every line must be valid JSON, every known field must have its
//! documented type, joint vectors must have the chain's dof, quaternions must be unit and
//! pose ids must be unique and increase, except poses a `skip` / `retry` / `fault` event
//! named, retried at the end of a run. The only tolerated damage is a **torn last line** (no trailing
//! newline and not valid JSON), which is dropped with a [`LoadWarning`]. Unknown fields
//! are kept (`extra`) and written back unchanged.
use std::path::Path;

use serde::Serialize;
use serde_json::{Map, Value};

use super::check::{self, Ty, AXIS_NORM_TOL};
use super::error::{DatasetError, LoadWarning, Location, Problem};
use super::types::{Dataset, Header, PoseRecord, Record, RobotBlock};

/// The `format` of a dataset header.
pub use crate::schema::DATASET_FORMAT;
/// The `what` values an `event` record may carry.
pub const EVENT_KINDS: [&str; 6] = ["skip", "retry", "fault", "resume", "pause", "note"];

/// The robot `model` of a dataset without a kinematic model: every pose record carries its
/// `flange` pose and no joint angles (`robocal import handeye`).
pub const NO_ROBOT_MODEL: &str = "none";

/// Number of joints of a built-in robot preset, `None` for an unknown name.
pub fn preset_dof(model: &str) -> Option<usize> {
    match model {
        "denso-vs060" | "ur5e" | "ur10e" => Some(6),
        _ => None,
    }
}

impl RobotBlock {
    /// A block that names a preset model only (no serial, chain, flange or extra keys).
    pub fn named(model: &str) -> Self {
        RobotBlock {
            model: model.into(),
            serial: None,
            chain: None,
            flange: None,
            extra: Default::default(),
        }
    }

    /// Number of joints: the chain's length, else the preset's.
    pub fn dof(&self) -> Option<usize> {
        match &self.chain {
            Some(c) => Some(c.len()),
            None => preset_dof(&self.model),
        }
    }
}

/// A dataset as read from a file, with what the reader tolerated.
#[derive(Debug, Clone, PartialEq)]
pub struct Loaded {
    /// The header and every valid record.
    pub dataset: Dataset,
    /// Non-fatal findings (a dropped torn last line).
    pub warnings: Vec<LoadWarning>,
    /// Byte length of the accepted part of the file (everything before a torn last line).
    pub valid_len: u64,
}

/// Incremental validator of the lines of one dataset; used by the reader and the journal.
#[derive(Debug, Clone)]
pub(crate) struct Validator {
    dof: usize,
    last_pose_id: Option<u64>,
    /// Every pose id seen so far (ids are unique).
    pose_ids: std::collections::HashSet<u64>,
    /// Pose ids a `skip` / `retry` / `fault` event named: the only poses that may come
    /// after a larger id (retried at the end of the run).
    retry_ids: std::collections::HashSet<u64>,
}

impl Validator {
    pub(crate) fn new(header: &Header) -> Self {
        Validator {
            // A parsed header always has a dof (checked by `check_header`).
            dof: header.robot.dof().unwrap_or(0),
            last_pose_id: None,
            pose_ids: Default::default(),
            retry_ids: Default::default(),
        }
    }

    /// Checks one record value and converts it; updates the id order on success.
    pub(crate) fn record(&mut self, v: Value) -> Result<Record, Problem> {
        let Some(obj) = v.as_object() else {
            return Err(Problem::Invalid("a record must be a JSON object".into()));
        };
        check::field(obj, "", "kind", Ty::Str, true)?;
        check::field(obj, "", "t", Ty::Num, true)?;
        let kind = obj.get("kind").and_then(Value::as_str).unwrap_or_default();
        match kind {
            "pose" => self.check_pose(obj)?,
            "pivot" => check_pivot(obj)?,
            "event" => check_event(obj)?,
            other => {
                return Err(Problem::field(
                    "kind",
                    format!("unknown record kind \"{other}\" (expected pose, pivot or event)"),
                ))
            }
        }
        let rec: Record = serde_json::from_value(v).map_err(|e| Problem::Invalid(e.to_string()))?;
        match &rec {
            Record::Pose(p) => {
                if let Some(flange) = &p.flange {
                    check::unit_quat(&flange.quat, "flange.quat")?;
                }
                if let Some(q) = p.marker.as_ref().and_then(|m| m.quat.as_ref()) {
                    check::unit_quat(q, "marker.quat")?;
                }
                if let Some(q) = p.reference.as_ref().and_then(|m| m.quat.as_ref()) {
                    check::unit_quat(q, "reference.quat")?;
                }
                self.last_pose_id = Some(p.id);
                self.pose_ids.insert(p.id);
            }
            Record::Pivot(p) => {
                if let Some(q) = &p.marker.quat {
                    check::unit_quat(q, "marker.quat")?;
                }
            }
            Record::Event(_) => {}
        }
        self.note_event(&rec);
        Ok(rec)
    }

    /// Remembers the pose an event says was skipped or retried (it may come again later).
    fn note_event(&mut self, rec: &Record) {
        if let Record::Event(e) = rec {
            if let (Some(id), "skip" | "retry" | "fault") = (e.id, e.what.as_str()) {
                self.retry_ids.insert(id);
            }
        }
    }

    /// Replays an already validated record (keeps the id order).
    pub(crate) fn note(&mut self, rec: &Record) {
        if let Record::Pose(p) = rec {
            self.last_pose_id = Some(p.id);
            self.pose_ids.insert(p.id);
        }
        self.note_event(rec);
    }

    fn check_pose(&self, obj: &Map<String, Value>) -> Result<(), Problem> {
        check::field(obj, "", "id", Ty::UInt, true)?;
        let id = obj.get("id").and_then(Value::as_u64).unwrap_or_default();
        // Ids increase in acquisition order, except poses a run retries at its end (skipped
        // for a transient reason first): an id may come after a larger one, never twice.
        if self.pose_ids.contains(&id) {
            let prev = self.last_pose_id.unwrap_or(id);
            return Err(Problem::field(
                "id",
                format!("pose id {id} is recorded twice (pose ids must be unique; last id {prev})"),
            ));
        }
        if let Some(last) = self.last_pose_id.filter(|&l| id < l) {
            if !self.retry_ids.contains(&id) {
                return Err(Problem::field(
                    "id",
                    format!(
                        "pose id {id} comes after pose id {last}: ids increase in acquisition \
                         order (only a pose a `skip` / `retry` event named may come again at the \
                         end of a run): records reversed, reordered or merged from two files"
                    ),
                ));
            }
        }
        for (k, ty) in [
            ("point", Ty::UInt),
            ("branch", Ty::UInt),
            ("group", Ty::Str),
            ("q_cmd", Ty::Nums(self.dof)),
            ("q", Ty::Nums(self.dof)),
            ("q_prev", Ty::Nums(self.dof)),
            ("range", Ty::NumOrNull),
            ("temp_c", Ty::Num),
            ("plane", Ty::Str),
            ("move", Ty::Str),
            ("target", Ty::Str),
            ("image", Ty::Str),
            ("corners", Ty::PairList),
            ("tip", Ty::Obj),
        ] {
            check::field(obj, "", k, ty, false)?;
        }
        let flange = check::object(obj, "", "flange", false)?;
        if let Some(f) = flange {
            check::file_pose(f, "flange")?;
        }
        let has_q = obj.get("q").is_some_and(|v| !v.is_null());
        if !has_q && flange.is_none() {
            return Err(Problem::field(
                "q",
                "missing (a pose needs measured joints `q` or a `flange` pose)",
            ));
        }
        if let Some(m) = check::object(obj, "", "marker", false)? {
            check::marker(m, "marker")?;
            let visible = m.get("visible").and_then(Value::as_bool).unwrap_or(true);
            if visible && m.get("p").is_none_or(Value::is_null) {
                return Err(Problem::field(
                    "marker.p",
                    "missing (the marker is visible)",
                ));
            }
        }
        if let Some(m) = check::object(obj, "", "reference", false)? {
            check::marker(m, "reference")?;
            let visible = m.get("visible").and_then(Value::as_bool).unwrap_or(true);
            if visible && m.get("p").is_none_or(Value::is_null) {
                return Err(Problem::field(
                    "reference.p",
                    "missing (the reference body is visible)",
                ));
            }
        }
        if let Some(tip) = check::object(obj, "", "tip", false)? {
            check::field(tip, "tip", "p", Ty::Nums(3), true)?;
        }
        Ok(())
    }
}

fn check_pivot(obj: &Map<String, Value>) -> Result<(), Problem> {
    check::field(obj, "", "tool", Ty::Str, false)?;
    let Some(m) = check::object(obj, "", "marker", true)? else {
        return Err(Problem::field("marker", "missing"));
    };
    check::marker(m, "marker")?;
    if m.get("p").is_none_or(Value::is_null) {
        return Err(Problem::field("marker.p", "missing"));
    }
    Ok(())
}

fn check_event(obj: &Map<String, Value>) -> Result<(), Problem> {
    check::field(obj, "", "what", Ty::Str, true)?;
    let what = obj.get("what").and_then(Value::as_str).unwrap_or_default();
    if !EVENT_KINDS.contains(&what) {
        return Err(Problem::field(
            "what",
            format!(
                "unknown event \"{what}\" (expected one of {})",
                EVENT_KINDS.join(", ")
            ),
        ));
    }
    check::field(obj, "", "id", Ty::UInt, false)?;
    check::field(obj, "", "reason", Ty::Str, false)
}

/// Checks a header value and converts it.
pub(crate) fn check_header(v: Value) -> Result<Header, Problem> {
    let Some(obj) = v.as_object() else {
        return Err(Problem::Invalid(
            "line 1 must be the header object (`{\"format\": \"robocal-dataset/1\", ...}`)".into(),
        ));
    };
    check::field(obj, "", "format", Ty::Str, true)?;
    let format = obj
        .get("format")
        .and_then(Value::as_str)
        .unwrap_or_default();
    if format != DATASET_FORMAT {
        return Err(Problem::field(
            "format",
            format!("expected \"{DATASET_FORMAT}\", got \"{format}\""),
        ));
    }
    check::field(obj, "", "created", Ty::Str, false)?;
    check::field(obj, "", "notes", Ty::Str, false)?;
    let Some(robot) = check::object(obj, "", "robot", true)? else {
        return Err(Problem::field("robot", "missing"));
    };
    check::robot(robot, "robot")?;
    // An RCM dataset (an `instrument` block) uses only the instrument pose (`flange`): its
    // instrument holder need not be a preset.
    let instrument_holder = obj.contains_key("instrument") && !robot.contains_key("chain");
    let header: Header = serde_json::from_value(v).map_err(|e| Problem::Invalid(e.to_string()))?;
    if !instrument_holder {
        check_robot_semantics(&header.robot, "robot")?;
    }
    Ok(header)
}

/// Semantic checks of a typed robot block: a known dof, unit axes, ordered limits.
pub(crate) fn check_robot_semantics(robot: &RobotBlock, prefix: &str) -> Result<(), Problem> {
    match &robot.chain {
        None if robot.model == NO_ROBOT_MODEL => {}
        None => {
            if preset_dof(&robot.model).is_none() {
                return Err(Problem::field(
                    check::join(prefix, "model"),
                    format!(
                        "unknown preset \"{}\" and no chain given (presets: denso-vs060, ur5e, ur10e; \"none\" when every pose carries its flange pose)",
                        robot.model
                    ),
                ));
            }
        }
        Some(chain) => {
            if chain.is_empty() {
                return Err(Problem::field(
                    check::join(prefix, "chain"),
                    "must list at least one joint",
                ));
            }
            for (i, j) in chain.iter().enumerate() {
                let n = j.axis.iter().map(|x| x * x).sum::<f64>().sqrt();
                if (n - 1.0).abs() > AXIS_NORM_TOL {
                    return Err(Problem::field(
                        format!("{}[{i}].axis", check::join(prefix, "chain")),
                        format!("must be a unit vector, its norm is {n:.6}"),
                    ));
                }
                if let Some([lo, hi]) = j.limits {
                    if lo >= hi {
                        return Err(Problem::field(
                            format!("{}[{i}].limits", check::join(prefix, "chain")),
                            format!("lower limit {lo} must be below upper limit {hi}"),
                        ));
                    }
                }
            }
        }
    }
    Ok(())
}

fn syntax(file: &Path, line: usize, msg: impl Into<String>) -> DatasetError {
    DatasetError::Syntax {
        at: Location {
            file: file.to_path_buf(),
            line: Some(line),
        },
        msg: msg.into(),
    }
}

/// Longest line of a dataset file (bytes): 4 MiB. A record with every corner of a large board
/// is a few tens of kB; a longer line is a corrupt or foreign file, and parsing it would take
/// tens of times its size in memory.
pub const MAX_LINE_BYTES: usize = 4 << 20;
/// Most records in one dataset file: 2 million (a 100 Hz stream of 5.5 hours).
pub const MAX_RECORDS: usize = 2_000_000;

thread_local! {
    static PARSES: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

/// How many dataset files this thread has parsed ([`parse_dataset`], which every reader goes
/// through): a test counts how often a pipeline reads its data.
pub fn dataset_parses_on_this_thread() -> usize {
    PARSES.with(|c| c.get())
}

/// Parses the bytes of a dataset file; `file` names it in errors and warnings.
pub fn parse_dataset(bytes: &[u8], file: &Path) -> Result<Loaded, DatasetError> {
    PARSES.with(|c| c.set(c.get() + 1));
    let mut header: Option<Header> = None;
    let mut validator: Option<Validator> = None;
    let mut records = Vec::new();
    let mut warnings = Vec::new();
    let mut offset = 0usize;
    let mut lineno = 0usize;
    while offset < bytes.len() {
        lineno += 1;
        let rest = &bytes[offset..];
        let (line, complete) = match rest.iter().position(|&b| b == b'\n') {
            Some(i) => (&rest[..i], true),
            None => (rest, false),
        };
        if line.len() > MAX_LINE_BYTES {
            return Err(syntax(
                file,
                lineno,
                format!(
                    "the line is {} bytes, longer than the {} MiB a dataset record can be: a \
                     corrupt file or not a robocal dataset",
                    line.len(),
                    MAX_LINE_BYTES >> 20
                ),
            ));
        }
        if lineno > MAX_RECORDS + 1 {
            return Err(syntax(
                file,
                lineno,
                format!(
                    "more than {MAX_RECORDS} records: split the acquisition into several \
                     datasets"
                ),
            ));
        }
        let parsed: Result<Value, String> = std::str::from_utf8(line)
            .map_err(|e| format!("not valid UTF-8: {e}"))
            .and_then(|s| serde_json::from_str::<Value>(s).map_err(|e| e.to_string()));
        let value = match parsed {
            Ok(v) => v,
            Err(_) if !complete && header.is_some() => {
                let w = LoadWarning::TornLastLine {
                    file: file.to_path_buf(),
                    line: lineno,
                    bytes: line.len(),
                };
                tracing::warn!("{w}");
                warnings.push(w);
                break;
            }
            Err(e) => {
                let msg = if line.iter().all(u8::is_ascii_whitespace) {
                    "empty line".to_string()
                } else if lineno == 1 {
                    // A pretty-printed robocal file (calibration, plan, ...) given as a dataset.
                    let text = String::from_utf8_lossy(bytes);
                    crate::schema::kind::with_other_kind(
                        format_args!("invalid JSON: {e}"),
                        &text,
                        crate::schema::DATASET_FORMAT,
                    )
                } else {
                    format!("invalid JSON: {e}")
                };
                return Err(syntax(file, lineno, msg));
            }
        };
        match &mut validator {
            None => {
                let h = check_header(value).map_err(|p| p.at(file, Some(lineno)))?;
                validator = Some(Validator::new(&h));
                header = Some(h);
            }
            Some(val) => {
                let rec = val.record(value).map_err(|p| p.at(file, Some(lineno)))?;
                records.push(rec);
            }
        }
        offset += line.len() + usize::from(complete);
    }
    let Some(header) = header else {
        return Err(DatasetError::Invalid {
            at: Location {
                file: file.to_path_buf(),
                line: Some(1),
            },
            msg: "empty file: expected a robocal-dataset/1 header on line 1".into(),
        });
    };
    Ok(Loaded {
        dataset: Dataset { header, records },
        warnings,
        valid_len: offset as u64,
    })
}

/// Reads a dataset file. A torn last line is dropped, returned as a warning and logged.
pub fn read_dataset(path: impl AsRef<Path>) -> Result<Loaded, DatasetError> {
    let path = path.as_ref();
    let bytes = crate::fsio::read(path).map_err(|e| DatasetError::io(path, e))?;
    parse_dataset(&bytes, path)
}

impl Dataset {
    /// Reads a dataset file (see [`read_dataset`]); warnings are logged and dropped.
    pub fn load(path: impl AsRef<Path>) -> Result<Dataset, DatasetError> {
        read_dataset(path).map(|l| l.dataset)
    }

    /// The whole dataset as JSON Lines text (header, then one record per line).
    pub fn to_jsonl(&self) -> String {
        let mut out = to_line(&self.header);
        for r in &self.records {
            out.push_str(&to_line(r));
        }
        out
    }

    /// Writes the dataset to `path` atomically (temporary file, fsync, rename).
    pub fn save(&self, path: impl AsRef<Path>) -> Result<(), DatasetError> {
        write_atomic(path.as_ref(), self.to_jsonl().as_bytes())
    }

    /// Number of joints of the header's robot.
    pub fn dof(&self) -> Option<usize> {
        self.header.robot.dof()
    }
}

/// Writes `dataset` to `path` (see [`Dataset::save`]).
pub fn write_dataset(path: impl AsRef<Path>, dataset: &Dataset) -> Result<(), DatasetError> {
    dataset.save(path)
}

/// One JSON value as one line (with its `\n`).
pub(crate) fn to_line<T: Serialize>(v: &T) -> String {
    // Serialising these types cannot fail: all map keys are strings.
    let mut s = serde_json::to_string(v).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}"));
    s.push('\n');
    s
}

/// Writes `bytes` to `path` atomically and durably ([`crate::fsio::write_atomic`]).
pub(crate) fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), DatasetError> {
    crate::fsio::write_atomic(path, bytes).map_err(|e| DatasetError::io(path, e))
}

/// Pose records with their `q` converted to radians (the library's internal unit).
pub fn q_rad(p: &PoseRecord) -> Option<Vec<f64>> {
    p.q.as_ref()
        .map(|q| q.iter().map(|d| d.to_radians()).collect())
}
