//! NDI Track's CSV export (Polaris / Aurora / Vega tools) → `pivot` records.
//!
//! One row per frame. After a first column with the number of tools, every tool has a block
//! `<tool name>,Frame,Face,State,Q0,Qx,Qy,Qz,Tx,Ty,Tz,Error,Markers`, then every marker's
//! `State,Tx,Ty,Tz` (the same four names repeated); the header row names the columns that way
//! (the tool's column is headed by the tool's name). Positions are mm, the quaternion is scalar
//! first, `Error` is the tool's fit RMS (mm). A tool or marker not seen is written as
//! `Missing,-3.697314E28,…`: such a frame is not imported (counted in a warning). The column layout is
//! taken from the header (each `Q0` starts a tool's pose) and checked on every row; a
//! malformed value names the line, the column and the cause.
use serde_json::{json, Map, Value};

use super::ImportError;
use crate::dataset::{Dataset, Header, PivotRecord, Record, RobotBlock, DATASET_FORMAT};

/// Values at or beyond this magnitude are NDI's "missing" sentinel (`-3.697314E28`).
pub const MISSING_ABS: f64 = 1e20;

/// One tool's columns (0-based indexes into a row).
#[derive(Debug, Clone, PartialEq)]
struct ToolCols {
    /// The tool's name as the header gives it.
    name: String,
    name_col: usize,
    frame: usize,
    state: usize,
    q0: usize,
    error: usize,
    markers: usize,
    /// Marker groups (`State,Tx,Ty,Tz`) following `Markers`.
    groups: usize,
}

fn split(line: &str) -> Vec<&str> {
    line.split(',').map(str::trim).collect()
}

fn tools_of(header: &[&str], file: &str) -> Result<Vec<ToolCols>, ImportError> {
    let expect = |i: usize, name: &str| -> Result<(), ImportError> {
        match header.get(i) {
            Some(h) if h.eq_ignore_ascii_case(name) => Ok(()),
            got => Err(ImportError::bad(
                file,
                Some(1),
                Some(got.copied().unwrap_or("(end of row)")),
                format!(
                    "column {} should be \"{name}\" in NDI Track's export layout (<tool>,Frame,Face,State,Q0,Qx,Qy,Qz,Tx,Ty,Tz,Error,Markers,State,Tx,Ty,Tz,…)",
                    i + 1
                ),
            )),
        }
    };
    let starts: Vec<usize> = header
        .iter()
        .enumerate()
        .filter(|(_, h)| h.eq_ignore_ascii_case("Q0"))
        .map(|(i, _)| i)
        .collect();
    if starts.is_empty() || starts[0] < 4 {
        return Err(ImportError::bad(
            file,
            Some(1),
            None,
            "no tool block (…,Frame,Face,State,Q0,Qx,Qy,Qz,Tx,Ty,Tz,Error,…) in the header: not an NDI Track CSV export",
        ));
    }
    let mut tools = vec![];
    for (k, &q0) in starts.iter().enumerate() {
        expect(q0 - 3, "Frame")?;
        expect(q0 - 2, "Face")?;
        expect(q0 - 1, "State")?;
        for (d, n) in ["Qx", "Qy", "Qz", "Tx", "Ty", "Tz", "Error"]
            .iter()
            .enumerate()
        {
            expect(q0 + 1 + d, n)?;
        }
        let end = starts.get(k + 1).map_or(header.len(), |&n| n - 4);
        let mut groups = 0;
        let markers = q0 + 8;
        if header
            .get(markers)
            .is_some_and(|h| h.eq_ignore_ascii_case("Markers"))
        {
            let mut c = markers + 1;
            while c + 3 < end + 1 && c + 3 < header.len() + 1 {
                if ["State", "Tx", "Ty", "Tz"]
                    .iter()
                    .enumerate()
                    .all(|(d, n)| header.get(c + d).is_some_and(|h| h.eq_ignore_ascii_case(n)))
                {
                    groups += 1;
                    c += 4;
                } else {
                    break;
                }
            }
        }
        tools.push(ToolCols {
            name: header[q0 - 4].to_string(),
            name_col: q0 - 4,
            frame: q0 - 3,
            state: q0 - 1,
            q0,
            error: q0 + 7,
            markers,
            groups,
        });
    }
    Ok(tools)
}

/// What the NDI import wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct NdiImport {
    pub dataset: Dataset,
    /// Per tool: `(name, frames, visible frames)`.
    pub tools: Vec<(String, usize, usize)>,
    pub warnings: Vec<String>,
}

