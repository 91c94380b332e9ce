//! A delimited text table (CSV with any one-byte delimiter, optional decimal comma) with the
//! file line of every row, so every value error names file, line and column.
use super::error::ImportError;

/// A parsed table: the header's column names and the data rows with their file lines.
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    /// The file as named in errors.
    pub file: String,
    pub columns: Vec<String>,
    /// `(1-based file line, fields)`; the header is line 1.
    pub rows: Vec<(usize, Vec<String>)>,
    /// Numbers use a decimal comma (`1,5`).
    pub decimal_comma: bool,
}

impl Table {
    /// Parse `text`; `file` names it in errors. Empty lines are skipped; a row with another
    /// number of fields than the header is an error.
    pub fn parse(
        text: &str,
        file: &str,
        delimiter: u8,
        decimal_comma: bool,
    ) -> Result<Table, ImportError> {
        if decimal_comma && delimiter == b',' {
            return Err(ImportError::Usage(format!(
                "{file}: a decimal comma needs another delimiter than ',' (e.g. --delimiter ';')"
            )));
        }
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        // The csv reader's line numbers are off by one after CRLF line ends: count on LF.
        let lf;
        let text = if text.contains('\r') {
            lf = text.replace("\r\n", "\n");
            lf.as_str()
        } else {
            text
        };
        let mut rd = csv::ReaderBuilder::new()
            .delimiter(delimiter)
            .has_headers(true)
            .flexible(true)
            .trim(csv::Trim::All)
            .from_reader(text.as_bytes());
        let columns: Vec<String> = match rd.headers() {
            Ok(h) => h.iter().map(str::to_string).collect(),
            Err(e) => return Err(ImportError::bad(file, Some(1), None, e.to_string())),
        };
        if columns.iter().all(String::is_empty) {
            return Err(ImportError::bad(
                file,
                Some(1),
                None,
                "empty file: expected a header row naming the columns",
            ));
        }
        if columns.len() == 1 && delimiter != b',' && columns[0].contains(',') {
            return Err(ImportError::bad(
                file,
                Some(1),
                None,
                format!(
                    "the header has one column \"{}\": the file seems to use ',' as delimiter, not '{}'",
                    short(&columns[0]),
                    delimiter as char
                ),
            ));
        }
        if columns.len() == 1 && delimiter == b',' && columns[0].contains(';') {
            return Err(ImportError::bad(
                file,
                Some(1),
                None,
                format!(
                    "the header has one column \"{}\": the file seems to use ';' as delimiter (try --delimiter ';' --decimal-comma)",
                    short(&columns[0])
                ),
            ));
        }
        let mut rows = Vec::new();
        for rec in rd.records() {
            let rec = match rec {
                Ok(r) => r,
                Err(e) => {
                    let line = e.position().map(|p| p.line() as usize);
                    return Err(ImportError::bad(file, line, None, e.to_string()));
                }
            };
            let line = rec.position().map_or(0, |p| p.line() as usize);
            if rec.iter().all(str::is_empty) {
                continue;
            }
            if rec.len() != columns.len() {
                return Err(ImportError::bad(
                    file,
                    Some(line),
                    None,
                    format!(
                        "{} fields, the header has {} columns (wrong delimiter, or a decimal comma in a ','-separated file?)",
                        rec.len(),
                        columns.len()
                    ),
                ));
            }
            rows.push((line, rec.iter().map(str::to_string).collect()));
        }
        if rows.is_empty() {
            return Err(ImportError::bad(
                file,
                None,
                None,
                "no data rows after the header",
            ));
        }
        Ok(Table {
            file: file.to_string(),
            columns,
            rows,
            decimal_comma,
        })
    }

    /// Index of column `name`; an unknown name lists the columns that exist.
    pub fn col(&self, name: &str) -> Result<usize, ImportError> {
        self.columns.iter().position(|c| c == name).ok_or_else(|| {
            let hint = self
                .columns
                .iter()
                .find(|c| c.eq_ignore_ascii_case(name))
                .map(|c| format!(" (did you mean \"{c}\"? names are case-sensitive)"))
                .unwrap_or_default();
            ImportError::bad(
                &self.file,
                Some(1),
                Some(name),
                format!(
                    "no such column{hint}; the header has: {}",
                    self.columns
                        .iter()
                        .map(|c| format!("\"{c}\""))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            )
        })
    }

    /// Index of column `name` when it exists.
    pub fn has(&self, name: &str) -> Option<usize> {
        self.columns.iter().position(|c| c == name)
    }

    /// Three numbers of `row` (an x, y, z triple) from the columns `cols[0..3]`.
    pub fn num3(&self, row: usize, cols: &[usize]) -> Result<[f64; 3], ImportError> {
        Ok([
            self.num(row, cols[0])?,
            self.num(row, cols[1])?,
            self.num(row, cols[2])?,
        ])
    }
    /// The number in row `row` (index into `rows`), column `col`: finite, else an error
    /// naming file, line and column.
    pub fn num(&self, row: usize, col: usize) -> Result<f64, ImportError> {
        let (line, fields) = &self.rows[row];
        let raw = fields[col].as_str();
        let colname = self.columns[col].as_str();
        let err = |msg: String| ImportError::bad(&self.file, Some(*line), Some(colname), msg);
        if raw.is_empty() {
            return Err(err("empty value (a number is needed)".into()));
        }
        let s = if self.decimal_comma {
            if raw.contains('.') && raw.contains(',') {
                return Err(err(format!(
                    "\"{}\" has both '.' and ',' (thousands separators are not supported)",
                    short(raw)
                )));
            }
            raw.replace(',', ".")
        } else {
            if raw.contains(',') {
                return Err(err(format!(
                    "\"{}\" is not a number (a decimal comma? then use --decimal-comma)",
                    short(raw)
                )));
            }
            raw.to_string()
        };
        let v: f64 = s.parse().map_err(|_| {
            err(format!(
                "\"{}\" is not a number{}",
                short(raw),
                if !self.decimal_comma && raw.contains(',') {
                    " (decimal comma?)"
                } else {
                    ""
                }
            ))
        })?;
        if !v.is_finite() {
            return Err(err(format!("\"{}\" is not a finite number", short(raw))));
        }
        Ok(v)
    }

    /// The raw text of a field.
    pub fn text(&self, row: usize, col: usize) -> &str {
        &self.rows[row].1[col]
    }

    /// The file line of row `row`.
    pub fn line(&self, row: usize) -> usize {
        self.rows[row].0
    }
}

fn short(s: &str) -> String {
    if s.chars().count() > 40 {
        format!("{}...", s.chars().take(37).collect::<String>())
    } else {
        s.to_string()
    }
}
