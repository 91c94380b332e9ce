//! Append-only dataset journal: what an acquisition writes while the robot moves.
//!
//! Every [`Journal::append`] writes one whole line, flushes and fsyncs before it returns,
//! so the record survives a power cut that happens during the next motion. Reopening a
//! journal after a crash truncates a torn last line (see [`super::read_dataset`]) and
//! continues after the last whole record.
use std::fs::{File, OpenOptions};
use std::io::Write as _;
use std::path::{Path, PathBuf};

use super::error::{DatasetError, LoadWarning};
use super::io::{check_header, parse_dataset, to_line, Loaded, Validator};
use super::types::{Dataset, Header, Record};

/// An open, append-only `robocal-dataset/1` file.
#[derive(Debug)]
pub struct Journal {
    path: PathBuf,
    file: File,
    header: Header,
    validator: Validator,
    /// Number of lines in the file (header included).
    lines: usize,
    last_pose_id: Option<u64>,
}

impl Journal {
    /// Creates a new journal holding only `header`; fails if `path` exists.
    pub fn create(path: impl AsRef<Path>, header: &Header) -> Result<Journal, DatasetError> {
        let path = path.as_ref();
        // The header must pass the reader's checks or the journal could never be read.
        let value = serde_json::to_value(header).map_err(|e| DatasetError::Invalid {
            at: super::error::Location {
                file: path.to_path_buf(),
                line: Some(1),
            },
            msg: e.to_string(),
        })?;
        let header = check_header(value).map_err(|p| p.at(path, Some(1)))?;
        let mut file = OpenOptions::new()
            .append(true)
            .create_new(true)
            .open(path)
            .map_err(|e| DatasetError::io(path, e))?;
        let io = |e| DatasetError::io(path, e);
        file.write_all(to_line(&header).as_bytes()).map_err(io)?;
        file.flush().map_err(io)?;
        file.sync_all().map_err(io)?;
        sync_parent_dir(path);
        Ok(Journal {
            path: path.to_path_buf(),
            file,
            validator: Validator::new(&header),
            header,
            lines: 1,
            last_pose_id: None,
        })
    }

    /// Opens an existing journal for appending. The file is read strictly; a torn last
    /// line is truncated away (and reported in the returned [`Loaded`]'s warnings).
    pub fn open(path: impl AsRef<Path>) -> Result<(Journal, Loaded), DatasetError> {
        let path = path.as_ref();
        let bytes = crate::fsio::read(path).map_err(|e| DatasetError::io(path, e))?;
        let loaded = parse_dataset(&bytes, path)?;
        let io = |e| DatasetError::io(path, e);
        let mut file = OpenOptions::new().append(true).open(path).map_err(io)?;
        if loaded.valid_len < bytes.len() as u64 {
            file.set_len(loaded.valid_len).map_err(io)?;
        }
        let valid = &bytes[..loaded.valid_len as usize];
        if valid.last().is_some_and(|&b| b != b'\n') {
            // The last whole line lacked its newline: end it before appending.
            file.write_all(b"\n").map_err(io)?;
        }
        file.sync_all().map_err(io)?;
        let mut validator = Validator::new(&loaded.dataset.header);
        let mut last_pose_id = None;
        for r in &loaded.dataset.records {
            if let Record::Pose(p) = r {
                last_pose_id = Some(p.id);
            }
            // Already validated by the reader; this only replays the id order.
            validator.note(r);
        }
        let lines = 1 + loaded.dataset.records.len();
        Ok((
            Journal {
                path: path.to_path_buf(),
                file,
                header: loaded.dataset.header.clone(),
                validator,
                lines,
                last_pose_id,
            },
            loaded,
        ))
    }

    /// Opens `path` for appending if it holds a journal, else creates it with `header`.
    /// A file that holds nothing but a torn header (a crash while creating it) is
    /// recreated. Returns the records already present and any warnings.
    pub fn open_or_create(
        path: impl AsRef<Path>,
        header: &Header,
    ) -> Result<(Journal, Vec<Record>, Vec<LoadWarning>), DatasetError> {
        let path = path.as_ref();
        match crate::fsio::read(path) {
            Ok(bytes)
                if bytes.contains(&b'\n')
                    || serde_json::from_slice::<serde_json::Value>(&bytes).is_ok() =>
            {
                let (j, loaded) = Journal::open(path)?;
                Ok((j, loaded.dataset.records, loaded.warnings))
            }
            Ok(_) => {
                std::fs::remove_file(path).map_err(|e| DatasetError::io(path, e))?;
                Ok((Journal::create(path, header)?, Vec::new(), Vec::new()))
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                Ok((Journal::create(path, header)?, Vec::new(), Vec::new()))
            }
            Err(e) => Err(DatasetError::io(path, e)),
        }
    }

    /// Appends one record as one line; returns after the line is flushed and fsync'd.
    /// The record is checked exactly as the reader would check it (dof, quaternions,
    /// increasing pose ids), so a journal always reads back.
    pub fn append(&mut self, rec: &Record) -> Result<(), DatasetError> {
        let line_no = self.lines + 1;
        let value = serde_json::to_value(rec).map_err(|e| DatasetError::Invalid {
            at: super::error::Location {
                file: self.path.clone(),
                line: Some(line_no),
            },
            msg: e.to_string(),
        })?;
        let mut v = self.validator.clone();
        v.record(value)
            .map_err(|p| p.at(&self.path, Some(line_no)))?;
        let line = to_line(rec);
        let io = |e| DatasetError::io(&self.path, e);
        self.file.write_all(line.as_bytes()).map_err(io)?;
        self.file.flush().map_err(io)?;
        self.file.sync_data().map_err(io)?;
        self.validator = v;
        self.lines = line_no;
        if let Record::Pose(p) = rec {
            self.last_pose_id = Some(p.id);
        }
        Ok(())
    }

    /// The journal's header.
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Number of lines written so far (header included).
    pub fn lines(&self) -> usize {
        self.lines
    }

    /// Id of the last pose record, if any.
    pub fn last_pose_id(&self) -> Option<u64> {
        self.last_pose_id
    }

    /// Reads the whole journal back from disk.
    pub fn read_back(&self) -> Result<Dataset, DatasetError> {
        Dataset::load(&self.path)
    }
}

fn sync_parent_dir(path: &Path) {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
}
