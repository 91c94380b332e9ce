//! Fleet history: every session's result in a database keyed by robot serial.
//!
//! SQLite file by default (embedded, no server); the same schema on PostgreSQL when the
//! location is a `postgres://` / `postgresql://` URL (a fleet shared between sites). The
//! location comes from `--history`, else `ROBOCAL_DB`, else the user's data directory
//! (see [`location`]). One SQL text serves both (`$n` placeholders, standard types).
#![allow(clippy::type_complexity)]
use std::path::Path;

use thiserror::Error;

use super::{SessionFile, VerdictKind};

/// History database errors.
#[derive(Debug, Error)]
pub enum HistoryError {
    #[error("SQLite {path}: {source}")]
    Sqlite {
        path: String,
        source: rusqlite::Error,
    },
    #[error("PostgreSQL: {0}")]
    Postgres(#[from] postgres::Error),
    #[error("history: {0}")]
    Other(String),
}

/// The schema (both back-ends).
pub const SCHEMA: [&str; 2] = [
    "CREATE TABLE IF NOT EXISTS robocal_session (
        session_id TEXT PRIMARY KEY,
        robot_serial TEXT NOT NULL,
        robot_model TEXT NOT NULL,
        created TEXT NOT NULL,
        mode TEXT NOT NULL,
        verdict TEXT NOT NULL,
        accept TEXT NOT NULL,
        poses_planned BIGINT NOT NULL,
        poses_skipped BIGINT NOT NULL,
        heldout_rms_mm_before DOUBLE PRECISION,
        heldout_rms_mm_after DOUBLE PRECISION,
        heldout_max_mm_before DOUBLE PRECISION,
        heldout_max_mm_after DOUBLE PRECISION,
        relative_distance_pct_before DOUBLE PRECISION,
        relative_distance_pct_after DOUBLE PRECISION,
        datasets TEXT NOT NULL
    )",
    "CREATE TABLE IF NOT EXISTS robocal_param (
        session_id TEXT NOT NULL REFERENCES robocal_session(session_id) ON DELETE CASCADE,
        name TEXT NOT NULL,
        unit TEXT NOT NULL,
        nominal DOUBLE PRECISION NOT NULL,
        value DOUBLE PRECISION NOT NULL,
        ci95 DOUBLE PRECISION,
        PRIMARY KEY (session_id, name)
    )",
];

const INSERT_SESSION: &str = "INSERT INTO robocal_session VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11, $12, $13, $14, $15, $16)";
const DELETE_SESSION: &str = "DELETE FROM robocal_session WHERE session_id = $1";
const DELETE_PARAMS: &str = "DELETE FROM robocal_param WHERE session_id = $1";
const INSERT_PARAM: &str = "INSERT INTO robocal_param VALUES ($1, $2, $3, $4, $5, $6)";
const SELECT_SESSIONS: &str = "SELECT session_id, robot_model, created, mode, verdict, poses_planned, poses_skipped, heldout_rms_mm_before, heldout_rms_mm_after, relative_distance_pct_before, relative_distance_pct_after FROM robocal_session WHERE robot_serial = $1 ORDER BY created, session_id";
const SELECT_PARAMS: &str = "SELECT p.session_id, p.name, p.unit, p.value - p.nominal FROM robocal_param p JOIN robocal_session s ON s.session_id = p.session_id WHERE s.robot_serial = $1 ORDER BY s.created, p.session_id, p.name";

/// One session of a robot, as stored.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    pub session_id: String,
    pub robot_model: String,
    pub created: String,
    pub mode: String,
    pub verdict: String,
    pub poses_planned: i64,
    pub poses_skipped: i64,
    pub rms_before: Option<f64>,
    pub rms_after: Option<f64>,
    pub rel_before: Option<f64>,
    pub rel_after: Option<f64>,
    /// Parameter changes from nominal: (name, unit, value − nominal).
    pub params: Vec<(String, String, f64)>,
}

/// An open history database.
pub enum History {
    Sqlite(rusqlite::Connection, String),
    Postgres(Box<postgres::Client>),
}

/// The location: `--history` if given, else `ROBOCAL_DB`, else
/// `$XDG_DATA_HOME/robocal/history.sqlite` (`~/.local/share/robocal/history.sqlite`), else
/// `robocal-history.sqlite` in the current directory.
pub fn location(arg: Option<&str>) -> String {
    let env = |k: &str| std::env::var(k).ok().filter(|s| !s.is_empty());
    arg.map(str::to_string)
        .or_else(|| env("ROBOCAL_DB"))
        .or_else(|| {
            env("XDG_DATA_HOME")
                .map(std::path::PathBuf::from)
                .or_else(|| env("HOME").map(|h| Path::new(&h).join(".local/share")))
                .map(|d| d.join("robocal/history.sqlite").display().to_string())
        })
        .unwrap_or_else(|| "robocal-history.sqlite".into())
}

