//! OpenCV cameras (feature `opencv`): `VideoCapture` sources, image files of any format
//! OpenCV reads, and chessboard corner detection.
//!
//! * [`VideoCaptureSource`]: a camera (`0`, `/dev/video2`), a network stream
//!   (`http://…/video.mjpg`, `rtsp://…`), a video file or an image sequence (`img_%03d.png`)
//!   as an [`ImageSource`]. Live targets (device indices and network streams) are read
//!   continuously by a background thread that keeps only the newest frame, so [`ImageSource::grab`]
//!   returns a frame that *arrived after the call* (never one buffered while the arm was still
//!   moving); when the link drops the thread reopens the target with backoff and `grab` reports
//!   `Timeout` / `Disconnected` meanwhile. Files and image sequences are read one frame per grab.
//! * [`read_image`] / [`write_image`]: grey images from / to PNG, JPEG, BMP, TIFF, PGM….
//! * [`find_chessboard`]: OpenCV's chessboard detectors (classic + sub-pixel refinement, or the
//!   sector-based `findChessboardCornersSB`).
//!
//! Needs the system OpenCV (Debian: `apt-get install libopencv-dev clang libclang-dev`, 4.6).
//! Frames are converted to 8-bit grey (colour → `COLOR_BGR(A)2GRAY`, 16-bit → high byte).

use super::Error;
use crate::error::{DriverError, DriverResult};
use crate::traits::{Clock, Image, ImageSource, SystemClock};
use async_trait::async_trait;
use opencv::core::{self, Mat, Point2f, Size, TermCriteria, Vector};
use opencv::prelude::*;
use opencv::{calib3d, imgcodecs, imgproc, videoio};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::Duration;

fn cv_err(what: &str, e: opencv::Error) -> Error {
    Error::Backend {
        detail: format!("{what}: {e}"),
    }
}

/// How frames are taken from the target.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// A background thread reads continuously and keeps the newest frame (cameras, streams).
    Live,
    /// One frame read per grab, in order (video files, image sequences).
    Sequential,
}

/// What to open and how.
#[derive(Debug, Clone)]
pub struct CaptureConfig {
    /// `0`, `/dev/video2`, a URL (`http://…`, `rtsp://…`), a video file or an image-sequence
    /// pattern (`frames/img_%03d.png`).
    pub target: String,
    /// Requested frame width (px), if the device lets it be set.
    pub width: Option<u32>,
    /// Requested frame height (px).
    pub height: Option<u32>,
    /// Requested frame rate (Hz).
    pub fps: Option<f64>,
    /// How long a grab waits for a frame, and the open / read timeouts of network streams (s).
    pub timeout_s: f64,
    /// Frames to let pass after the call before one is returned (live mode): 0 = the first
    /// frame that arrives after the call, 1 = the one after it (skips a frame exposed during
    /// the call), ….
    pub skip: u32,
    /// Live or sequential; `None` = live for device indices and network URLs, else sequential.
    pub mode: Option<Mode>,
}

impl CaptureConfig {
    /// Defaults for `target`: timeout 5 s, skip 1, automatic mode.
    pub fn new(target: impl Into<String>) -> Self {
        Self {
            target: target.into(),
            width: None,
            height: None,
            fps: None,
            timeout_s: 5.0,
            skip: 1,
            mode: None,
        }
    }

    /// The device index, for `0`, `1`, … and `/dev/videoN`.
    pub fn device_index(&self) -> Option<i32> {
        let t = self.target.trim();
        t.parse::<i32>()
            .ok()
            .or_else(|| t.strip_prefix("/dev/video")?.parse::<i32>().ok())
            .filter(|i| *i >= 0)
    }

    /// Whether the target is a network stream.
    pub fn is_network(&self) -> bool {
        let t = self.target.trim().to_ascii_lowercase();
        [
            "http://", "https://", "rtsp://", "rtmp://", "udp://", "tcp://",
        ]
        .iter()
        .any(|p| t.starts_with(p))
    }

