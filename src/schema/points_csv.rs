//! The point tables `id,x_mm,y_mm,z_mm` (truth files, `heldout_predictions.csv`) and
//! `name,x_mm,y_mm,z_mm` (fiducials, CT targets, surface points, `predict --points`): typed
//! rows read and written through the `csv` crate by one reader; errors name the file, line and
//! field.
use std::collections::HashMap;
use std::path::Path;

use nalgebra::Point3;
use serde::{Deserialize, Serialize};

/// The header of the table.
pub const HEADER: [&str; 4] = ["id", "x_mm", "y_mm", "z_mm"];

/// One row: a pose id and a point (mm).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct IdPoint {
    /// Pose (record) id.
    pub id: u64,
    /// x (mm).
    pub x_mm: f64,
    /// y (mm).
    pub y_mm: f64,
    /// z (mm).
    pub z_mm: f64,
}

/// Why a point table was refused.
#[derive(Debug, thiserror::Error)]
pub enum PointsCsvError {
    /// The file could not be read or written.
    #[error("{file}: {source}")]
    Io {
        /// The file.
        file: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A line is not a valid row.
    #[error("{file}:{line}: {msg}")]
    Bad {
        /// The file.
        file: String,
        /// Line number (1-based).
        line: u64,
        /// What is wrong, naming the field.
        msg: String,
    },
}

/// One row of a named point table `name,x_mm,y_mm,z_mm` (fiducials, CT targets, surface
/// points): a name and a point (mm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NamedRow {
    /// Point name.
    pub name: String,
    /// x (mm).
    pub x_mm: f64,
    /// y (mm).
    pub y_mm: f64,
    /// z (mm).
    pub z_mm: f64,
}

/// The header of the named table.
pub const NAMED_HEADER: [&str; 4] = ["name", "x_mm", "y_mm", "z_mm"];

