//! Reader and writer of `robocal-calibration/1` (one JSON object).
use std::path::Path;

use serde_json::{Map, Value};

use super::check::{self, Ty};
use super::error::{DatasetError, Location, Problem};
use super::io::{check_robot_semantics, write_atomic};
use super::types::{CalEffect, CalParam, CalibrationFile, RobotBlock};

/// The `format` of a calibration file.
pub use crate::schema::CALIBRATION_FORMAT;

/// What a calibration file calibrates (its optional top-level `kind`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CalibrationKind {
    /// Robot kinematics + base + tool; predictions are marker origins in the tracker frame.
    /// This is the default when `kind` is absent (or `"kinematic"`).
    Kinematic,
    /// A range sensor on the flange (`"kind": "laser"`); predictions are laser spots in
    /// the robot base frame.
    Laser,
    /// Any other `kind` value, kept verbatim.
    Other(String),
}

impl CalibrationFile {
    /// A calibration file with the given robot block and parameters, no effects or metrics.
    pub fn new(robot: RobotBlock, params: Vec<CalParam>) -> CalibrationFile {
        CalibrationFile {
            format: CALIBRATION_FORMAT.to_string(),
            robot,
            params,
            effects: Vec::new(),
            effects_joint_range: None,
            metrics: Map::new(),
            extra: Map::new(),
        }
    }

    /// The calibration's kind, from the optional top-level `kind` field.
    pub fn kind(&self) -> CalibrationKind {
        match self.extra.get("kind").and_then(Value::as_str) {
            None | Some("kinematic") => CalibrationKind::Kinematic,
            Some("laser") => CalibrationKind::Laser,
            Some(other) => CalibrationKind::Other(other.to_string()),
        }
    }

    /// Sets the top-level `kind` field (`"laser"`, ...).
    pub fn set_kind(&mut self, kind: &str) {
        self.extra
            .insert("kind".to_string(), Value::String(kind.to_string()));
    }

    /// The parameter called `name`.
    pub fn param(&self, name: &str) -> Option<&CalParam> {
        self.params.iter().find(|p| p.name == name)
    }

    /// Parses a calibration file's text; `file` names it in errors.
    pub fn parse(text: &str, file: &Path) -> Result<CalibrationFile, DatasetError> {
        let value: Value = serde_json::from_str(text).map_err(|e| DatasetError::Syntax {
            at: Location {
                file: file.to_path_buf(),
                line: Some(e.line()),
            },
            msg: crate::schema::kind::with_other_kind(
                format_args!("invalid JSON: {e}"),
                text,
                crate::schema::CALIBRATION_FORMAT,
            ),
        })?;
        check_calibration(value).map_err(|p| p.at(file, None))
    }

    /// Reads and checks a calibration file.
    pub fn load(path: impl AsRef<Path>) -> Result<CalibrationFile, DatasetError> {
        let path = path.as_ref();
        let text = crate::fsio::read_to_string(path).map_err(|e| DatasetError::io(path, e))?;
        CalibrationFile::parse(&text, path)
    }

    /// Pretty-printed JSON text (with a trailing newline).
    pub fn to_json_pretty(&self) -> String {
        let mut s =
            serde_json::to_string_pretty(self).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}"));
        s.push('\n');
        s
    }

    /// Checks the file as the reader would, then writes it atomically.
    pub fn save(&self, path: impl AsRef<Path>) -> Result<(), DatasetError> {
        let path = path.as_ref();
        let value = serde_json::to_value(self).map_err(|e| DatasetError::Invalid {
            at: Location {
                file: path.to_path_buf(),
                line: None,
            },
            msg: e.to_string(),
        })?;
        check_calibration(value).map_err(|p| p.at(path, None))?;
        // What robocal writes, its own readers accept: the plausibility checks
        // `predict` and `diagnose --calibration` apply, before anything is written.
        crate::plausible::calibration::check_values(self, path)?;
        write_atomic(path, self.to_json_pretty().as_bytes())
    }
}

/// Reads a calibration file (see [`CalibrationFile::load`]).
pub fn read_calibration(path: impl AsRef<Path>) -> Result<CalibrationFile, DatasetError> {
    CalibrationFile::load(path)
}

