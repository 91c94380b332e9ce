//! Cameras as image sources.
//!
//! * [`pgm`]: a dependency-free PGM (P5 binary / P2 ASCII, 8- or 16-bit) reader and writer.
//! * [`decode`]: PNG, JPEG, BMP, TIFF (8/16-bit, grey/colour) and PGM files → 8-bit grey,
//!   pure Rust (the `image` crate), in the default build.
//! * [`FolderSource`]: an [`ImageSource`] that serves the image files of a folder in name
//!   order (recorded sessions, or images a simulator renders from the world).
//! * `opencv` (feature `opencv`): OpenCV `VideoCapture` cameras and network streams, image
//!   files of any format, chessboard detection. Needs `libopencv-dev`, `clang` and
//!   `libclang-dev` on the host (Debian's OpenCV 4.6).

pub mod decode;
#[cfg(feature = "opencv")]
pub mod opencv;
pub mod pgm;

use crate::error::{DeviceError, DriverError, DriverResult, ErrorKind};
use crate::traits::{Clock, Image, ImageSource, SystemClock};
use async_trait::async_trait;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// Errors of the image sources.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// Reading a file or folder failed.
    #[error("cannot read {path}: {source}")]
    Io {
        /// Path.
        path: String,
        /// Cause.
        #[source]
        source: std::io::Error,
    },
    /// A file that is not a valid PGM.
    #[error("{path}: {detail}")]
    Format {
        /// Path.
        path: String,
        /// What is wrong.
        detail: String,
    },
    /// The folder holds no images, or all were served and `repeat` is off.
    #[error("no more images in {0}")]
    Exhausted(String),
    /// The camera / stream could not be opened, or its link dropped.
    #[error("cannot open camera {target}: {detail}")]
    Open {
        /// What was opened (index, URL, file).
        target: String,
        /// Why.
        detail: String,
    },
    /// No frame arrived in time.
    #[error("no frame from {target} within {secs} s")]
    Timeout {
        /// What was opened.
        target: String,
        /// The deadline (s).
        secs: f64,
    },
    /// The image library failed.
    #[error("image backend: {detail}")]
    Backend {
        /// What failed.
        detail: String,
    },
    /// A bad argument (image size, pattern size).
    #[error("invalid argument: {0}")]
    Invalid(String),
}

impl DeviceError for Error {
    fn kind(&self) -> ErrorKind {
        match self {
            Error::Io { .. } => ErrorKind::Disconnected,
            Error::Format { .. } => ErrorKind::Protocol,
            Error::Exhausted(_) => ErrorKind::Other,
            Error::Open { .. } => ErrorKind::Disconnected,
            Error::Timeout { .. } => ErrorKind::Timeout,
            Error::Backend { .. } => ErrorKind::Other,
            Error::Invalid(_) => ErrorKind::InvalidArgument,
        }
    }
}

/// Serves the image files of a folder ([`IMAGE_EXTENSIONS`]) in file-name order.
pub struct FolderSource {
    dir: PathBuf,
    files: Vec<PathBuf>,
    next: Mutex<usize>,
    repeat: bool,
    clock: Arc<dyn Clock>,
}

impl std::fmt::Debug for FolderSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FolderSource")
            .field("dir", &self.dir)
            .field("files", &self.files.len())
            .finish()
    }
}

impl FolderSource {
    /// List `dir`; `repeat` restarts at the first file after the last.
    pub fn open(dir: &Path, repeat: bool) -> Result<Self, Error> {
        let io = |source| Error::Io {
            path: dir.display().to_string(),
            source,
        };
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(io)?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| is_image_file(p))
            .collect();
        files.sort();
        if files.is_empty() {
            return Err(Error::Exhausted(dir.display().to_string()));
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            files,
            next: Mutex::new(0),
            repeat,
            clock: Arc::new(SystemClock::default()),
        })
    }

    /// Use `clock` for image timestamps.
    pub fn with_clock(mut self, clock: Arc<dyn Clock>) -> Self {
        self.clock = clock;
        self
    }

    /// Number of images in the folder.
    pub fn len(&self) -> usize {
        self.files.len()
    }

    /// Whether the folder is empty (never true for an opened source).
    pub fn is_empty(&self) -> bool {
        self.files.is_empty()
    }

    /// The next image.
    pub fn next_image(&self) -> Result<Image, Error> {
        let path = {
            let mut n = self.next.lock().unwrap_or_else(|e| e.into_inner());
            if *n >= self.files.len() {
                if !self.repeat {
                    return Err(Error::Exhausted(self.dir.display().to_string()));
                }
                *n = 0;
            }
            let p = self.files[*n].clone();
            *n += 1;
            p
        };
        let mut img = read_image_file(&path)?;
        img.t = self.clock.now();
        Ok(img)
    }
}

/// The extensions [`FolderSource`] serves: `pgm`, `png`, `jpg`, `jpeg`, `bmp`, `tif`, `tiff`
/// (any case).
pub const IMAGE_EXTENSIONS: &[&str] = &["pgm", "png", "jpg", "jpeg", "bmp", "tif", "tiff"];

fn is_image_file(p: &Path) -> bool {
    p.extension()
        .and_then(|x| x.to_str())
        .is_some_and(|x| IMAGE_EXTENSIONS.iter().any(|e| x.eq_ignore_ascii_case(e)))
}

/// Read one image file as 8-bit grey: PNG, JPEG, BMP, TIFF (8/16-bit, grey/colour) or PGM,
/// recognised by content ([`decode::read_file`]). The timestamp is 0. The error names the file
/// and why it cannot be used (missing, a directory, empty, not an image, truncated, ...).
pub fn read_image_file(path: &Path) -> Result<Image, Error> {
    decode::read_file(path)
}

#[async_trait]
impl ImageSource for FolderSource {
    async fn grab(&self) -> DriverResult<Image> {
        self.next_image()
            .map_err(|e| DriverError::from_device(format!("camera@{}", self.dir.display()), e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn folder_source_serves_files_in_name_order_then_stops() {
        let dir = std::env::temp_dir().join(format!("robocal-camera-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("b.pgm"), pgm::encode(2, 1, &[3, 4])).unwrap();
        std::fs::write(dir.join("a.pgm"), pgm::encode(1, 1, &[9])).unwrap();
        std::fs::write(dir.join("c.PGM"), b"P5\n2 2\n255\n").unwrap();
        std::fs::write(dir.join("notes.txt"), b"ignored").unwrap();
        let src = FolderSource::open(&dir, false).unwrap();
        assert_eq!(src.len(), 3);
        assert_eq!(src.grab().await.unwrap().data, vec![9]);
        let b = src.grab().await.unwrap();
        assert_eq!((b.width, b.height, b.data), (2, 1, vec![3, 4]));
        assert_eq!(
            src.grab().await.unwrap_err().kind(),
            ErrorKind::Protocol,
            "truncated c.PGM"
        );
        assert_eq!(
            src.grab().await.unwrap_err().kind(),
            ErrorKind::Other,
            "exhausted"
        );
        let again = FolderSource::open(&dir, true).unwrap();
        for _ in 0..2 {
            let _ = again.grab().await;
        }
        let _ = again.grab().await;
        assert_eq!(again.grab().await.unwrap().data, vec![9], "repeat restarts");
        std::fs::remove_dir_all(&dir).unwrap();
        assert!(FolderSource::open(&dir, false).is_err());
    }
}
