//! [`NdiTracker`]: the [`MarkerTracker`] capability over an [`NdiClient`].

use super::client::{NdiClient, NdiConfig};
use super::error::Error;
use super::frame::{HandleState, TrackingReply, PORT_OUT_OF_VOLUME, PORT_PARTIALLY_IN_VOLUME};
use crate::error::{DriverError, DriverResult};
use crate::traits::{
    Clock, MarkerToTracker, MarkerTracker, SystemClock, ToolObservation, ToolStatus, TrackerFrame,
};
use crate::ur::Backoff;
use async_trait::async_trait;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use std::future::Future;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::sync::Mutex;

/// Which tracking command the tracker sends each frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReplyMode {
    /// `BX:0801` (binary, float32; the default, as scikit-surgerynditracker uses).
    Binary,
    /// `TX:0801` (text, 0.01 mm / 1e-4 resolution).
    Text,
}

/// Reply option sent with `BX` / `TX`: transforms + status, also out-of-volume transforms.
pub const TRACKING_OPTIONS: u16 = 0x0801;

/// Opens a fresh session's byte stream (a new TCP connection, the serial port again).
pub type Reopen<T> = Arc<
    dyn Fn() -> Pin<Box<dyn Future<Output = Result<NdiClient<T>, Error>> + Send>> + Send + Sync,
>;

/// One open session: the client and the port handles of the loaded tools.
struct Session<T> {
    client: NdiClient<T>,
    tools: Vec<(u8, String)>,
}

/// A tracker with its tools loaded, initialised, enabled, and tracking started.
///
/// Built with [`NdiTracker::connect_tcp`] or [`NdiTracker::open_serial`] it rebuilds a lost
/// session by itself: when a frame fails because the link dropped or went silent, the link is
/// reopened (with backoff), the start-up sequence runs again and the frame is asked once more.
/// Built with [`NdiTracker::setup`] over an attached stream it cannot reopen the stream and
/// reports the loss.
pub struct NdiTracker<T> {
    session: Mutex<Option<Session<T>>>,
    roms: Vec<(String, Vec<u8>)>,
    mode: ReplyMode,
    clock: Arc<dyn Clock>,
    name: String,
    reopen: Option<Reopen<T>>,
    backoff: Backoff,
    recoveries: AtomicU64,
}

impl<T> std::fmt::Debug for NdiTracker<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NdiTracker")
            .field("name", &self.name)
            .field("tools", &self.roms.iter().map(|r| &r.0).collect::<Vec<_>>())
            .field("mode", &self.mode)
            .field("reopens", &self.reopen.is_some())
            .finish()
    }
}

/// Convert a tracking record into a vendor-independent status.
///
/// Out-of-volume records (port status 0x40 / 0x80: a transform reported because of option
/// 0x0800, or MISSING with the bit set) become [`ToolStatus::OutOfVolume`]; a non-finite or
/// non-unit quaternion is a protocol error.
pub fn tool_status(state: &HandleState, port_status: u32) -> Result<ToolStatus, String> {
    Ok(match *state {
        HandleState::Valid { q, t, rms } => {
            if port_status & (PORT_OUT_OF_VOLUME | PORT_PARTIALLY_IN_VOLUME) != 0 {
                return Ok(ToolStatus::OutOfVolume);
            }
            let finite = q.iter().chain(t.iter()).all(|v| v.is_finite()) && rms.is_finite();
            let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
            if !finite || !(0.5..=1.5).contains(&norm) {
                return Err(format!("implausible transform q={q:?} t={t:?}"));
            }
            let rot = UnitQuaternion::from_quaternion(Quaternion::new(q[0], q[1], q[2], q[3]));
            ToolStatus::Visible {
                pose: MarkerToTracker(Isometry3::from_parts(
                    Translation3::new(t[0], t[1], t[2]),
                    rot,
                )),
                rms_mm: rms,
            }
        }
        HandleState::Missing if port_status & PORT_OUT_OF_VOLUME != 0 => ToolStatus::OutOfVolume,
        HandleState::Missing => ToolStatus::Missing,
        HandleState::Disabled => ToolStatus::Disabled,
    })
}