/// Writes a calibration file (see [`CalibrationFile::save`]).
pub fn write_calibration(
    path: impl AsRef<Path>,
    cal: &CalibrationFile,
) -> Result<(), DatasetError> {
    cal.save(path)
}

fn check_calibration(value: Value) -> Result<CalibrationFile, Problem> {
    let Some(obj) = value.as_object() else {
        return Err(Problem::Invalid(
            "a calibration file must be one JSON object".into(),
        ));
    };
    check::field(obj, "", "format", Ty::Str, true)?;
    let format = obj
        .get("format")
        .and_then(Value::as_str)
        .unwrap_or_default();
    if format != CALIBRATION_FORMAT {
        return Err(Problem::field(
            "format",
            format!("expected \"{CALIBRATION_FORMAT}\", got \"{format}\""),
        ));
    }
    check::field(obj, "", "kind", Ty::Str, false)?;
    let Some(robot) = check::object(obj, "", "robot", true)? else {
        return Err(Problem::field("robot", "missing"));
    };
    check::robot(robot, "robot")?;
    let params = match obj.get("params") {
        Some(Value::Array(a)) => a,
        Some(v) => {
            return Err(Problem::field(
                "params",
                format!("expected an array of parameters, got {v}"),
            ))
        }
        None => return Err(Problem::field("params", "missing")),
    };
    let mut names = std::collections::HashSet::new();
    for (i, p) in params.iter().enumerate() {
        let pre = format!("params[{i}]");
        let Some(p) = p.as_object() else {
            return Err(Problem::field(pre, "expected an object"));
        };
        check::field(p, &pre, "name", Ty::Str, true)?;
        check::field(p, &pre, "value", Ty::Num, true)?;
        check::field(p, &pre, "std", Ty::Num, false)?;
        check::field(p, &pre, "unit", Ty::Str, true)?;
        check::field(p, &pre, "free", Ty::Bool, true)?;
        let name = p.get("name").and_then(Value::as_str).unwrap_or_default();
        if !names.insert(name.to_string()) {
            return Err(Problem::field(
                format!("{pre}.name"),
                format!("parameter \"{name}\" appears twice"),
            ));
        }
    }
    match obj.get("effects") {
        None => {}
        Some(Value::Array(a)) => {
            for (i, e) in a.iter().enumerate() {
                let pre = format!("effects[{i}]");
                let Some(e) = e.as_object() else {
                    return Err(Problem::field(pre, "expected an object"));
                };
                check::field(e, &pre, "kind", Ty::Str, true)?;
                check::field(e, &pre, "joint", Ty::UInt, false)?;
                if e.contains_key("params") {
                    check::field(e, &pre, "params", Ty::Obj, true)?;
                }
            }
        }
        Some(v) => {
            return Err(Problem::field(
                "effects",
                format!("expected an array of effects, got {v}"),
            ))
        }
    }
    if obj.contains_key("metrics") {
        check::field(obj, "", "metrics", Ty::Obj, true)?;
    }
    // An RCM hand-eye (`kind: "rcm"`) holds no joint parameters: its instrument holder need
    // not be a preset.
    let rcm = obj.get("kind").and_then(Value::as_str) == Some("rcm");
    let cal: CalibrationFile =
        serde_json::from_value(value).map_err(|e| Problem::Invalid(e.to_string()))?;
    if !(rcm && cal.robot.chain.is_none()) {
        check_robot_semantics(&cal.robot, "robot")?;
    }
    let dof = cal.robot.dof().unwrap_or(0);
    for (i, e) in cal.effects.iter().enumerate() {
        check_effect(e, i, dof)?;
    }
    Ok(cal)
}

fn check_effect(e: &CalEffect, i: usize, dof: usize) -> Result<(), Problem> {
    if let Some(j) = e.joint {
        if j == 0 || j > dof {
            return Err(Problem::field(
                format!("effects[{i}].joint"),
                format!("joint {j} does not exist (joints are 1..={dof})"),
            ));
        }
    }
    Ok(())
}