    /// The effective mode.
    pub fn effective_mode(&self) -> Mode {
        self.mode
            .unwrap_or(if self.device_index().is_some() || self.is_network() {
                Mode::Live
            } else {
                Mode::Sequential
            })
    }

    fn open(&self) -> Result<videoio::VideoCapture, Error> {
        let fail = |detail: String| Error::Open {
            target: self.target.clone(),
            detail,
        };
        if !self.timeout_s.is_finite() || self.timeout_s <= 0.0 {
            return Err(Error::Invalid(format!(
                "timeout_s must be > 0 (got {})",
                self.timeout_s
            )));
        }
        let ms = (self.timeout_s * 1000.0)
            .round()
            .clamp(1.0, i32::MAX as f64) as i32;
        let mut cap = if let Some(i) = self.device_index() {
            videoio::VideoCapture::new(i, videoio::CAP_ANY)
        } else {
            let params = if self.is_network() {
                Vector::from_slice(&[
                    videoio::CAP_PROP_OPEN_TIMEOUT_MSEC,
                    ms,
                    videoio::CAP_PROP_READ_TIMEOUT_MSEC,
                    ms,
                ])
            } else {
                Vector::new()
            };
            // Network streams go to FFmpeg directly (GStreamer's http source may be missing).
            let api = if self.is_network() {
                videoio::CAP_FFMPEG
            } else {
                videoio::CAP_ANY
            };
            videoio::VideoCapture::from_file_with_params(&self.target, api, &params)
        }
        .map_err(|e| fail(e.to_string()))?;
        if !cap.is_opened().map_err(|e| fail(e.to_string()))? {
            return Err(fail(
                "OpenCV could not open it (no backend accepted it)".into(),
            ));
        }
        // Requests a device may ignore; the frames say what was granted.
        if let Some(w) = self.width {
            let _ = cap.set(videoio::CAP_PROP_FRAME_WIDTH, w as f64);
        }
        if let Some(h) = self.height {
            let _ = cap.set(videoio::CAP_PROP_FRAME_HEIGHT, h as f64);
        }
        if let Some(f) = self.fps {
            let _ = cap.set(videoio::CAP_PROP_FPS, f);
        }
        Ok(cap)
    }
}

/// A frame as an 8-bit grey [`Image`] stamped `t`.
pub fn mat_to_image(m: &Mat, t: f64) -> Result<Image, Error> {
    if m.empty() {
        return Err(Error::Backend {
            detail: "empty frame".into(),
        });
    }
    let mut grey = match m.channels() {
        1 => m.try_clone().map_err(|e| cv_err("copy", e))?,
        3 | 4 => {
            let code = if m.channels() == 3 {
                imgproc::COLOR_BGR2GRAY
            } else {
                imgproc::COLOR_BGRA2GRAY
            };
            let mut g = Mat::default();
            imgproc::cvt_color_def(m, &mut g, code).map_err(|e| cv_err("cvtColor", e))?;
            g
        }
        c => {
            return Err(Error::Backend {
                detail: format!("{c}-channel frames are not supported"),
            })
        }
    };
    match grey.depth() {
        core::CV_8U => {}
        core::CV_16U => {
            let mut g8 = Mat::default();
            grey.convert_to(&mut g8, core::CV_8U, 1.0 / 256.0, 0.0)
                .map_err(|e| cv_err("convertTo", e))?;
            grey = g8;
        }
        d => {
            return Err(Error::Backend {
                detail: format!("pixel depth {d} is not supported (8- or 16-bit only)"),
            })
        }
    }
    if !grey.is_continuous() {
        grey = grey.try_clone().map_err(|e| cv_err("copy", e))?;
    }
    let data = grey
        .data_bytes()
        .map_err(|e| cv_err("frame bytes", e))?
        .to_vec();
    Ok(Image {
        width: grey.cols() as u32,
        height: grey.rows() as u32,
        data,
        t,
    })
}

