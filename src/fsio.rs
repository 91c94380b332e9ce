//! Durable file writes: the one atomic-write helper every file robocal writes goes through
//! (temporary file in the same directory, fsync, rename over the target, fsync of the
//! directory), the bounded reader every input file goes through ([`read`],
//! [`read_to_string`]), and the exclusive run-directory lock of `robocal run`.
//!
//! A crash (kill -9, power cut) at any moment leaves either the old file or the new one,
//! never a torn one; after [`write_atomic`] returns the new content and its directory entry
//! are on disk.
//!
//! Trust at the boundary: the writer only ever replaces a regular file. An
//! existing target that is a device, FIFO, socket or directory is refused (renaming over
//! `/dev/null` would break the host); a symbolic link is resolved and its regular-file target
//! written (the link stays a link); a dangling link is refused. Temporary files a killed
//! writer left behind (`.<name>.tmp<pid>` of a process that no longer runs) are removed on the
//! next write of the same file. The reader refuses anything but a regular file (a FIFO would
//! block forever, `/dev/zero` never ends) and files larger than [`MAX_INPUT_BYTES`].
use std::io::{Read as _, Write as _};
use std::path::{Path, PathBuf};

/// Largest input file robocal reads whole (bytes): 512 MiB. Every file robocal reads is far
/// smaller (the largest real dataset is a few MB; images are read by the camera drivers).
pub const MAX_INPUT_BYTES: u64 = 512 << 20;

/// What the file at `path` is, for messages ("a character device", "a regular file", ...;
/// "missing" when it does not exist).
pub fn describe(path: &Path) -> &'static str {
    match std::fs::symlink_metadata(path) {
        Err(_) => "missing",
        Ok(m) if m.file_type().is_file() => "a regular file",
        Ok(m) => kind_name(&m.file_type()),
    }
}

/// What a non-regular file is, for messages.
fn kind_name(ft: &std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt as _;
        if ft.is_fifo() {
            return "a FIFO (named pipe)";
        }
        if ft.is_char_device() {
            return "a character device";
        }
        if ft.is_block_device() {
            return "a block device";
        }
        if ft.is_socket() {
            return "a socket";
        }
    }
    if ft.is_dir() {
        "a directory"
    } else if ft.is_symlink() {
        "a symbolic link"
    } else {
        "not a regular file"
    }
}

fn invalid(msg: String) -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::InvalidInput, msg)
}

/// Checks that `path` is a regular file of at most [`MAX_INPUT_BYTES`] (symbolic links
/// followed) and returns its size. The error names what the path is instead (a FIFO, a
/// device, a directory) and why it is refused. Nothing is opened, so a FIFO never blocks.
pub fn check_input(path: &Path) -> std::io::Result<u64> {
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(invalid(format!(
            "{}, not a regular file: give a file (reading a FIFO, device or socket could block \
             forever or never end)",
            kind_name(&meta.file_type())
        )));
    }
    if meta.len() > MAX_INPUT_BYTES {
        return Err(invalid(format!(
            "{} bytes, more than the {} MiB robocal reads from one input file: not an input \
             file of robocal (a wrong path?)",
            meta.len(),
            MAX_INPUT_BYTES >> 20
        )));
    }
    Ok(meta.len())
}

/// Reads a whole input file, bounded: a regular file ([`check_input`]) and never more than
/// [`MAX_INPUT_BYTES`] (a file that grows while it is read included). The drop-in replacement
/// of `std::fs::read` for every input robocal reads.
pub fn read(path: impl AsRef<Path>) -> std::io::Result<Vec<u8>> {
    let path = path.as_ref();
    let len = check_input(path)?;
    let f = std::fs::File::open(path)?;
    let mut buf = Vec::with_capacity(len as usize);
    f.take(MAX_INPUT_BYTES + 1).read_to_end(&mut buf)?;
    if buf.len() as u64 > MAX_INPUT_BYTES {
        return Err(invalid(format!(
            "grew past {} MiB while it was read: not an input file of robocal",
            MAX_INPUT_BYTES >> 20
        )));
    }
    Ok(buf)
}

/// [`read`] as UTF-8 text (the drop-in replacement of `std::fs::read_to_string`).
pub fn read_to_string(path: impl AsRef<Path>) -> std::io::Result<String> {
    String::from_utf8(read(path)?).map_err(|e| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "not UTF-8 text (invalid byte at offset {}): a binary file or another encoding",
                e.utf8_error().valid_up_to()
            ),
        )
    })
}

/// The file [`write_atomic`] may replace for `path`: `path` itself when it does not exist or
/// is a regular file; the final target of a symbolic link when that is a regular file (the
/// link is kept); an error for anything else (device, FIFO, socket, directory, dangling link).
pub fn output_target(path: &Path) -> std::io::Result<PathBuf> {
    let meta = match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(path.to_path_buf()),
        Err(e) => return Err(e),
        Ok(m) => m,
    };
    if meta.is_file() {
        return Ok(path.to_path_buf());
    }
    if meta.file_type().is_symlink() {
        let target = std::fs::canonicalize(path).map_err(|_| {
            invalid(
                "a symbolic link to a missing file: refusing to replace the link (give the \
                 target's path, or remove the link)"
                    .to_string(),
            )
        })?;
        let tm = std::fs::metadata(&target)?;
        if tm.is_file() {
            return Ok(target);
        }
        return Err(invalid(format!(
            "a symbolic link to {}, which is {}: robocal writes only regular files \
             (replacing it would destroy it)",
            target.display(),
            kind_name(&tm.file_type())
        )));
    }
    Err(invalid(format!(
        "{}, not a regular file: robocal writes only regular files (replacing it would destroy \
         it); give another output path",
        kind_name(&meta.file_type())
    )))
}

