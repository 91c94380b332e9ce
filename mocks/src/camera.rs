//! Simulated network camera: MJPEG over HTTP, as IP cameras and webcam streamers serve it and
//! as OpenCV's `VideoCapture("http://host:port/video.mjpg")` (FFmpeg `mpjpeg` demuxer) reads it.
//!
//! A small hand-written HTTP/1.x server on tokio, one task per connection:
//!
//! | request                | answer |
//! | ---------------------- | ------ |
//! | `GET /video.mjpg`, `GET /` | `200`, `Content-Type: multipart/x-mixed-replace; boundary=<b>`, then parts forever, each `--<b>\r\nContent-Type: image/jpeg\r\nContent-Length: N\r\nX-Timestamp: <world s>\r\n\r\n<jpeg>\r\n` |
//! | `GET /snapshot.jpg`    | `200`, one JPEG (`image/jpeg`, `Content-Length`) |
//! | `GET /snapshot.pgm`    | `200`, the same view as a binary PGM (`P5`, lossless; `image/x-portable-graymap`) |
//! | other path             | `404` |
//! | other method           | `405` with `Allow: GET` |
//! | malformed request line | `400` |
//! | head over [`MAX_REQUEST`] bytes | `431` |
//!
//! Every reply carries `Connection: close`; the query string is ignored. The request head
//! (request line and headers up to the blank line) is read with a bound of [`MAX_REQUEST`]
//! bytes and [`REQUEST_TIMEOUT_S`] seconds of wall time; a client that sends nothing is dropped.
//!
//! Every frame is rendered from the world AT SEND TIME (`world.render_camera_of(i)`, 8-bit
//! grey, with the scenario's blur and noise) and JPEG-encoded (greyscale, quality
//! [`SimCameraConfig::quality`], default 95) on a blocking thread. The stream is paced on
//! tokio wall time at [`SimCameraConfig::rate_hz`] (default 15 Hz; a frame that takes longer
//! to render than the period lowers the rate, frames are never sent in bursts: the world's
//! renderer costs ~0.1 s per 640×480 frame at opt-level 1 and over 1 s unoptimised, and holds
//! the world lock meanwhile). The camera
//! never advances a virtual world clock: it is a passive observer, so a virtual-clock session
//! stays deterministic however many frames a viewer pulls.
//!
//! # Faults
//!
//! `world.take_fault(device)` is polled once per request (before the status line) and once
//! before every further frame of a stream whose viewer is still connected (a stream whose viewer
//! has closed its end ends there, without taking a fault meant for a live viewer). A fault taken at request time that is not about the
//! reply as a whole (`Garbage`, `Truncated`, `BadCrc`) applies to the snapshot body or to the
//! stream's first frame.
//!
//! | fault | effect |
//! | ----- | ------ |
//! | `DropLink` | the connection is closed at once (at request time: no status line at all) |
//! | `Delay { secs }`, `Silence { secs }` | nothing is sent for `secs` (clamped to 0–600 s; wall time with a virtual world clock, the world clock when it is real), then the reply / frame goes out normally |
//! | `ErrorReply { code }` | at request time: the reply is `code` when it is an HTTP error status (400–599), else `503 Service Unavailable`, with a short text body; in the middle of a stream (a status cannot change any more): the stream ends (connection closed) |
//! | `Garbage { bytes }` | stream: the bytes (or, when empty, [`DEFAULT_GARBAGE`]) and a CRLF are written between two parts, before the next boundary line, and the stream continues (a client that scans for the boundary line recovers); snapshot: the bytes are sent instead of the reply and the connection is closed |
//! | `Truncated` | the part (or snapshot) headers announce the full `Content-Length`, only the first half of the image bytes is sent, then the connection is closed |
//! | `BadCrc` | the image bytes are corrupted in place, length unchanged (stream in sync): JPEG — the SOI marker and 64 bytes in the middle of the entropy-coded data are inverted, so the frame does not decode; PGM — the magic becomes `P0` and the middle 64 pixels are inverted |