/// An [`Image`] as a grey `Mat` (copied).
pub fn image_to_mat(img: &Image) -> Result<Mat, Error> {
    let (w, h) = (img.width as usize, img.height as usize);
    if w == 0 || h == 0 || img.data.len() != w * h || w > i32::MAX as usize {
        return Err(Error::Invalid(format!(
            "image of {}×{} with {} bytes",
            img.width,
            img.height,
            img.data.len()
        )));
    }
    let m = Mat::new_rows_cols_with_data(h as i32, w as i32, &img.data)
        .map_err(|e| cv_err("wrap image", e))?;
    m.try_clone().map_err(|e| cv_err("copy", e))
}

/// Read an image file of any format OpenCV knows, as 8-bit grey.
pub fn read_image(path: &Path) -> Result<Image, Error> {
    let p = path.display().to_string();
    if !path.is_file() {
        return Err(Error::Io {
            path: p,
            source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
        });
    }
    let m = imgcodecs::imread(path.as_os_str(), imgcodecs::IMREAD_UNCHANGED)
        .map_err(|e| cv_err(&p, e))?;
    if m.empty() {
        return Err(Error::Format {
            path: p,
            detail: "OpenCV cannot decode this file".into(),
        });
    }
    mat_to_image(&m, 0.0).map_err(|e| Error::Format {
        path: p,
        detail: e.to_string(),
    })
}

/// Write `img` (the format follows the extension: `.png`, `.pgm`, `.bmp`, `.tif`, `.jpg`…).
pub fn write_image(path: &Path, img: &Image) -> Result<(), Error> {
    let m = image_to_mat(img)?;
    let ok = imgcodecs::imwrite(path.as_os_str(), &m, &Vector::new())
        .map_err(|e| cv_err(&path.display().to_string(), e))?;
    if ok {
        Ok(())
    } else {
        Err(Error::Format {
            path: path.display().to_string(),
            detail: "OpenCV could not write this format".into(),
        })
    }
}

/// Which chessboard detector.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Detector {
    /// `findChessboardCorners` (adaptive threshold, normalised) + `cornerSubPix`.
    Classic,
    /// `findChessboardCornersSB` (exhaustive, accuracy), sub-pixel by construction.
    SectorBased,
}

/// The inner corners of a chessboard with `cols × rows` inner corners (not squares), in
/// OpenCV's order (row by row; the detector picks which end is first). `Ok(None)` when the
/// board is not found.
pub fn find_chessboard(
    img: &Image,
    cols: u32,
    rows: u32,
    detector: Detector,
) -> Result<Option<Vec<[f64; 2]>>, Error> {
    if cols < 2 || rows < 2 || cols > 1000 || rows > 1000 {
        return Err(Error::Invalid(format!(
            "a chessboard needs at least 2×2 inner corners (got {cols}×{rows})"
        )));
    }
    let m = image_to_mat(img)?;
    let size = Size::new(cols as i32, rows as i32);
    let mut corners: Vector<Point2f> = Vector::new();
    let found = match detector {
        Detector::Classic => calib3d::find_chessboard_corners(
            &m,
            size,
            &mut corners,
            calib3d::CALIB_CB_ADAPTIVE_THRESH | calib3d::CALIB_CB_NORMALIZE_IMAGE,
        ),
        Detector::SectorBased => calib3d::find_chessboard_corners_sb(
            &m,
            size,
            &mut corners,
            calib3d::CALIB_CB_EXHAUSTIVE | calib3d::CALIB_CB_ACCURACY,
        ),
    }
    .map_err(|e| cv_err("findChessboardCorners", e))?;
    if !found || corners.len() != (cols * rows) as usize {
        return Ok(None);
    }
    if detector == Detector::Classic {
        // Half-window: a little under half the smallest spacing of neighbouring corners.
        let pts: Vec<Point2f> = corners.to_vec();
        let mut spacing = f32::INFINITY;
        for r in 0..rows as usize {
            for c in 0..cols as usize {
                let i = r * cols as usize + c;
                if c + 1 < cols as usize {
                    spacing = spacing.min(dist(pts[i], pts[i + 1]));
                }
                if r + 1 < rows as usize {
                    spacing = spacing.min(dist(pts[i], pts[i + cols as usize]));
                }
            }
        }
        let half = ((spacing * 0.4).floor() as i32).clamp(2, 11);
        let criteria = TermCriteria::new(
            core::TermCriteria_Type::COUNT as i32 | core::TermCriteria_Type::EPS as i32,
            40,
            1e-3,
        )
        .map_err(|e| cv_err("TermCriteria", e))?;
        imgproc::corner_sub_pix(
            &m,
            &mut corners,
            Size::new(half, half),
            Size::new(-1, -1),
            criteria,
        )
        .map_err(|e| cv_err("cornerSubPix", e))?;
    }
    Ok(Some(
        corners.iter().map(|p| [p.x as f64, p.y as f64]).collect(),
    ))
}

