//! Errors and warnings of dataset / calibration file I/O.
use std::path::{Path, PathBuf};

/// Where in a file something went wrong: the file, and the 1-based line when known.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Location {
    /// The file as it was named by the caller (or a label such as `<memory>`).
    pub file: PathBuf,
    /// 1-based line number, when the error belongs to one line.
    pub line: Option<usize>,
}

impl std::fmt::Display for Location {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.line {
            Some(l) => write!(f, "{}:{l}", self.file.display()),
            None => write!(f, "{}", self.file.display()),
        }
    }
}

/// An error reading or writing a `robocal-dataset/1` or `robocal-calibration/1` file.
///
/// Every variant names the file; parse errors also name the line and, where one is to
/// blame, the field (`train.jsonl:17: field "q": expected an array of 6 numbers`).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DatasetError {
    /// The file could not be opened, read, written or synced.
    // The OS error is part of the message (not a `source`) so `{:#}` prints it once.
    #[error("{}: {error}", file.display())]
    Io {
        /// The file.
        file: PathBuf,
        /// The OS error.
        error: std::io::Error,
    },
    /// A line (or the whole calibration file) is not valid JSON, or not an object.
    #[error("{at}: {msg}")]
    Syntax {
        /// File and line.
        at: Location,
        /// What is wrong.
        msg: String,
    },
    /// A field has the wrong type or an invalid value.
    #[error("{at}: field \"{field}\": {msg}")]
    Field {
        /// File and line.
        at: Location,
        /// The field, dotted for nested fields (`marker.p`, `params[3].unit`).
        field: String,
        /// What is wrong.
        msg: String,
    },
    /// A line is valid but breaks a rule of the format that is not about one field
    /// (missing header, unknown record kind, ids out of order, ...).
    #[error("{at}: {msg}")]
    Invalid {
        /// File and line.
        at: Location,
        /// What is wrong.
        msg: String,
    },
}

impl DatasetError {
    pub(crate) fn io(file: &Path, source: std::io::Error) -> Self {
        DatasetError::Io {
            file: file.to_path_buf(),
            error: source,
        }
    }

    /// The 1-based line the error belongs to, when it belongs to one.
    pub fn line(&self) -> Option<usize> {
        match self {
            DatasetError::Io { .. } => None,
            DatasetError::Syntax { at, .. }
            | DatasetError::Field { at, .. }
            | DatasetError::Invalid { at, .. } => at.line,
        }
    }

    /// The field the error names, when it names one.
    pub fn field(&self) -> Option<&str> {
        match self {
            DatasetError::Field { field, .. } => Some(field),
            _ => None,
        }
    }
}

/// A field-level problem before it is attached to a file location.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Problem {
    Field { field: String, msg: String },
    Invalid(String),
}

impl Problem {
    pub(crate) fn field(field: impl Into<String>, msg: impl Into<String>) -> Self {
        Problem::Field {
            field: field.into(),
            msg: msg.into(),
        }
    }

    pub(crate) fn at(self, file: &Path, line: Option<usize>) -> DatasetError {
        let at = Location {
            file: file.to_path_buf(),
            line,
        };
        match self {
            Problem::Field { field, msg } => DatasetError::Field { at, field, msg },
            Problem::Invalid(msg) => DatasetError::Invalid { at, msg },
        }
    }
}

/// A non-fatal finding of the reader.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum LoadWarning {
    /// The last line had no newline and was not valid JSON (what a power cut leaves
    /// behind); it was dropped.
    TornLastLine {
        /// The file.
        file: PathBuf,
        /// Its 1-based line number.
        line: usize,
        /// Its length in bytes.
        bytes: usize,
    },
}

impl std::fmt::Display for LoadWarning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LoadWarning::TornLastLine { file, line, bytes } => write!(
                f,
                "{}:{line}: dropped a torn last line ({bytes} bytes, no newline, not valid JSON)",
                file.display()
            ),
        }
    }
}