use crate::serve::{Bind, Endpoint, ServeError};
use crate::world::{DeviceRef, Fault, WorldHandle};
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::task::JoinHandle;

/// The usual port of HTTP camera streamers.
pub const STANDARD_PORT: u16 = 8080;
/// Longest request head accepted (bytes); longer heads get `431`.
pub const MAX_REQUEST: usize = 8192;
/// Wall time allowed to send the request head (s).
pub const REQUEST_TIMEOUT_S: f64 = 10.0;
/// The junk line sent for a `Garbage` fault with no bytes.
pub const DEFAULT_GARBAGE: &[u8] = b"\x00\xffgarbage\r\n";

/// Stream settings.
#[derive(Debug, Clone, PartialEq)]
pub struct SimCameraConfig {
    /// Frame rate of `/video.mjpg` (Hz; non-positive or non-finite values mean 15).
    pub rate_hz: f64,
    /// JPEG quality (1–100).
    pub quality: u8,
    /// Multipart boundary (without the leading `--`).
    pub boundary: String,
}

impl Default for SimCameraConfig {
    fn default() -> Self {
        Self {
            rate_hz: 15.0,
            quality: 95,
            boundary: "robocalmjpegboundary".into(),
        }
    }
}

impl SimCameraConfig {
    fn period(&self) -> Duration {
        let hz = if self.rate_hz.is_finite() && self.rate_hz > 0.0 {
            self.rate_hz
        } else {
            15.0
        };
        Duration::from_secs_f64(1.0 / hz.min(1000.0))
    }
}

/// A running simulated camera. Dropping it stops the server (open streams end with the
/// runtime or at their next failed write).
pub struct SimCamera {
    addr: SocketAddr,
    frames: Arc<AtomicU64>,
    task: Option<JoinHandle<()>>,
}

impl std::fmt::Debug for SimCamera {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimCamera")
            .field("addr", &self.addr)
            .finish()
    }
}

impl Drop for SimCamera {
    fn drop(&mut self) {
        if let Some(t) = &self.task {
            t.abort();
        }
    }
}

impl SimCamera {
    /// The bound address.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }
    /// `http://addr/video.mjpg`.
    pub fn url(&self) -> String {
        format!("http://{}/video.mjpg", self.addr)
    }
    /// Stream parts written in full so far (all connections).
    pub fn frames_sent(&self) -> u64 {
        self.frames.load(Ordering::Relaxed)
    }
    /// Hand the server task over to the `sim serve` registry.
    pub fn into_endpoint(mut self, device: &str, protocol: &str) -> Endpoint {
        Endpoint {
            device: device.to_string(),
            protocol: protocol.to_string(),
            addr: Some(self.addr),
            path: None,
            task: self.task.take(),
        }
    }
}

struct Shared {
    world: WorldHandle,
    device: String,
    camera: usize,
    config: SimCameraConfig,
    frames: Arc<AtomicU64>,
}

/// Serve camera `device` of `world` on `bind` (port 0 for a free port); returns once listening.
pub async fn serve(
    world: WorldHandle,
    device: &str,
    config: SimCameraConfig,
    bind: SocketAddr,
) -> Result<SimCamera, ServeError> {
    let camera = match world.device(device) {
        Some(DeviceRef::Camera(i)) => i,
        _ => return Err(ServeError::NoSuchDevice(device.to_string())),
    };
    let io = |source| ServeError::Io {
        device: device.to_string(),
        source,
    };
    let listener = tokio::net::TcpListener::bind(bind).await.map_err(io)?;
    let addr = listener.local_addr().map_err(io)?;
    let frames = Arc::new(AtomicU64::new(0));
    let shared = Arc::new(Shared {
        world,
        device: device.to_string(),
        camera,
        config,
        frames: frames.clone(),
    });
    let task = tokio::spawn(async move {
        loop {
            match listener.accept().await {
                Ok((stream, _)) => {
                    let _ = stream.set_nodelay(true);
                    let shared = shared.clone();
                    tokio::spawn(async move {
                        let _ = connection(stream, shared).await;
                    });
                }
                // Out of descriptors and the like: back off instead of spinning.
                Err(_) => tokio::time::sleep(Duration::from_millis(50)).await,
            }
        }
    });
    Ok(SimCamera {
        addr,
        frames,
        task: Some(task),
    })
}

