//! Errors of `robocal import`: every one names the file and, where it has one, the line
//! (1-based, the header row is line 1) and the column, with the likely cause.
use std::fmt;

/// Where an import error is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct At {
    /// The input file as the user named it.
    pub file: String,
    /// 1-based line (header = 1), when the error is on one line.
    pub line: Option<usize>,
    /// Column name, when the error is in one column.
    pub column: Option<String>,
}

impl fmt::Display for At {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file)?;
        if let Some(l) = self.line {
            write!(f, ":{l}")?;
        }
        if let Some(c) = &self.column {
            write!(f, ": column \"{c}\"")?;
        }
        Ok(())
    }
}

/// Why an import failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ImportError {
    /// The file could not be read or written.
    #[error("{file}: {source}")]
    Io {
        file: String,
        #[source]
        source: std::io::Error,
    },
    /// Bad content (what and where, with the likely cause).
    #[error("{at}: {msg}")]
    Bad { at: At, msg: String },
    /// Bad options (no file position).
    #[error("{0}")]
    Usage(String),
}

impl ImportError {
    pub(crate) fn bad(
        file: &str,
        line: Option<usize>,
        column: Option<&str>,
        msg: impl Into<String>,
    ) -> Self {
        ImportError::Bad {
            at: At {
                file: file.to_string(),
                line,
                column: column.map(str::to_string),
            },
            msg: msg.into(),
        }
    }
}
