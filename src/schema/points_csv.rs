//! The point table `id,x_mm,y_mm,z_mm` (truth files, `heldout_predictions.csv`): one typed
//! row read and written through the `csv` crate; errors name the file, line and field.
use std::collections::HashMap;
use std::path::Path;

use nalgebra::Point3;
use serde::{Deserialize, Serialize};

/// The header of the table.
pub const HEADER: [&str; 4] = ["id", "x_mm", "y_mm", "z_mm"];

/// One row: a pose id and a point (mm).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct IdPoint {
    pub id: u64,
    pub x_mm: f64,
    pub y_mm: f64,
    pub z_mm: f64,
}

/// Why a point table was refused.
#[derive(Debug, thiserror::Error)]
pub enum PointsCsvError {
    #[error("{file}: {source}")]
    Io {
        file: String,
        source: std::io::Error,
    },
    #[error("{file}:{line}: {msg}")]
    Bad {
        file: String,
        line: u64,
        msg: String,
    },
}

/// Parse the text of a point table; `file` names it in errors. The header must be
/// `id,x_mm,y_mm,z_mm`; every value finite; ids unique.
pub fn parse(text: &str, file: &str) -> Result<HashMap<u64, Point3<f64>>, PointsCsvError> {
    let bad = |line: u64, msg: String| PointsCsvError::Bad {
        file: file.to_string(),
        line,
        msg,
    };
    // The csv reader's line numbers are off by one after CRLF line ends: count on LF.
    let text = text.replace("\r\n", "\n");
    let mut rd = csv::ReaderBuilder::new()
        .has_headers(true)
        .trim(csv::Trim::All)
        .from_reader(text.as_bytes());
    let header: Vec<String> = rd
        .headers()
        .map_err(|e| bad(1, e.to_string()))?
        .iter()
        .map(str::to_string)
        .collect();
    if header != HEADER {
        return Err(bad(
            1,
            format!(
                "expected the header `{}`, found `{}`",
                HEADER.join(","),
                header.join(",")
            ),
        ));
    }
    let hdr = csv::StringRecord::from(HEADER.to_vec());
    let mut out = HashMap::new();
    for rec in rd.records() {
        let describe = |e: &csv::Error| match e.kind() {
            csv::ErrorKind::Deserialize { err, .. } => match err.field() {
                Some(k) => format!(
                    "field `{}`: {}",
                    HEADER.get(k as usize).copied().unwrap_or("?"),
                    err.kind()
                ),
                None => err.to_string(),
            },
            csv::ErrorKind::UnequalLengths { len, .. } => {
                format!("expected 4 fields (id,x_mm,y_mm,z_mm), found {len}")
            }
            _ => e.to_string(),
        };
        let rec = rec.map_err(|e| bad(e.position().map_or(0, |p| p.line()), describe(&e)))?;
        let line = rec.position().map_or(0, |p| p.line());
        let row: IdPoint = rec
            .deserialize(Some(&hdr))
            .map_err(|e| bad(line, describe(&e)))?;
        for (name, v) in [("x_mm", row.x_mm), ("y_mm", row.y_mm), ("z_mm", row.z_mm)] {
            if !v.is_finite() {
                return Err(bad(
                    line,
                    format!("field `{name}`: {v} is not a finite number"),
                ));
            }
        }
        if out
            .insert(row.id, Point3::new(row.x_mm, row.y_mm, row.z_mm))
            .is_some()
        {
            return Err(bad(
                line,
                format!("field `id`: id {} appears twice", row.id),
            ));
        }
    }
    Ok(out)
}

/// Read a point table file (see [`parse`]).
pub fn read(path: &Path) -> Result<HashMap<u64, Point3<f64>>, PointsCsvError> {
    let text = std::fs::read_to_string(path).map_err(|source| PointsCsvError::Io {
        file: path.display().to_string(),
        source,
    })?;
    parse(&text, &path.display().to_string())
}

/// The text of a point table (rows in the given order, 1e-5 mm resolution).
pub fn to_string(rows: &[IdPoint]) -> String {
    let mut w = csv::Writer::from_writer(Vec::new());
    for r in rows {
        // Serialising plain numbers into memory cannot fail.
        let _ = w.write_record([
            r.id.to_string(),
            format!("{:.5}", r.x_mm),
            format!("{:.5}", r.y_mm),
            format!("{:.5}", r.z_mm),
        ]);
    }
    let body = w.into_inner().unwrap_or_default();
    format!("{}\n{}", HEADER.join(","), String::from_utf8_lossy(&body))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_errors_name_file_line_field() {
        let rows = [
            IdPoint {
                id: 3,
                x_mm: 1.5,
                y_mm: -2.0,
                z_mm: 1e3,
            },
            IdPoint {
                id: 7,
                x_mm: 0.0,
                y_mm: 0.25,
                z_mm: -4.0,
            },
        ];
        let text = to_string(&rows);
        let back = parse(&text, "p.csv").unwrap();
        assert_eq!(back.len(), 2);
        assert_eq!(back[&7], Point3::new(0.0, 0.25, -4.0));
        let e = parse("id,x_mm,y_mm,z_mm\n1,2,3,4\n2,x,3,4\n", "t.csv")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("t.csv:3: field `x_mm`"), "{e}");
        let e = parse("id,x_mm,y_mm,z_mm\r\n1,2,3,4\r\n2,1,3\r\n", "t.csv")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("t.csv:3:") && e.contains("4 fields"), "{e}");
        let e = parse("id,x,y,z\n1,2,3,4\n", "t.csv")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("t.csv:1:") && e.contains("header"), "{e}");
        let e = parse("id,x_mm,y_mm,z_mm\n1,2,3,4\n1,2,3,5\n", "t.csv")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("t.csv:3: field `id`"), "{e}");
        let e = parse("id,x_mm,y_mm,z_mm\n1,2,NaN,4\n", "t.csv")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("t.csv:2: field `y_mm`"), "{e}");
    }
}