/// `sim serve` entry point for `camera`: MJPEG over HTTP on `bind.addr(8080)`.
pub async fn start(
    world: WorldHandle,
    device: &str,
    bind: &Bind,
) -> Result<Vec<Endpoint>, ServeError> {
    let sim = serve(
        world,
        device,
        SimCameraConfig::default(),
        bind.addr(STANDARD_PORT),
    )
    .await?;
    Ok(vec![sim.into_endpoint(device, "mjpeg")])
}

/// A parsed request line.
#[derive(Debug, PartialEq)]
struct Request {
    method: String,
    path: String,
    http10: bool,
}

enum Head {
    Request(Request),
    Malformed,
    TooLarge,
    Closed,
}

fn end_of_head(buf: &[u8]) -> Option<usize> {
    let crlf = buf.windows(4).position(|w| w == b"\r\n\r\n").map(|p| p + 4);
    let lf = buf.windows(2).position(|w| w == b"\n\n").map(|p| p + 2);
    match (crlf, lf) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}

fn parse_request_line(head: &[u8]) -> Option<Request> {
    let line_end = head.iter().position(|&b| b == b'\n')?;
    let line = std::str::from_utf8(&head[..line_end])
        .ok()?
        .trim_end_matches('\r');
    let mut parts = line.split(' ');
    let (method, target, version) = (parts.next()?, parts.next()?, parts.next()?);
    if parts.next().is_some()
        || method.is_empty()
        || !method.bytes().all(|b| b.is_ascii_uppercase())
        || !(target.starts_with('/') || target == "*")
        || !matches!(version, "HTTP/1.0" | "HTTP/1.1")
    {
        return None;
    }
    let path = target.split(['?', '#']).next().unwrap_or("").to_string();
    Some(Request {
        method: method.to_string(),
        path,
        http10: version == "HTTP/1.0",
    })
}

async fn read_head(sock: &mut TcpStream) -> Head {
    let mut buf = Vec::with_capacity(512);
    let mut scratch = [0u8; 1024];
    let deadline = tokio::time::Instant::now() + Duration::from_secs_f64(REQUEST_TIMEOUT_S);
    loop {
        if let Some(end) = end_of_head(&buf) {
            return match parse_request_line(&buf[..end]) {
                Some(r) => Head::Request(r),
                None => Head::Malformed,
            };
        }
        if buf.len() > MAX_REQUEST {
            return Head::TooLarge;
        }
        match tokio::time::timeout_at(deadline, sock.read(&mut scratch)).await {
            Ok(Ok(0)) | Ok(Err(_)) | Err(_) => return Head::Closed,
            Ok(Ok(n)) => buf.extend_from_slice(&scratch[..n]),
        }
    }
}

fn reason(code: u16) -> &'static str {
    match code {
        200 => "OK",
        400 => "Bad Request",
        401 => "Unauthorized",
        403 => "Forbidden",
        404 => "Not Found",
        405 => "Method Not Allowed",
        408 => "Request Timeout",
        429 => "Too Many Requests",
        431 => "Request Header Fields Too Large",
        500 => "Internal Server Error",
        501 => "Not Implemented",
        502 => "Bad Gateway",
        503 => "Service Unavailable",
        504 => "Gateway Timeout",
        _ => "Error",
    }
}