/// The start-up sequence on an open client (scikit-surgerynditracker's, but freeing every
/// handle listed by `PHSR:00` instead of `PHSR:01`): `INIT`, `PHF` per old handle, per tool
/// `PHRQ` + `PVWR`, `PINIT`, `PENA:hhD`, then `TSTART`.
async fn start<T: AsyncRead + AsyncWrite + Unpin + Send>(
    client: NdiClient<T>,
    roms: &[(String, Vec<u8>)],
) -> Result<Session<T>, Error> {
    client.init().await?;
    // Take the tracker over: free every handle a previous session left (scikit-
    // surgerynditracker frees only those listed as "to be freed", PHSR:01, and leaves its own
    // loaded tools behind on close; a session rebuilt after a dropped link finds its own).
    for h in client.port_handles(0x00).await? {
        client.free_handle(h.handle).await?;
    }
    let mut loaded = Vec::with_capacity(roms.len());
    for (name, rom) in roms {
        let handle = client.load_tool(rom).await?;
        loaded.push((handle, name.clone()));
    }
    for (handle, _) in &loaded {
        client.init_handle(*handle).await?;
    }
    for (handle, _) in &loaded {
        client.enable_handle(*handle).await?;
    }
    client.start_tracking().await?;
    Ok(Session {
        client,
        tools: loaded,
    })
}

impl NdiTracker<tokio::net::TcpStream> {
    /// Connect to a Polaris Vega at `addr` and start tracking `tools` (`(name, .rom bytes)`);
    /// a dropped or silent link is reconnected and the session rebuilt on the next frame.
    pub async fn connect_tcp(
        addr: &str,
        config: NdiConfig,
        tools: &[(String, Vec<u8>)],
        mode: ReplyMode,
    ) -> Result<Self, Error> {
        let addr = addr.to_string();
        let reopen: Reopen<tokio::net::TcpStream> = Arc::new(move || {
            let (addr, config) = (addr.clone(), config.clone());
            Box::pin(async move { NdiClient::connect(&addr, config).await })
        });
        Self::with_reopen(reopen, tools, mode).await
    }
}

impl NdiTracker<tokio_serial::SerialStream> {
    /// Open a serial Polaris (Spectra / Vicra) at `path` (9600 8N1) and start tracking `tools`;
    /// a failed or silent port is reopened and the session rebuilt on the next frame.
    pub async fn open_serial(
        path: &str,
        config: NdiConfig,
        tools: &[(String, Vec<u8>)],
        mode: ReplyMode,
    ) -> Result<Self, Error> {
        let path = path.to_string();
        let reopen: Reopen<tokio_serial::SerialStream> = Arc::new(move || {
            let r = NdiClient::open_serial(&path, config.clone());
            Box::pin(async move { r })
        });
        Self::with_reopen(reopen, tools, mode).await
    }
}

impl<T: AsyncRead + AsyncWrite + Unpin + Send> NdiTracker<T> {
    /// Run the start-up sequence over an attached client (no reconnection: a lost link is an
    /// error on every later frame). `tools` are `(name, .rom bytes)`.
    pub async fn setup(
        client: NdiClient<T>,
        tools: &[(String, Vec<u8>)],
        mode: ReplyMode,
    ) -> Result<Self, Error> {
        if tools.is_empty() {
            return Err(Error::InvalidArgument("no tool definitions given".into()));
        }
        let name = client.name().to_string();
        let session = start(client, tools).await?;
        Ok(Self {
            session: Mutex::new(Some(session)),
            roms: tools.to_vec(),
            mode,
            clock: Arc::new(SystemClock::default()),
            name,
            reopen: None,
            backoff: Backoff::default(),
            recoveries: AtomicU64::new(0),
        })
    }

    /// Open through `reopen` (with backoff) and start tracking; `reopen` is used again whenever
    /// the link is lost.
    pub async fn with_reopen(
        reopen: Reopen<T>,
        tools: &[(String, Vec<u8>)],
        mode: ReplyMode,
    ) -> Result<Self, Error> {
        if tools.is_empty() {
            return Err(Error::InvalidArgument("no tool definitions given".into()));
        }
        let backoff = Backoff::default();
        let session = backoff
            .retry(|| async { start(reopen().await?, tools).await })
            .await?;
        Ok(Self {
            name: session.client.name().to_string(),
            session: Mutex::new(Some(session)),
            roms: tools.to_vec(),
            mode,
            clock: Arc::new(SystemClock::default()),
            reopen: Some(reopen),
            backoff,
            recoveries: AtomicU64::new(0),
        })
    }