/// Parse an NDI Track CSV export. `tool`: only the tool whose name contains this text.
/// `rate_hz`: the tracker's frame counter rate (`t` = (frame − first frame) / rate).
pub fn parse_ndi(
    text: &str,
    file: &str,
    tool: Option<&str>,
    rate_hz: f64,
) -> Result<NdiImport, ImportError> {
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        return Err(ImportError::Usage(format!(
            "--frame-rate {rate_hz}: give the tracker's frame rate in Hz (Polaris 60)"
        )));
    }
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let Some((_, head)) = lines.next() else {
        return Err(ImportError::bad(file, None, None, "empty file"));
    };
    let header = split(head.trim_start_matches('\u{feff}'));
    let mut tools = tools_of(&header, file)?;
    if let Some(t) = tool {
        tools.retain(|c| c.name.contains(t));
        if tools.is_empty() {
            return Err(ImportError::Usage(format!(
                "{file}: no tool named like \"{t}\" (tools: {})",
                tools_of(&header, file)?
                    .iter()
                    .map(|c| c.name.clone())
                    .collect::<Vec<_>>()
                    .join("; ")
            )));
        }
    }
    let mut records = vec![];
    let mut counts: Vec<(String, usize, usize)> =
        tools.iter().map(|c| (c.name.clone(), 0, 0)).collect();
    let mut first_frame: Option<f64> = None;
    let mut warnings = vec![];
    for (i, line) in lines {
        let ln = i + 1;
        let row = split(line);
        let cell = |c: usize, name: &str| -> Result<&str, ImportError> {
            row.get(c).copied().ok_or_else(|| {
                ImportError::bad(
                    file,
                    Some(ln),
                    Some(name),
                    format!(
                        "the row has {} values, the header {} (a truncated line?)",
                        row.len(),
                        header.len()
                    ),
                )
            })
        };
        let num = |c: usize, name: &str| -> Result<f64, ImportError> {
            let s = cell(c, name)?;
            s.parse::<f64>()
                .ok()
                .filter(|v| !v.is_nan())
                .ok_or_else(|| {
                    ImportError::bad(
                        file,
                        Some(ln),
                        Some(name),
                        format!("\"{s}\" is not a number"),
                    )
                })
        };
        for (k, c) in tools.iter().enumerate() {
            let name = cell(c.name_col, &c.name)?.to_string();
            let frame = num(c.frame, "Frame")?;
            let f0 = *first_frame.get_or_insert(frame);
            let state = cell(c.state, "State")?.to_string();
            let vals: Vec<f64> = (0..8)
                .map(|d| {
                    num(
                        c.q0 + d,
                        ["Q0", "Qx", "Qy", "Qz", "Tx", "Ty", "Tz", "Error"][d],
                    )
                })
                .collect::<Result<_, _>>()?;
            let missing = state.eq_ignore_ascii_case("Missing")
                || state.eq_ignore_ascii_case("Disabled")
                || vals.iter().any(|v| v.abs() >= MISSING_ABS);
            let mut extra = Map::new();
            extra.insert("frame".into(), json!(frame));
            if !state.eq_ignore_ascii_case("OK") {
                extra.insert("state".into(), json!(state));
            }
            if missing {
                // No pose in this frame: nothing to record (counted, and said below).
                counts[k].1 += 1;
                continue;
            }
            let marker = {
                let q = [vals[0], vals[1], vals[2], vals[3]];
                let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
                if let Err(e) = crate::plausible::quat::unit_wxyz(&q) {
                    return Err(ImportError::bad(
                        file,
                        Some(ln),
                        Some("Q0,Qx,Qy,Qz"),
                        format!("{e} (a column shifted?)"),
                    ));
                }
                let p = [vals[4], vals[5], vals[6]];
                if p.iter().any(|v| v.abs() > 1e5) {
                    return Err(ImportError::bad(
                        file,
                        Some(ln),
                        Some("Tx,Ty,Tz"),
                        format!("position {p:?} mm is beyond ±100 m"),
                    ));
                }
                counts[k].2 += 1;
                super::marker_obs(p, Some(q.map(|v| v / n)), Some(vals[7]))
            };
            // Individual markers: the visible ones, by their index in the tool.
            if c.groups > 0 {
                let n_markers = num(c.markers, "Markers")?;
                if n_markers < 0.0 || n_markers.fract() != 0.0 || n_markers as usize > c.groups {
                    return Err(ImportError::bad(
                        file,
                        Some(ln),
                        Some("Markers"),
                        format!(
                            "{n_markers} markers, the header has columns for {}",
                            c.groups
                        ),
                    ));
                }
                let mut ms = vec![];
                for g in 0..n_markers as usize {
                    let base = c.markers + 1 + 4 * g;
                    let st = cell(base, "State")?;
                    let xyz = [
                        num(base + 1, "Tx")?,
                        num(base + 2, "Ty")?,
                        num(base + 3, "Tz")?,
                    ];
                    if !st.eq_ignore_ascii_case("Missing")
                        && xyz.iter().all(|v| v.abs() < MISSING_ABS)
                    {
                        ms.push(json!({"i": g, "p": xyz}));
                    }
                }
                extra.insert("markers".into(), Value::Array(ms));
            }
            counts[k].1 += 1;
            records.push(Record::Pivot(PivotRecord {
                t: (frame - f0) / rate_hz,
                tool: Some(name),
                marker,
                extra,
            }));
        }
    }
    if records.is_empty() {
        return Err(ImportError::bad(
            file,
            None,
            None,
            "no data rows after the header",
        ));
    }
    for (name, n, v) in &counts {
        if *v == 0 {
            warnings.push(format!(
                "tool \"{name}\": not seen in any of its {n} frames"
            ));
        } else if v < n {
            warnings.push(format!(
                "tool \"{name}\": {} of its {n} frames Missing (not imported)",
                n - v
            ));
        }
    }
    let mut hx = Map::new();
    hx.insert(
        "source".into(),
        json!({"file": file, "importer": "ndi-track-csv"}),
    );
    let dataset = Dataset {
        header: Header {
            format: DATASET_FORMAT.into(),
            created: None,
            robot: RobotBlock {
                model: crate::dataset::NO_ROBOT_MODEL.into(),
                serial: None,
                chain: None,
                flange: None,
                extra: Map::new(),
            },
            tool: None,
            tracker: Some(json!({"kind": "ndi", "export": "NDI Track CSV"})),
            range_sensor: None,
            plan: None,
            notes: None,
            extra: hx,
        },
        records,
    };
    Ok(NdiImport {
        dataset,
        tools: counts,
        warnings,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tiny export of our own: two tools, the second with two marker groups, a missing frame.
    fn fixture() -> String {
        let mut s = String::from("Tools,Probe A,Frame,Face,State,Q0,Qx,Qy,Qz,Tx,Ty,Tz,Error,Markers,State,Tx,Ty,Tz,State,Tx,Ty,Tz,Ref B,Frame,Face,State,Q0,Qx,Qy,Qz,Tx,Ty,Tz,Error,Markers,State,Tx,Ty,Tz\n");
        s += "2,Probe A,1000,1,OK,1.0,0.0,0.0,0.0,10.5,-20.25,-1500.0,0.12,2,OK,1.0,2.0,-1490.0,Missing,-3.697314E28,-3.697314E28,-3.697314E28,Ref B,1000,1,OK,0.7071068,0.7071068,0.0,0.0,100.0,0.0,-1600.0,0.2,1,OK,5.0,5.0,-1600.0\n";
        s += "2,Probe A,1003,1,Missing,-3.697314E28,-3.697314E28,-3.697314E28,-3.697314E28,-3.697314E28,-3.697314E28,-3.697314E28,-3.697314E28,2,Missing,-3.697314E28,-3.697314E28,-3.697314E28,Missing,-3.697314E28,-3.697314E28,-3.697314E28,Ref B,1003,1,Partially Out of Volume,0.7071068,0.7071068,0.0,0.0,100.5,0.0,-1600.0,0.3,1,OK,5.0,5.0,-1600.0\n";
        s
    }

    #[test]
    fn two_tools_with_repeated_marker_columns_and_missing_frames() {
        let r = parse_ndi(&fixture(), "track.csv", None, 60.0).unwrap();
        assert_eq!(
            r.tools,
            vec![("Probe A".to_string(), 2, 1), ("Ref B".to_string(), 2, 2)]
        );
        let pivots: Vec<&PivotRecord> = r
            .dataset
            .records
            .iter()
            .filter_map(|x| match x {
                Record::Pivot(p) => Some(p),
                _ => None,
            })
            .collect();
        assert_eq!(pivots.len(), 3, "the Missing frame is not imported");
        assert_eq!(pivots[0].marker.p, Some([10.5, -20.25, -1500.0]));
        assert_eq!(pivots[0].marker.rms, Some(0.12));
        assert_eq!(
            pivots[0].extra["markers"],
            json!([{"i": 0, "p": [1.0, 2.0, -1490.0]}])
        );
        assert_eq!(pivots[2].extra["state"], json!("Partially Out of Volume"));
        assert!((pivots[2].t - 0.05).abs() < 1e-12, "{}", pivots[2].t);
        assert!(
            r.warnings[0].contains("1 of its 2 frames Missing"),
            "{:?}",
            r.warnings
        );
        let only = parse_ndi(&fixture(), "track.csv", Some("Ref"), 60.0).unwrap();
        assert_eq!(only.dataset.records.len(), 2);
    }

    #[test]
    fn malformed_exports_name_line_and_column() {
        let f = fixture();
        let cases = [
            (
                f.replace(
                    "Qy,Qz,Tx,Ty,Tz,Error,Markers,State,Tx,Ty,Tz,State",
                    "Qy,Qz,Ty,Tx,Tz,Error,Markers,State,Tx,Ty,Tz,State",
                ),
                "track.csv:1",
                "\"Tx\"",
            ),
            (f.replace("10.5,", "10.5x,"), "track.csv:2", "not a number"),
            (
                f.replace("1.0,0.0,0.0,0.0,10.5", "2.0,0.0,0.0,0.0,10.5"),
                "track.csv:2",
                "norm",
            ),
            (
                f.lines().take(2).collect::<Vec<_>>().join("\n")[..300].to_string(),
                "track.csv:2",
                "truncated",
            ),
            (
                "id,x,y\n1,2,3\n".to_string(),
                "track.csv:1",
                "not an NDI Track",
            ),
            (String::new(), "track.csv", "empty"),
        ];
        for (text, at, want) in cases {
            let e = parse_ndi(&text, "track.csv", None, 60.0)
                .unwrap_err()
                .to_string();
            assert!(e.contains(at) && e.contains(want), "{at} {want}: {e}");
        }
    }
}