fn status_line(http10: bool, code: u16) -> String {
    format!(
        "HTTP/1.{} {code} {}\r\n",
        if http10 { 0 } else { 1 },
        reason(code)
    )
}

async fn simple_reply(
    sock: &mut TcpStream,
    http10: bool,
    code: u16,
    extra: &str,
    body: &str,
) -> std::io::Result<()> {
    let msg = format!(
        "{}Content-Type: text/plain\r\nContent-Length: {}\r\nConnection: close\r\n{extra}\r\n{body}",
        status_line(http10, code),
        body.len()
    );
    sock.write_all(msg.as_bytes()).await?;
    sock.flush().await
}

/// What a fault does to the reply that follows it.
enum Apply {
    Nothing,
    Close,
    Error(u16),
    Garbage(Vec<u8>),
    Truncated,
    BadCrc,
}

async fn take(shared: &Shared) -> Apply {
    let Some(f) = shared.world.take_fault(&shared.device) else {
        return Apply::Nothing;
    };
    match f {
        Fault::DropLink => Apply::Close,
        Fault::Delay { secs } | Fault::Silence { secs } => {
            let secs = if secs.is_finite() {
                secs.clamp(0.0, 600.0)
            } else {
                0.0
            };
            if shared.world.is_virtual() {
                tokio::time::sleep(Duration::from_secs_f64(secs)).await;
            } else {
                shared.world.clock().sleep(secs).await;
            }
            Apply::Nothing
        }
        Fault::ErrorReply { code } => Apply::Error(
            u16::try_from(code)
                .ok()
                .filter(|c| (400..=599).contains(c))
                .unwrap_or(503),
        ),
        Fault::Garbage { bytes } => Apply::Garbage(if bytes.is_empty() {
            DEFAULT_GARBAGE.to_vec()
        } else {
            bytes
        }),
        Fault::Truncated => Apply::Truncated,
        Fault::BadCrc => Apply::BadCrc,
    }
}

/// One rendered view: (JPEG or PGM bytes, world time of the render).
struct Frame {
    bytes: Vec<u8>,
    t: f64,
}

#[derive(Clone, Copy, PartialEq)]
enum Format {
    Jpeg,
    Pgm,
}

fn encode(img: &robocal_drivers::Image, format: Format, quality: u8) -> Option<Vec<u8>> {
    let (w, h) = (
        u16::try_from(img.width).ok()?,
        u16::try_from(img.height).ok()?,
    );
    if w == 0 || h == 0 || img.data.len() != usize::from(w) * usize::from(h) {
        return None;
    }
    match format {
        Format::Jpeg => {
            let mut out = Vec::with_capacity(img.data.len() / 4);
            jpeg_encoder::Encoder::new(&mut out, quality.clamp(1, 100))
                .encode(&img.data, w, h, jpeg_encoder::ColorType::Luma)
                .ok()?;
            Some(out)
        }
        Format::Pgm => {
            let mut out = format!("P5\n{w} {h}\n255\n").into_bytes();
            out.extend_from_slice(&img.data);
            Some(out)
        }
    }
}

async fn render(shared: &Arc<Shared>, format: Format) -> Option<Frame> {
    let s = shared.clone();
    tokio::task::spawn_blocking(move || {
        let img = s.world.render_camera_of(s.camera);
        encode(&img, format, s.config.quality).map(|bytes| Frame { bytes, t: img.t })
    })
    .await
    .ok()
    .flatten()
}