fn dist(a: Point2f, b: Point2f) -> f32 {
    ((a.x - b.x).powi(2) + (a.y - b.y).powi(2)).sqrt()
}

struct LiveState {
    seq: u64,
    latest: Option<Image>,
    last_error: Option<String>,
    opened: bool,
}

struct Live {
    state: Mutex<LiveState>,
    cv: Condvar,
    stop: AtomicBool,
}

enum Inner {
    Live(Arc<Live>),
    Sequential(Arc<Mutex<Option<videoio::VideoCapture>>>),
}

/// An OpenCV `VideoCapture` as an [`ImageSource`]. See the module docs.
pub struct VideoCaptureSource {
    config: CaptureConfig,
    name: String,
    clock: Arc<dyn Clock>,
    inner: Inner,
}

impl std::fmt::Debug for VideoCaptureSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VideoCaptureSource")
            .field("target", &self.config.target)
            .field("mode", &self.config.effective_mode())
            .finish()
    }
}

impl VideoCaptureSource {
    /// Open `config.target` with the wall clock. Fails if the first open fails (a live source
    /// then reopens by itself whenever the link drops).
    pub fn open(config: CaptureConfig) -> Result<Self, Error> {
        Self::open_with_clock(config, Arc::new(SystemClock::default()))
    }