/// The URL schemes of a history location (anything else with `://` is refused).
pub const SUPPORTED: &str =
    "a SQLite file path, or a postgres:// (postgresql://) URL for PostgreSQL";

fn is_postgres(loc: &str) -> bool {
    loc.starts_with("postgres://") || loc.starts_with("postgresql://")
}

/// Checks a history location without creating or changing anything (before any device opens): an
/// unknown URL scheme (`mysql://`) is an error naming the supported ones; an existing path
/// must be a regular file holding a SQLite database that is empty or robocal's (a foreign
/// database never gets robocal's tables added). A missing file is fine here: a session
/// creates it. PostgreSQL URLs are checked when connecting.
pub fn check_location(loc: &str) -> Result<(), HistoryError> {
    if loc.trim().is_empty() {
        return Err(HistoryError::Other(format!(
            "empty history location: give {SUPPORTED}"
        )));
    }
    if is_postgres(loc) {
        return Ok(());
    }
    if let Some((scheme, _)) = loc.split_once("://") {
        return Err(HistoryError::Other(format!(
            "{loc}: unknown history URL scheme \"{scheme}://\": supported are {SUPPORTED}"
        )));
    }
    let path = Path::new(loc);
    match std::fs::metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(HistoryError::Other(format!("{loc}: {e}"))),
        Ok(m) if !m.is_file() => Err(HistoryError::Other(format!(
            "{loc} is not a regular file (a directory or device): give the history's SQLite \
             file"
        ))),
        Ok(m) if m.len() == 0 => Ok(()),
        Ok(_) => {
            let c = open_sqlite_read_only(loc)?;
            robocal_tables(&c, loc).map(|_| ())
        }
    }
}

fn open_sqlite_read_only(loc: &str) -> Result<rusqlite::Connection, HistoryError> {
    rusqlite::Connection::open_with_flags(
        loc,
        rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY | rusqlite::OpenFlags::SQLITE_OPEN_NO_MUTEX,
    )
    .map_err(|source| HistoryError::Sqlite {
        path: loc.into(),
        source,
    })
}

/// Whether the SQLite database holds robocal's tables (`true`) or no table at all (`false`);
/// an error for a file that is not SQLite or a database with other tables.
fn robocal_tables(c: &rusqlite::Connection, loc: &str) -> Result<bool, HistoryError> {
    let names: Vec<String> = c
        .prepare("SELECT name FROM sqlite_master WHERE type = 'table' ORDER BY name")
        .and_then(|mut st| {
            st.query_map([], |r| r.get::<_, String>(0))?
                .collect::<Result<Vec<_>, _>>()
        })
        .map_err(|e| {
            HistoryError::Other(format!(
                "{loc} is not a SQLite database ({e}): give robocal's history file"
            ))
        })?;
    if names.is_empty() {
        return Ok(false);
    }
    if names.iter().any(|n| n == "robocal_session") {
        return Ok(true);
    }
    Err(HistoryError::Other(format!(
        "{loc} is a SQLite database of something else (tables: {}), not a robocal history: \
         robocal does not add its tables to a foreign database; give another --history / --db",
        names.join(", ")
    )))
}

impl History {
    /// Opens the database at `loc` for queries only (`robocal history`): nothing is created
    /// or altered. A missing SQLite file, an empty or foreign database and an unknown URL
    /// scheme are errors.
    pub fn open_read_only(loc: &str) -> Result<History, HistoryError> {
        check_location(loc)?;
        if is_postgres(loc) {
            let c = postgres::Client::connect(loc, postgres::NoTls)?;
            return Ok(History::Postgres(Box::new(c)));
        }
        if !Path::new(loc).is_file() {
            return Err(HistoryError::Other(format!(
                "{loc}: no history database there (nothing was recorded at this location; \
                 check --db / ROBOCAL_DB)"
            )));
        }
        let c = open_sqlite_read_only(loc)?;
        if !robocal_tables(&c, loc)? {
            return Err(HistoryError::Other(format!(
                "{loc}: an empty database, no session recorded in it"
            )));
        }
        Ok(History::Sqlite(c, loc.into()))
    }