/// Whether process `pid` runs (Linux: `/proc/<pid>`; elsewhere assumed running).
fn pid_alive(pid: u32) -> bool {
    if cfg!(target_os = "linux") {
        Path::new(&format!("/proc/{pid}")).exists()
    } else {
        true
    }
}

/// Removes the temporary files `.<name>.tmp<pid>` in `dir` that a killed writer of a process
/// no longer running left behind (regular files only).
fn clean_stale_temps(dir: &Path, name: &str) {
    let prefix = format!(".{name}.tmp");
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let file_name = e.file_name();
        let Some(pid) = file_name
            .to_str()
            .and_then(|n| n.strip_prefix(&prefix))
            .and_then(|p| p.parse::<u32>().ok())
        else {
            continue;
        };
        let regular = e.file_type().is_ok_and(|t| t.is_file());
        if regular && pid != std::process::id() && !pid_alive(pid) {
            let _ = std::fs::remove_file(e.path());
        }
    }
}

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
///
/// Only a regular file is ever replaced ([`output_target`]): a device, FIFO, socket or
/// directory at `path` is an error, a symbolic link is written through (the link is kept).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let target = output_target(path)?;
    let path = target.as_path();
    let dir = parent_dir(path);
    let name = path
        .file_name()
        .map_or_else(|| "out".into(), |n| n.to_string_lossy().into_owned());
    clean_stale_temps(dir, &name);
    let tmp = dir.join(format!(".{name}.tmp{}", std::process::id()));
    // A temporary file of this process from an earlier, failed write (or anything an attacker
    // placed there): never written through, removed first, then created exclusively.
    if std::fs::symlink_metadata(&tmp).is_ok_and(|m| !m.is_dir()) {
        let _ = std::fs::remove_file(&tmp);
    }
    let result = (|| {
        let mut f = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)?;
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
    #[cfg(unix)]
    use std::os::unix::fs::FileTypeExt as _;

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

    /// A FIFO named `fifo` in `dir`.
    #[cfg(unix)]
    fn mkfifo(dir: &std::path::Path) -> std::path::PathBuf {
        let fifo = dir.join("fifo");
        assert!(std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success());
        fifo
    }

    #[cfg(unix)]
    #[test]
    fn write_atomic_never_replaces_what_is_not_a_regular_file() {
        let d = tempfile::tempdir().unwrap();
        // A FIFO and a directory are refused and stay what they are.
        let fifo = mkfifo(d.path());
        let e = write_atomic(&fifo, b"x").unwrap_err().to_string();
        assert!(
            e.contains("FIFO") && e.contains("not a regular file"),
            "{e}"
        );
        assert!(std::fs::symlink_metadata(&fifo)
            .unwrap()
            .file_type()
            .is_fifo());
        let dir = d.path().join("dir");
        std::fs::create_dir(&dir).unwrap();
        let e = write_atomic(&dir, b"x").unwrap_err().to_string();
        assert!(e.contains("a directory"), "{e}");
        assert!(dir.is_dir());
        // A symbolic link to a regular file: the target is written, the link stays a link.
        let real = d.path().join("real.json");
        std::fs::write(&real, "old").unwrap();
        let link = d.path().join("link.json");
        std::os::unix::fs::symlink(&real, &link).unwrap();
        write_atomic(&link, b"new").unwrap();
        assert!(std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
        assert_eq!(std::fs::read(&real).unwrap(), b"new");
        // A link to a FIFO or a missing file is refused.
        let to_fifo = d.path().join("to-fifo");
        std::os::unix::fs::symlink(&fifo, &to_fifo).unwrap();
        let e = write_atomic(&to_fifo, b"x").unwrap_err().to_string();
        assert!(e.contains("FIFO"), "{e}");
        let dangling = d.path().join("dangling");
        std::os::unix::fs::symlink(d.path().join("missing"), &dangling).unwrap();
        let e = write_atomic(&dangling, b"x").unwrap_err().to_string();
        assert!(e.contains("missing file"), "{e}");
        assert!(!d.path().join("missing").exists());
    }

    #[test]
    fn stale_temp_files_of_dead_processes_are_removed_on_the_next_write() {
        let d = tempfile::tempdir().unwrap();
        // PID 4194304 + 1 is above Linux's PID_MAX_LIMIT: never a running process.
        let stale = d.path().join(".a.json.tmp4194305");
        std::fs::write(&stale, "torn").unwrap();
        let other = d.path().join(".b.json.tmp4194305");
        std::fs::write(&other, "another file's").unwrap();
        write_atomic(&d.path().join("a.json"), b"ok").unwrap();
        if cfg!(target_os = "linux") {
            assert!(!stale.exists(), "stale temp file kept");
        }
        assert!(other.exists(), "another file's temp file removed");
    }

    #[cfg(unix)]
    #[test]
    fn read_refuses_fifos_directories_and_devices_without_blocking() {
        let d = tempfile::tempdir().unwrap();
        let fifo = mkfifo(d.path());
        let e = read(&fifo).unwrap_err().to_string();
        assert!(e.contains("FIFO"), "{e}");
        let e = read_to_string(d.path()).unwrap_err().to_string();
        assert!(e.contains("directory"), "{e}");
        let e = read("/dev/zero").unwrap_err().to_string();
        assert!(e.contains("character device"), "{e}");
        let bin = d.path().join("bin");
        std::fs::write(&bin, [0xffu8, 0xfe, 0]).unwrap();
        let e = read_to_string(&bin).unwrap_err().to_string();
        assert!(e.contains("not UTF-8"), "{e}");
        std::fs::write(&bin, "text").unwrap();
        assert_eq!(read_to_string(&bin).unwrap(), "text");
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
