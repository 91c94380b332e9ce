//! Named 3-D points: CSV `name,x_mm,y_mm,z_mm` (fiducials, targets, surface points) and the
//! probe-tip records of a dataset (`pose` records with `tip.p` and a `target` label).
use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

use nalgebra::Point3;

use super::{io_err, RegisterError};
use crate::dataset::Dataset;
use crate::schema::points_csv::{self, NamedRow, PointsCsvError};

/// One named point (mm).
#[derive(Debug, Clone, PartialEq)]
pub struct NamedPoint {
    pub name: String,
    pub p: Point3<f64>,
    /// 1-based line of the source file (0 when not from a file).
    pub line: usize,
}

/// Parses CSV text `name,x_mm,y_mm,z_mm` through the one point-table reader
/// ([`crate::schema::points_csv::parse_named`]: header required, `#` comments and blank lines
/// skipped, other units in the header refused with a hint, non-finite numbers, empty and
/// duplicate names refused; errors name file, line and field).
pub fn parse_points_csv(text: &str, file: &str) -> Result<Vec<NamedPoint>, RegisterError> {
    let rows = points_csv::parse_named(text, file).map_err(|e| match e {
        PointsCsvError::Bad { file, line, msg } => RegisterError::Input {
            file,
            line: line as usize,
            msg,
        },
        PointsCsvError::Io { file, source } => RegisterError::Io { path: file, source },
    })?;
    Ok(rows
        .into_iter()
        .map(|(r, line)| NamedPoint {
            name: r.name,
            p: Point3::new(r.x_mm, r.y_mm, r.z_mm),
            line: line as usize,
        })
        .collect())
}

/// Reads a points CSV file.
pub fn read_points_csv(path: &Path) -> Result<Vec<NamedPoint>, RegisterError> {
    let text = crate::fsio::read_to_string(path).map_err(|e| io_err(path, e))?;
    parse_points_csv(&text, &path.display().to_string())
}

/// Surface points from a CSV `name,x_mm,y_mm,z_mm` table or a PLY point cloud (the vertices,
/// named `v1`, `v2`, …; e.g. `robocal calibrate laser --scan … --ply`), by the file's first
/// bytes. A PLY without vertices is an error naming the file.
pub fn read_surface_points(path: &Path) -> Result<Vec<NamedPoint>, RegisterError> {
    let bytes = crate::fsio::read(path).map_err(|e| io_err(path, e))?;
    if !bytes.starts_with(b"ply") {
        return read_points_csv(path);
    }
    let file = path.display().to_string();
    let m = super::mesh::parse_mesh(&bytes, &file)?;
    if m.vertices.is_empty() {
        return Err(RegisterError::Input {
            file,
            line: 0,
            msg: "a PLY point cloud without vertices".into(),
        });
    }
    Ok(m.vertices
        .iter()
        .enumerate()
        .map(|(i, p)| NamedPoint {
            name: format!("v{}", i + 1),
            p: *p,
            line: 0,
        })
        .collect())
}

/// Writes named points as CSV `name,x_mm,y_mm,z_mm` (to 1e-6 mm), through the same schema.
pub fn write_points_csv<W: Write>(mut w: W, pts: &[NamedPoint]) -> std::io::Result<()> {
    let rows: Vec<NamedRow> = pts
        .iter()
        .map(|p| NamedRow {
            name: p.name.clone(),
            x_mm: p.p.x,
            y_mm: p.p.y,
            z_mm: p.p.z,
        })
        .collect();
    w.write_all(points_csv::named_to_string(&rows).as_bytes())?;
    w.flush()
}

/// Probe-tip points of a dataset: every `pose` record with a `tip` (`{"p": [x, y, z]}` in
/// the tracker frame) and a `target` label; several records of one label are averaged.
pub fn tip_points_from_dataset(ds: &Dataset, file: &str) -> Result<Vec<NamedPoint>, RegisterError> {
    let mut acc: BTreeMap<String, (nalgebra::Vector3<f64>, usize, usize)> = BTreeMap::new();
    for (k, rec) in ds.poses().enumerate() {
        let (Some(tip), Some(label)) = (&rec.tip, &rec.target) else {
            continue;
        };
        let p = tip
            .get("p")
            .and_then(|v| v.as_array())
            .filter(|a| a.len() == 3)
            .and_then(|a| {
                let v: Option<Vec<f64>> = a.iter().map(|x| x.as_f64()).collect();
                v
            })
            .filter(|v| v.iter().all(|x| x.is_finite()))
            .ok_or_else(|| RegisterError::Input {
                file: file.to_string(),
                line: 0,
                msg: format!(
                    "pose record {} (#{k}): field `tip.p` must be 3 finite numbers (mm)",
                    rec.id
                ),
            })?;
        let e =
            acc.entry(label.clone())
                .or_insert((nalgebra::Vector3::zeros(), 0, rec.id as usize));
        e.0 += nalgebra::Vector3::new(p[0], p[1], p[2]);
        e.1 += 1;
    }
    if acc.is_empty() {
        return Err(RegisterError::Input {
            file: file.to_string(),
            line: 0,
            msg: "no pose record carries both `tip` and `target`: no probe-tip fiducials".into(),
        });
    }
    Ok(acc
        .into_iter()
        .map(|(name, (s, n, _))| NamedPoint {
            name,
            p: Point3::from(s / n as f64),
            line: 0,
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_refuses_with_line_numbers() {
        let ok =
            parse_points_csv("name,x_mm,y_mm,z_mm\n# c\nF1,1,2,3\nF2, 4 ,5,6\n", "a.csv").unwrap();
        assert_eq!(ok.len(), 2);
        assert_eq!(ok[1].p, Point3::new(4.0, 5.0, 6.0));
        assert_eq!(ok[1].line, 4);
        let e = parse_points_csv("name,x_mm,y_mm,z_mm\nF1,1,2,3\nF1,1,2,3\n", "a.csv")
            .unwrap_err()
            .to_string();
        assert!(e.contains("a.csv:3") && e.contains("twice"), "{e}");
        let e = parse_points_csv("name,x_m,y_m,z_m\nF1,1,2,3\n", "b.csv")
            .unwrap_err()
            .to_string();
        assert!(e.contains("b.csv:1") && e.contains("unit"), "{e}");
        let e = parse_points_csv("name,x_mm,y_mm,z_mm\nF1,1,NaN,3\n", "c.csv")
            .unwrap_err()
            .to_string();
        assert!(e.contains("c.csv:2") && e.contains("y_mm"), "{e}");
        let e = parse_points_csv("name,x_mm,y_mm,z_mm\nF1,1,x,3\n", "c.csv")
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a number"), "{e}");
    }
}