    /// Open (and create the schema in) the database at `loc`: a `postgres://` URL or a
    /// SQLite file path ([`check_location`] first: never a foreign database).
    pub fn open(loc: &str) -> Result<History, HistoryError> {
        check_location(loc)?;
        if is_postgres(loc) {
            let mut c = postgres::Client::connect(loc, postgres::NoTls)?;
            for s in SCHEMA {
                c.batch_execute(s)?;
            }
            Ok(History::Postgres(Box::new(c)))
        } else {
            let sq = |source| HistoryError::Sqlite {
                path: loc.into(),
                source,
            };
            if let Some(p) = Path::new(loc)
                .parent()
                .filter(|p| !p.as_os_str().is_empty())
            {
                std::fs::create_dir_all(p)
                    .map_err(|e| HistoryError::Other(format!("{}: {e}", p.display())))?;
            }
            let c = rusqlite::Connection::open(loc).map_err(sq)?;
            c.execute_batch("PRAGMA foreign_keys = ON;").map_err(sq)?;
            for s in SCHEMA {
                c.execute_batch(s).map_err(sq)?;
            }
            Ok(History::Sqlite(c, loc.into()))
        }
    }

    /// Record (or replace) a finished session. The session id is the SHA-256 of its
    /// training dataset (a session is its data).
    pub fn record(&mut self, s: &SessionFile) -> Result<String, HistoryError> {
        let id = s
            .datasets
            .iter()
            .find(|d| d.role == "train")
            .map(|d| d.sha256.clone())
            .ok_or_else(|| HistoryError::Other("the session has no training dataset yet".into()))?;
        let serial = s
            .cell
            .robot_serial
            .clone()
            .unwrap_or_else(|| "unknown".into());
        let m = &s.measured;
        let verdict = match s.verdict {
            VerdictKind::Pass => "PASS",
            VerdictKind::Fail => "FAIL",
            VerdictKind::Incomplete => "INCOMPLETE",
        };
        let mode = match s.setup.mode {
            super::Mode::Sim => "sim",
            super::Mode::Live => "live",
        };
        let datasets = s.dataset_hashes().to_string();
        let planned = s.poses_planned as i64;
        let skipped = s.poses_skipped as i64;
        match self {
            History::Sqlite(c, loc) => {
                let sq = |source| HistoryError::Sqlite {
                    path: loc.clone(),
                    source,
                };
                let tx = c.transaction().map_err(sq)?;
                tx.execute(DELETE_PARAMS, [&id]).map_err(sq)?;
                tx.execute(DELETE_SESSION, [&id]).map_err(sq)?;
                tx.execute(
                    INSERT_SESSION,
                    rusqlite::params![
                        id,
                        serial,
                        s.cell.robot_model,
                        s.created,
                        mode,
                        verdict,
                        s.accept.name,
                        planned,
                        skipped,
                        m.heldout_rms_mm_before,
                        m.heldout_rms_mm_after,
                        m.heldout_max_mm_before,
                        m.heldout_max_mm_after,
                        m.relative_distance_pct_before,
                        m.relative_distance_pct_after,
                        datasets
                    ],
                )
                .map_err(sq)?;
                for p in &s.params {
                    tx.execute(
                        INSERT_PARAM,
                        rusqlite::params![id, p.name, p.unit, p.nominal, p.value, p.ci95],
                    )
                    .map_err(sq)?;
                }
                tx.commit().map_err(sq)?;
            }
            History::Postgres(c) => {
                let mut tx = c.transaction()?;
                tx.execute(DELETE_PARAMS, &[&id])?;
                tx.execute(DELETE_SESSION, &[&id])?;
                tx.execute(
                    INSERT_SESSION,
                    &[
                        &id,
                        &serial,
                        &s.cell.robot_model,
                        &s.created,
                        &mode,
                        &verdict,
                        &s.accept.name,
                        &planned,
                        &skipped,
                        &m.heldout_rms_mm_before,
                        &m.heldout_rms_mm_after,
                        &m.heldout_max_mm_before,
                        &m.heldout_max_mm_after,
                        &m.relative_distance_pct_before,
                        &m.relative_distance_pct_after,
                        &datasets,
                    ],
                )?;
                for p in &s.params {
                    tx.execute(
                        INSERT_PARAM,
                        &[&id, &p.name, &p.unit, &p.nominal, &p.value, &p.ci95],
                    )?;
                }
                tx.commit()?;
            }
        }
        Ok(id)
    }

