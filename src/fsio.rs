//! Durable file writes: the one atomic-write helper every file robocal writes goes through
//! (temporary file in the same directory, fsync, rename over the target, fsync of the
//! directory), and the exclusive run-directory lock of `robocal run`.
//!
//! A crash (kill -9, power cut) at any moment leaves either the old file or the new one,
//! never a torn one; after [`write_atomic`] returns the new content and its directory entry
//! are on disk.
use std::io::Write as _;
use std::path::{Path, PathBuf};

/// The directory holding `path` (`.` for a bare file name).
fn parent_dir(path: &Path) -> &Path {
    path.parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// Fsyncs a directory, so a new entry or a rename in it survives a power cut.
pub fn sync_dir(dir: &Path) -> std::io::Result<()> {
    #[cfg(unix)]
    std::fs::File::open(dir)?.sync_all()?;
    #[cfg(not(unix))]
    let _ = dir;
    Ok(())
}

/// Writes `bytes` to `path` atomically and durably: a temporary file next to it
/// (`.<name>.tmp<pid>`), fsync, rename over `path`, fsync of the directory. On error the
/// temporary file is removed and `path` is unchanged.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = parent_dir(path);
    let name = path
        .file_name()
        .map_or_else(|| "out".into(), |n| n.to_string_lossy().into_owned());
    let tmp = dir.join(format!(".{name}.tmp{}", std::process::id()));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        drop(f);
        std::fs::rename(&tmp, path)?;
        sync_dir(dir)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// [`write_atomic`] with the signature of `std::fs::write` (a drop-in replacement).
pub fn write(path: impl AsRef<Path>, contents: impl AsRef<[u8]>) -> std::io::Result<()> {
    write_atomic(path.as_ref(), contents.as_ref())
}

/// [`write_atomic`] with the file named in the error (for `anyhow` callers).
pub fn write_atomic_ctx(path: impl AsRef<Path>, bytes: &[u8]) -> anyhow::Result<()> {
    let path = path.as_ref();
    write_atomic(path, bytes).map_err(|e| anyhow::anyhow!("writing {}: {e}", path.display()))
}

/// Creates `dir` (and its parents) and fsyncs the directory that holds it.
pub fn create_dir_durable(dir: &Path) -> std::io::Result<()> {
    if dir.is_dir() {
        return Ok(());
    }
    std::fs::create_dir_all(dir)?;
    sync_dir(parent_dir(dir))
}

/// Why a run directory could not be locked.
#[derive(Debug, thiserror::Error)]
pub enum LockError {
    /// Another process holds the lock.
    #[error(
        "{dir} is in use by another robocal process{holder}: wait for it to finish (or stop \
         it), then continue with `{}`",
        resume_command(dir),
        dir = dir.display(),
        holder = pid.map_or_else(String::new, |p| format!(" (pid {p})"))
    )]
    Busy {
        /// The run directory.
        dir: PathBuf,
        /// The holder's process id, as it wrote it into the lock file.
        pid: Option<u32>,
    },
    /// The lock file could not be opened or written.
    #[error("locking {}: {error}", file.display())]
    Io {
        /// The lock file.
        file: PathBuf,
        /// The cause.
        error: std::io::Error,
    },
}

/// The command that continues the run in `dir`: `robocal session --resume SESSION` when the run
/// belongs to a session (its parent holds `session.json`), else `robocal run --resume DIR`.
pub fn resume_command(dir: &Path) -> String {
    match dir.parent().filter(|p| p.join("session.json").is_file()) {
        Some(s) => format!("robocal session --resume {}", s.display()),
        None => format!("robocal run --resume {}", dir.display()),
    }
}

/// An exclusive OS lock on a run directory (`DIR/.lock`, holding the owner's PID), held for
/// as long as this value lives. It is an `flock` on an open file: the OS drops it when the
/// process ends in any way (kill -9 included), so a stale lock file never blocks a resume.
#[derive(Debug)]
pub struct DirLock {
    _file: std::fs::File,
    path: PathBuf,
}

/// Name of the lock file inside a run directory.
pub const LOCK_FILE: &str = ".lock";

impl DirLock {
    /// Takes the lock on `dir` (which must exist) without waiting: [`LockError::Busy`] with
    /// the holder's PID when another process has it.
    pub fn acquire(dir: &Path) -> Result<DirLock, LockError> {
        let path = dir.join(LOCK_FILE);
        let io = |error| LockError::Io {
            file: path.clone(),
            error,
        };
        let mut file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(io)?;
        match file.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                let pid = std::fs::read_to_string(&path)
                    .ok()
                    .and_then(|s| s.trim().parse().ok());
                return Err(LockError::Busy {
                    dir: dir.to_path_buf(),
                    pid,
                });
            }
            Err(std::fs::TryLockError::Error(e)) => return Err(io(e)),
        }
        file.set_len(0).map_err(io)?;
        writeln!(file, "{}", std::process::id()).map_err(io)?;
        file.sync_data().map_err(io)?;
        Ok(DirLock { _file: file, path })
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn write_atomic_replaces_whole_file_and_leaves_no_temp() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("a.json");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two two").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"two two");
        let names: Vec<_> = std::fs::read_dir(d.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names.len(), 1, "{names:?}");
    }

    #[test]
    fn write_atomic_error_names_nothing_left_behind() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("missing-dir").join("a.json");
        assert!(write_atomic(&p, b"x").is_err());
        assert!(write_atomic_ctx(&p, b"x")
            .unwrap_err()
            .to_string()
            .contains("missing-dir"));
    }

    #[test]
    fn second_lock_is_refused_with_the_holders_pid_and_released_on_drop() {
        let d = tempfile::tempdir().unwrap();
        let first = DirLock::acquire(d.path()).unwrap();
        // flock locks belong to the open file description: a second open in the same
        // process conflicts exactly as another process would.
        let err = DirLock::acquire(d.path()).unwrap_err();
        match &err {
            LockError::Busy { pid, .. } => assert_eq!(*pid, Some(std::process::id())),
            other => panic!("{other}"),
        }
        assert!(err
            .to_string()
            .contains(&format!("pid {}", std::process::id())));
        assert!(err.to_string().contains("robocal run --resume"), "{err}");
        drop(first);
        DirLock::acquire(d.path()).unwrap();
        // A run inside a session directory is continued through the session.
        let run = d.path().join("run-train");
        std::fs::create_dir(&run).unwrap();
        std::fs::write(d.path().join("session.json"), "{}").unwrap();
        let _held = DirLock::acquire(&run).unwrap();
        let err = DirLock::acquire(&run).unwrap_err().to_string();
        assert!(
            err.contains(&format!("robocal session --resume {}", d.path().display())),
            "{err}"
        );
    }
}