/// A row of either table: its key and its point.
trait Row: serde::de::DeserializeOwned {
    const HEADER: [&'static str; 4];
    type Key: std::fmt::Display + Eq + std::hash::Hash + Clone;
    fn key(&self) -> Self::Key;
    fn xyz(&self) -> [f64; 3];
}

impl Row for IdPoint {
    const HEADER: [&'static str; 4] = HEADER;
    type Key = u64;
    fn key(&self) -> u64 {
        self.id
    }
    fn xyz(&self) -> [f64; 3] {
        [self.x_mm, self.y_mm, self.z_mm]
    }
}

impl Row for NamedRow {
    const HEADER: [&'static str; 4] = NAMED_HEADER;
    type Key = String;
    fn key(&self) -> String {
        self.name.clone()
    }
    fn xyz(&self) -> [f64; 3] {
        [self.x_mm, self.y_mm, self.z_mm]
    }
}

/// The one reader of both tables: header exactly `R::HEADER` (a byte-order mark, blank
/// lines and `#` comment lines allowed), 4 fields per row, every value finite, keys unique.
/// Rows come back in file order with their 1-based line.
fn parse_rows<R: Row>(text: &str, file: &str) -> Result<Vec<(R, u64)>, PointsCsvError> {
    let want = R::HEADER;
    let bad = |line: u64, msg: String| PointsCsvError::Bad {
        file: file.to_string(),
        line,
        msg,
    };
    // The csv reader's line numbers are off by one after CRLF line ends: count on LF.
    let text = text.trim_start_matches('\u{feff}').replace("\r\n", "\n");
    let mut rd = csv::ReaderBuilder::new()
        .has_headers(true)
        .trim(csv::Trim::All)
        .comment(Some(b'#'))
        .from_reader(text.as_bytes());
    let header: Vec<String> = rd
        .headers()
        .map_err(|e| bad(1, e.to_string()))?
        .iter()
        .map(str::to_string)
        .collect();
    let header_line = text
        .lines()
        .position(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .map_or(1, |i| i as u64 + 1);
    if header.iter().all(|h| h.is_empty()) {
        return Err(bad(
            0,
            format!("empty file: no `{}` header", want.join(",")),
        ));
    }
    if header != want {
        let other_unit = header
            .iter()
            .any(|c| ["x_", "y_", "z_"].iter().any(|p| c.starts_with(p)) && !c.ends_with("_mm"));
        let hint = if other_unit {
            " (a unit other than mm: convert the file to mm)"
        } else {
            ""
        };
        return Err(bad(
            header_line,
            format!(
                "expected the header `{}`, found `{}`{hint}",
                want.join(","),
                header.join(",")
            ),
        ));
    }
    let hdr = csv::StringRecord::from(want.to_vec());
    let describe = |e: &csv::Error, rec: Option<&csv::StringRecord>| match e.kind() {
        csv::ErrorKind::Deserialize { err, .. } => match err.field() {
            Some(k) => {
                let name = want.get(k as usize).copied().unwrap_or("?");
                let value = rec.and_then(|r| r.get(k as usize)).unwrap_or("");
                match err.kind() {
                    csv::DeserializeErrorKind::ParseFloat(_)
                    | csv::DeserializeErrorKind::ParseInt(_) => {
                        format!("field `{name}`: `{value}` is not a number")
                    }
                    kind => format!("field `{name}`: {kind}"),
                }
            }
            None => err.to_string(),
        },
        csv::ErrorKind::UnequalLengths { len, .. } => {
            format!("expected 4 fields ({}), found {len}", want.join(","))
        }
        _ => e.to_string(),
    };
    let mut out: Vec<(R, u64)> = Vec::new();
    let mut seen: HashMap<R::Key, u64> = HashMap::new();
    for rec in rd.records() {
        let rec = rec.map_err(|e| bad(e.position().map_or(0, |p| p.line()), describe(&e, None)))?;
        let line = rec.position().map_or(0, |p| p.line());
        let row: R = rec
            .deserialize(Some(&hdr))
            .map_err(|e| bad(line, describe(&e, Some(&rec))))?;
        for (name, v) in want[1..].iter().zip(row.xyz()) {
            if !v.is_finite() {
                return Err(bad(
                    line,
                    format!("field `{name}`: {v} is not a finite number"),
                ));
            }
        }
        let key = row.key();
        if key.to_string().is_empty() {
            return Err(bad(line, format!("field `{}` is empty", want[0])));
        }
        if let Some(first) = seen.insert(key.clone(), line) {
            return Err(bad(
                line,
                format!(
                    "field `{}`: `{key}` appears twice (first on line {first}): it pairs the points",
                    want[0]
                ),
            ));
        }
        out.push((row, line));
    }
    Ok(out)
}

/// Parse the text of a point table; `file` names it in errors. The header must be
/// `id,x_mm,y_mm,z_mm`; every value finite; ids unique.
pub fn parse(text: &str, file: &str) -> Result<HashMap<u64, Point3<f64>>, PointsCsvError> {
    Ok(parse_rows::<IdPoint>(text, file)?
        .into_iter()
        .map(|(r, _)| (r.id, Point3::new(r.x_mm, r.y_mm, r.z_mm)))
        .collect())
}

/// Parse the text of a named point table `name,x_mm,y_mm,z_mm` (rows in file order, each
/// with its 1-based line); the same rules as [`parse`], names unique and non-empty.
pub fn parse_named(text: &str, file: &str) -> Result<Vec<(NamedRow, u64)>, PointsCsvError> {
    parse_rows::<NamedRow>(text, file)
}

/// The text of a named point table (rows in the given order, 1e-6 mm resolution).
pub fn named_to_string(rows: &[NamedRow]) -> String {
    let mut w = csv::Writer::from_writer(Vec::new());
    for r in rows {
        // Serialising into memory cannot fail.
        let _ = w.write_record([
            r.name.clone(),
            format!("{:.6}", r.x_mm),
            format!("{:.6}", r.y_mm),
            format!("{:.6}", r.z_mm),
        ]);
    }
    let body = w.into_inner().unwrap_or_default();
    format!(
        "{}\n{}",
        NAMED_HEADER.join(","),
        String::from_utf8_lossy(&body)
    )
}

/// Read a point table file (see [`parse`]).
pub fn read(path: &Path) -> Result<HashMap<u64, Point3<f64>>, PointsCsvError> {
    let text = crate::fsio::read_to_string(path).map_err(|source| PointsCsvError::Io {
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
        assert!(
            e.starts_with("t.csv:3: field `id`") && e.contains("twice"),
            "{e}"
        );
        let e = parse("id,x_mm,y_mm,z_mm\n1,2,NaN,4\n", "t.csv")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("t.csv:2: field `y_mm`"), "{e}");
    }

    #[test]
    fn named_table_round_trips_and_refuses_like_the_id_table() {
        let rows = vec![
            NamedRow {
                name: "F1".into(),
                x_mm: 1.0,
                y_mm: 2.0,
                z_mm: 3.0,
            },
            NamedRow {
                name: "tip, left".into(),
                x_mm: -4.25,
                y_mm: 0.5,
                z_mm: 1e3,
            },
        ];
        let back = parse_named(&named_to_string(&rows), "n.csv").unwrap();
        let back: Vec<NamedRow> = back.into_iter().map(|(r, _)| r).collect();
        assert_eq!(back, rows);
        let ok = parse_named(
            "\u{feff}# fiducials\nname,x_mm,y_mm,z_mm\n# c\nF1,1,2,3\nF2, 4 ,5,6\n",
            "a.csv",
        )
        .unwrap();
        assert_eq!(ok.len(), 2);
        assert_eq!((ok[1].0.x_mm, ok[1].1), (4.0, 5));
        let e = parse_named("name,x_mm,y_mm,z_mm\nF1,1,2,3\nF1,1,2,3\n", "a.csv")
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("a.csv:3: field `name`") && e.contains("twice"),
            "{e}"
        );
        let e = parse_named("name,x_m,y_m,z_m\nF1,1,2,3\n", "b.csv")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("b.csv:1:") && e.contains("unit"), "{e}");
        let e = parse_named("name,x_mm,y_mm,z_mm\nF1,1,x,3\n", "c.csv")
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("c.csv:2: field `y_mm`") && e.contains("not a number"),
            "{e}"
        );
        let e = parse_named("name,x_mm,y_mm,z_mm\n,1,2,3\n", "c.csv")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("c.csv:2: field `name` is empty"), "{e}");
        let e = parse_named("", "d.csv").unwrap_err().to_string();
        assert!(e.contains("empty file"), "{e}");
    }
}