    /// Every robot in the history: serial, model and how many sessions, sorted by serial.
    pub fn robots(&mut self) -> Result<Vec<(String, String, i64)>, HistoryError> {
        const Q: &str = "SELECT robot_serial, MAX(robot_model), COUNT(*) FROM robocal_session \
                         GROUP BY robot_serial ORDER BY robot_serial";
        match self {
            History::Sqlite(c, loc) => {
                let sq = |source| HistoryError::Sqlite {
                    path: loc.clone(),
                    source,
                };
                let mut st = c.prepare(Q).map_err(sq)?;
                let rows = st
                    .query_map([], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)))
                    .map_err(sq)?
                    .collect::<Result<Vec<_>, _>>()
                    .map_err(sq)?;
                Ok(rows)
            }
            History::Postgres(c) => Ok(c
                .query(Q, &[])?
                .iter()
                .map(|r| (r.get(0), r.get(1), r.get(2)))
                .collect()),
        }
    }

    /// The sessions of one robot, oldest first, with their parameter changes.
    pub fn robot(&mut self, serial: &str) -> Result<Vec<Row>, HistoryError> {
        type Raw = (
            String,
            String,
            String,
            String,
            String,
            i64,
            i64,
            Option<f64>,
            Option<f64>,
            Option<f64>,
            Option<f64>,
        );
        let (raw, params): (Vec<Raw>, Vec<(String, String, String, f64)>) = match self {
            History::Sqlite(c, loc) => {
                let sq = |source| HistoryError::Sqlite {
                    path: loc.clone(),
                    source,
                };
                let mut st = c.prepare(SELECT_SESSIONS).map_err(sq)?;
                let raw = st
                    .query_map([serial], |r| {
                        Ok((
                            r.get(0)?,
                            r.get(1)?,
                            r.get(2)?,
                            r.get(3)?,
                            r.get(4)?,
                            r.get(5)?,
                            r.get(6)?,
                            r.get(7)?,
                            r.get(8)?,
                            r.get(9)?,
                            r.get(10)?,
                        ))
                    })
                    .map_err(sq)?
                    .collect::<Result<Vec<_>, _>>()
                    .map_err(sq)?;
                let mut st = c.prepare(SELECT_PARAMS).map_err(sq)?;
                let params = st
                    .query_map([serial], |r| {
                        Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?))
                    })
                    .map_err(sq)?
                    .collect::<Result<Vec<_>, _>>()
                    .map_err(sq)?;
                (raw, params)
            }
            History::Postgres(c) => {
                let raw = c
                    .query(SELECT_SESSIONS, &[&serial])?
                    .iter()
                    .map(|r| {
                        (
                            r.get(0),
                            r.get(1),
                            r.get(2),
                            r.get(3),
                            r.get(4),
                            r.get(5),
                            r.get(6),
                            r.get(7),
                            r.get(8),
                            r.get(9),
                            r.get(10),
                        )
                    })
                    .collect();
                let params = c
                    .query(SELECT_PARAMS, &[&serial])?
                    .iter()
                    .map(|r| (r.get(0), r.get(1), r.get(2), r.get(3)))
                    .collect();
                (raw, params)
            }
        };
        Ok(raw
            .into_iter()
            .map(|r| Row {
                params: params
                    .iter()
                    .filter(|p| p.0 == r.0)
                    .map(|p| (p.1.clone(), p.2.clone(), p.3))
                    .collect(),
                session_id: r.0,
                robot_model: r.1,
                created: r.2,
                mode: r.3,
                verdict: r.4,
                poses_planned: r.5,
                poses_skipped: r.6,
                rms_before: r.7,
                rms_after: r.8,
                rel_before: r.9,
                rel_after: r.10,
            })
            .collect())
    }
}

/// The history of a robot as a text table.
pub fn table(serial: &str, rows: &[Row]) -> String {
    use std::fmt::Write as _;
    let f = |v: Option<f64>, p: usize| v.map_or("—".into(), |x| format!("{x:.p$}"));
    let mut s = format!("history of robot {serial}: {} session(s)\n", rows.len());
    let _ = writeln!(
        s,
        "{:<20} {:<5} {:<10} {:>9} {:>17} {:>17}",
        "created", "mode", "verdict", "skipped", "held-out RMS mm", "rel. distance %"
    );
    for r in rows {
        let _ = writeln!(
            s,
            "{:<20} {:<5} {:<10} {:>9} {:>17} {:>17}",
            r.created.chars().take(19).collect::<String>(),
            r.mode,
            r.verdict,
            format!("{}/{}", r.poses_skipped, r.poses_planned),
            format!("{} → {}", f(r.rms_before, 3), f(r.rms_after, 3)),
            format!("{} → {}", f(r.rel_before, 3), f(r.rel_after, 3)),
        );
    }
    s
}

/// SVG: held-out RMS before / after per session (accuracy drift).
pub fn svg(serial: &str, rows: &[Row]) -> String {
    let b: Vec<f64> = rows
        .iter()
        .map(|r| r.rms_before.unwrap_or(f64::NAN))
        .collect();
    let a: Vec<f64> = rows
        .iter()
        .map(|r| r.rms_after.unwrap_or(f64::NAN))
        .collect();
    super::svg::before_after(
        &format!("Robot {serial}: held-out RMS per session"),
        "session (oldest first)",
        &b,
        &a,
    )
}