    /// Use `clock` for frame timestamps (the world's virtual clock in dry runs).
    pub fn with_clock(mut self, clock: Arc<dyn Clock>) -> Self {
        self.clock = clock;
        self
    }

    /// The loaded tools as `(port handle, name)` of the current session (empty while the link
    /// is down).
    pub async fn tools(&self) -> Vec<(u8, String)> {
        self.session
            .lock()
            .await
            .as_ref()
            .map(|s| s.tools.clone())
            .unwrap_or_default()
    }

    /// A short name for messages (`ndi@127.0.0.1:8765`).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// One raw tracking reply, with the tools of the session that produced it. A lost link
    /// is rebuilt once (when this tracker can reopen it) before the error is reported.
    async fn reply(&self) -> Result<(TrackingReply, Vec<(u8, String)>), Error> {
        use crate::error::DeviceError as _;
        let mut g = self.session.lock().await;
        for attempt in 0..2 {
            if g.is_none() {
                let Some(reopen) = &self.reopen else {
                    return Err(Error::Open {
                        target: self.name.clone(),
                        message: "the session was lost and this tracker cannot reopen it".into(),
                    });
                };
                tracing::warn!("{}: reopening the NDI session", self.name);
                let roms = &self.roms;
                *g = Some(
                    self.backoff
                        .retry(|| async { start(reopen().await?, roms).await })
                        .await?,
                );
                self.recoveries.fetch_add(1, Ordering::Relaxed);
            }
            let s = g.as_ref().expect("set above");
            let r = match self.mode {
                ReplyMode::Binary => s.client.bx(TRACKING_OPTIONS).await,
                ReplyMode::Text => s.client.tx(TRACKING_OPTIONS).await,
            };
            match r {
                Ok(reply) => return Ok((reply, s.tools.clone())),
                Err(e) if self.reopen.is_some() && e.kind().needs_reconnect() => {
                    // The link is in doubt: do not reuse it (a late reply would answer the
                    // next command); open a new one. (An attached stream cannot be reopened:
                    // its client drops stale bytes before the next command instead.)
                    *g = None;
                    if attempt == 1 {
                        return Err(e);
                    }
                }
                Err(e) => return Err(e),
            }
        }
        unreachable!("the second attempt returns")
    }

    /// One raw tracking reply.
    pub async fn tracking_reply(&self) -> Result<TrackingReply, Error> {
        self.reply().await.map(|(r, _)| r)
    }

    /// `TSTOP`.
    pub async fn stop(&self) -> Result<(), Error> {
        match self.session.lock().await.as_ref() {
            Some(s) => s.client.stop_tracking().await,
            None => Ok(()),
        }
    }

    fn to_frame(
        &self,
        reply: &TrackingReply,
        tools: &[(u8, String)],
    ) -> Result<TrackerFrame, Error> {
        let mut out = Vec::with_capacity(reply.handles.len());
        let mut frame_number = 0u64;
        for rec in &reply.handles {
            let name = tools
                .iter()
                .find(|(h, _)| *h == rec.handle)
                .map_or_else(|| format!("{:02X}", rec.handle), |(_, n)| n.clone());
            let status =
                tool_status(&rec.state, rec.port_status).map_err(|detail| Error::Malformed {
                    command: "BX/TX".into(),
                    detail: format!("handle {:02X}: {detail}", rec.handle),
                })?;
            frame_number = frame_number.max(u64::from(rec.frame));
            out.push(ToolObservation { tool: name, status });
        }
        Ok(TrackerFrame {
            frame_number,
            t: self.clock.now(),
            tools: out,
        })
    }
}

#[async_trait]
impl<T: AsyncRead + AsyncWrite + Unpin + Send> MarkerTracker for NdiTracker<T> {
    async fn frame(&self) -> DriverResult<TrackerFrame> {
        let (reply, tools) = self
            .reply()
            .await
            .map_err(|e| DriverError::from_device(self.name.clone(), e))?;
        self.to_frame(&reply, &tools)
            .map_err(|e| DriverError::from_device(self.name.clone(), e))
    }
    fn link_recoveries(&self) -> u64 {
        self.recoveries.load(Ordering::Relaxed)
    }
}