/// Corrupt an image in place, length unchanged (see the module doc).
fn corrupt(bytes: &mut [u8], format: Format) {
    match format {
        Format::Jpeg => {
            if bytes.len() >= 2 {
                bytes[0] ^= 0xFF;
                bytes[1] ^= 0xFF;
            }
            // Entropy-coded data starts after the SOS segment (FF DA, 2-byte length).
            let sos = bytes
                .windows(2)
                .position(|w| w == [0xFF, 0xDA])
                .map_or(2, |p| {
                    let len = bytes
                        .get(p + 2..p + 4)
                        .map_or(0, |l| usize::from(u16::from_be_bytes([l[0], l[1]])));
                    p + 2 + len
                });
            let mid = sos + bytes.len().saturating_sub(sos) / 2;
            let end = (mid + 64).min(bytes.len().saturating_sub(2));
            for b in bytes.iter_mut().take(end).skip(mid) {
                *b ^= 0xFF;
            }
        }
        Format::Pgm => {
            if bytes.len() >= 2 {
                bytes[1] = b'0';
            }
            let mid = bytes.len() / 2;
            let end = (mid + 64).min(bytes.len());
            for b in bytes.iter_mut().take(end).skip(mid) {
                *b ^= 0xFF;
            }
        }
    }
}

async fn connection(mut sock: TcpStream, shared: Arc<Shared>) -> std::io::Result<()> {
    let req = match read_head(&mut sock).await {
        Head::Request(r) => r,
        Head::Closed => return Ok(()),
        Head::Malformed => {
            return simple_reply(&mut sock, false, 400, "", "bad request\n").await;
        }
        Head::TooLarge => {
            return simple_reply(&mut sock, false, 431, "", "request head too large\n").await;
        }
    };
    let format = match req.path.as_str() {
        "/" | "/video.mjpg" => None,
        "/snapshot.jpg" => Some(Format::Jpeg),
        "/snapshot.pgm" => Some(Format::Pgm),
        _ => {
            return simple_reply(&mut sock, req.http10, 404, "", "not found\n").await;
        }
    };
    if req.method != "GET" {
        return simple_reply(
            &mut sock,
            req.http10,
            405,
            "Allow: GET\r\n",
            "method not allowed\n",
        )
        .await;
    }
    let first = match take(&shared).await {
        Apply::Close => return Ok(()),
        Apply::Error(code) => {
            return simple_reply(&mut sock, req.http10, code, "", "camera error (injected)\n")
                .await;
        }
        other => other,
    };
    match format {
        Some(f) => snapshot(&mut sock, &shared, &req, f, first).await,
        None => stream(&mut sock, &shared, &req, first).await,
    }
}

async fn snapshot(
    sock: &mut TcpStream,
    shared: &Arc<Shared>,
    req: &Request,
    format: Format,
    fault: Apply,
) -> std::io::Result<()> {
    if let Apply::Garbage(bytes) = &fault {
        sock.write_all(bytes).await?;
        return sock.flush().await;
    }
    let Some(mut frame) = render(shared, format).await else {
        return simple_reply(sock, req.http10, 500, "", "render failed\n").await;
    };
    let ctype = match format {
        Format::Jpeg => "image/jpeg",
        Format::Pgm => "image/x-portable-graymap",
    };
    let head = format!(
        "{}Content-Type: {ctype}\r\nContent-Length: {}\r\nCache-Control: no-cache\r\nX-Timestamp: {:.6}\r\nConnection: close\r\n\r\n",
        status_line(req.http10, 200),
        frame.bytes.len(),
        frame.t
    );
    sock.write_all(head.as_bytes()).await?;
    match fault {
        Apply::Truncated => {
            let half = frame.bytes.len() / 2;
            sock.write_all(&frame.bytes[..half]).await?;
        }
        Apply::BadCrc => {
            corrupt(&mut frame.bytes, format);
            sock.write_all(&frame.bytes).await?;
        }
        _ => sock.write_all(&frame.bytes).await?,
    }
    sock.flush().await
}

/// True when the viewer has closed its end (its FIN has arrived, or the socket failed). Polled
/// once, never waits: a viewer that sent extra bytes is still a live viewer.
fn peer_closed(sock: &mut TcpStream) -> bool {
    use futures_util::FutureExt;
    let mut b = [0u8; 1];
    matches!(sock.peek(&mut b).now_or_never(), Some(Ok(0) | Err(_)))
}