    /// Open with `clock` stamping the frames (at arrival).
    pub fn open_with_clock(config: CaptureConfig, clock: Arc<dyn Clock>) -> Result<Self, Error> {
        let cap = config.open()?;
        let name = format!("camera@{}", config.target);
        let inner = match config.effective_mode() {
            Mode::Sequential => Inner::Sequential(Arc::new(Mutex::new(Some(cap)))),
            Mode::Live => {
                let live = Arc::new(Live {
                    state: Mutex::new(LiveState {
                        seq: 0,
                        latest: None,
                        last_error: None,
                        opened: true,
                    }),
                    cv: Condvar::new(),
                    stop: AtomicBool::new(false),
                });
                let (l, c, k) = (live.clone(), config.clone(), clock.clone());
                std::thread::Builder::new()
                    .name(format!("camera {}", config.target))
                    .spawn(move || reader(l, c, k, cap))
                    .map_err(|e| Error::Open {
                        target: config.target.clone(),
                        detail: format!("cannot start the reader thread: {e}"),
                    })?;
                Inner::Live(live)
            }
        };
        Ok(Self {
            config,
            name,
            clock,
            inner,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &CaptureConfig {
        &self.config
    }

    /// Frames received so far (live mode; 0 in sequential mode).
    pub fn frames_received(&self) -> u64 {
        match &self.inner {
            Inner::Live(l) => lock(&l.state).seq,
            Inner::Sequential(_) => 0,
        }
    }

    /// The next frame (blocking; see [`ImageSource::grab`] for the async form).
    pub fn grab_blocking(&self) -> Result<Image, Error> {
        match &self.inner {
            Inner::Sequential(cap) => read_sequential(cap, &self.config, self.clock.now()),
            Inner::Live(live) => wait_live(live, &self.config),
        }
    }
}

/// Wait for the frame `skip + 1` arrivals after now.
fn wait_live(live: &Live, config: &CaptureConfig) -> Result<Image, Error> {
    let timeout = Duration::from_secs_f64(config.timeout_s.max(1e-3));
    let deadline = std::time::Instant::now() + timeout;
    let mut st = lock(&live.state);
    let want = st.seq + 1 + config.skip as u64;
    while st.seq < want {
        let now = std::time::Instant::now();
        if now >= deadline {
            return Err(if st.opened {
                Error::Timeout {
                    target: config.target.clone(),
                    secs: config.timeout_s,
                }
            } else {
                Error::Open {
                    target: config.target.clone(),
                    detail: st.last_error.clone().unwrap_or_else(|| "link down".into()),
                }
            });
        }
        st = live
            .cv
            .wait_timeout(st, deadline - now)
            .unwrap_or_else(|e| e.into_inner())
            .0;
    }
    st.latest.clone().ok_or_else(|| Error::Backend {
        detail: "no frame".into(),
    })
}

impl Drop for VideoCaptureSource {
    fn drop(&mut self) {
        if let Inner::Live(l) = &self.inner {
            l.stop.store(true, Ordering::SeqCst);
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

fn read_sequential(
    cap: &Mutex<Option<videoio::VideoCapture>>,
    config: &CaptureConfig,
    t: f64,
) -> Result<Image, Error> {
    let mut guard = lock(cap);
    let Some(c) = guard.as_mut() else {
        return Err(Error::Exhausted(config.target.clone()));
    };
    let mut m = Mat::default();
    let ok = c.read(&mut m).map_err(|e| cv_err("read", e))?;
    if !ok || m.empty() {
        let _ = c.release();
        *guard = None;
        return Err(Error::Exhausted(config.target.clone()));
    }
    mat_to_image(&m, t)
}

/// The live reader: newest frame wins; reopen with backoff when the link drops.
fn reader(
    live: Arc<Live>,
    config: CaptureConfig,
    clock: Arc<dyn Clock>,
    first: videoio::VideoCapture,
) {
    let mut cap = Some(first);
    let mut backoff = 0.1f64;
    let mut m = Mat::default();
    while !live.stop.load(Ordering::SeqCst) {
        let Some(c) = cap.as_mut() else {
            std::thread::sleep(Duration::from_secs_f64(backoff));
            backoff = (backoff * 2.0).min(2.0);
            match config.open() {
                Ok(c) => {
                    cap = Some(c);
                    lock(&live.state).opened = true;
                }
                Err(e) => lock(&live.state).last_error = Some(e.to_string()),
            }
            continue;
        };
        let got = match c.read(&mut m) {
            Ok(true) if !m.empty() => mat_to_image(&m, clock.now()),
            Ok(_) => Err(Error::Backend {
                detail: "the stream ended or the read timed out".into(),
            }),
            Err(e) => Err(cv_err("read", e)),
        };
        match got {
            Ok(img) => {
                backoff = 0.1;
                let mut st = lock(&live.state);
                st.seq += 1;
                st.latest = Some(img);
                st.last_error = None;
                drop(st);
                live.cv.notify_all();
            }
            Err(e) => {
                if live.stop.load(Ordering::SeqCst) {
                    break;
                }
                if lock(&live.state).opened {
                    // Once per outage; the reopen attempts that follow are quiet.
                    tracing::warn!(target = %config.target, "camera: {e}; reopening");
                }
                if let Some(mut c) = cap.take() {
                    let _ = c.release();
                }
                let mut st = lock(&live.state);
                st.opened = false;
                st.last_error = Some(e.to_string());
            }
        }
    }
    if let Some(mut c) = cap {
        let _ = c.release();
    }
}

#[async_trait]
impl ImageSource for VideoCaptureSource {
    async fn grab(&self) -> DriverResult<Image> {
        let r = match &self.inner {
            Inner::Sequential(cap) => {
                let (cap, config, t) = (cap.clone(), self.config.clone(), self.clock.now());
                tokio::task::spawn_blocking(move || read_sequential(&cap, &config, t)).await
            }
            Inner::Live(live) => {
                let (live, config) = (live.clone(), self.config.clone());
                tokio::task::spawn_blocking(move || wait_live(&live, &config)).await
            }
        };
        r.unwrap_or_else(|e| {
            Err(Error::Backend {
                detail: format!("reader task: {e}"),
            })
        })
        .map_err(|e| DriverError::from_device(self.name.clone(), e))
    }
}