async fn stream(
    sock: &mut TcpStream,
    shared: &Arc<Shared>,
    req: &Request,
    first: Apply,
) -> std::io::Result<()> {
    let b = &shared.config.boundary;
    let head = format!(
        "{}Content-Type: multipart/x-mixed-replace; boundary={b}\r\nCache-Control: no-cache\r\nPragma: no-cache\r\nConnection: close\r\n\r\n",
        status_line(req.http10, 200)
    );
    sock.write_all(head.as_bytes()).await?;
    sock.flush().await?;
    let mut ticker = tokio::time::interval(shared.config.period());
    ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut fault = Some(first);
    loop {
        ticker.tick().await;
        if peer_closed(sock) {
            // A viewer that has gone must not take the next fault meant for a live one.
            return Ok(());
        }
        let apply = match fault.take() {
            Some(a) => a,
            None => take(shared).await,
        };
        match &apply {
            Apply::Close | Apply::Error(_) => return Ok(()),
            Apply::Garbage(bytes) => {
                sock.write_all(bytes).await?;
                sock.write_all(b"\r\n").await?;
            }
            _ => {}
        }
        let Some(mut frame) = render(shared, Format::Jpeg).await else {
            return Ok(());
        };
        let part = format!(
            "--{b}\r\nContent-Type: image/jpeg\r\nContent-Length: {}\r\nX-Timestamp: {:.6}\r\n\r\n",
            frame.bytes.len(),
            frame.t
        );
        sock.write_all(part.as_bytes()).await?;
        match apply {
            Apply::Truncated => {
                let half = frame.bytes.len() / 2;
                sock.write_all(&frame.bytes[..half]).await?;
                sock.flush().await?;
                return Ok(());
            }
            Apply::BadCrc => corrupt(&mut frame.bytes, Format::Jpeg),
            _ => {}
        }
        sock.write_all(&frame.bytes).await?;
        sock.write_all(b"\r\n").await?;
        sock.flush().await?;
        shared.frames.fetch_add(1, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn request_lines() {
        let r = parse_request_line(b"GET /video.mjpg?x=1 HTTP/1.1\r\nHost: a\r\n\r\n").unwrap();
        assert_eq!(r.method, "GET");
        assert_eq!(r.path, "/video.mjpg");
        assert!(!r.http10);
        assert!(parse_request_line(b"GET / HTTP/1.0\n\n").unwrap().http10);
        for bad in [
            &b"GET /\r\n\r\n"[..],
            b"GET / HTTP/2.0\r\n\r\n",
            b"get / HTTP/1.1\r\n\r\n",
            b"GET video HTTP/1.1\r\n\r\n",
            b"GET / HTTP/1.1 x\r\n\r\n",
            b"\xff\xfe / HTTP/1.1\r\n\r\n",
            b"",
        ] {
            assert!(parse_request_line(bad).is_none(), "{bad:?}");
        }
        assert_eq!(end_of_head(b"GET / HTTP/1.1\r\nA: b\r\n\r\nrest"), Some(24));
        assert_eq!(end_of_head(b"GET / HTTP/1.1\nA: b\n\n"), Some(21));
        assert_eq!(end_of_head(b"GET / HTTP/1.1\r\n"), None);
    }

    #[test]
    fn corrupting_keeps_the_length() {
        let mut j: Vec<u8> = vec![0xFF, 0xD8, 0xFF, 0xDA, 0x00, 0x04, 1, 2];
        j.extend(std::iter::repeat_n(0x55u8, 200));
        j.extend([0xFF, 0xD9]);
        let n = j.len();
        corrupt(&mut j, Format::Jpeg);
        assert_eq!(j.len(), n);
        assert_eq!(&j[..2], &[0x00, 0x27]);
        assert_eq!(j.iter().filter(|&&b| b == 0xAA).count(), 64);
        assert_eq!(&j[n - 2..], &[0xFF, 0xD9]);
    }
}
