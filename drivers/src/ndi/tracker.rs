//! [`NdiTracker`]: the [`MarkerTracker`] capability over an [`NdiClient`].

use super::client::NdiClient;
use super::error::Error;
use super::frame::{HandleState, TrackingReply, PORT_OUT_OF_VOLUME, PORT_PARTIALLY_IN_VOLUME};
use crate::error::{DriverError, DriverResult};
use crate::traits::{
    Clock, MarkerToTracker, MarkerTracker, SystemClock, ToolObservation, ToolStatus, TrackerFrame,
};
use async_trait::async_trait;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use std::sync::Arc;
use tokio::io::{AsyncRead, AsyncWrite};

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

/// A tracker with its tools loaded, initialised, enabled, and tracking started.
pub struct NdiTracker<T> {
    client: NdiClient<T>,
    tools: Vec<(u8, String)>,
    mode: ReplyMode,
    clock: Arc<dyn Clock>,
}

impl<T> std::fmt::Debug for NdiTracker<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NdiTracker")
            .field("client", &self.client)
            .field("tools", &self.tools)
            .field("mode", &self.mode)
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

impl<T: AsyncRead + AsyncWrite + Unpin + Send> NdiTracker<T> {
    /// Run the start-up sequence (scikit-surgerynditracker's, but freeing every handle listed
    /// by `PHSR:00` instead of `PHSR:01`): `INIT`, `PHF` per old handle, per tool `PHRQ` + `PVWR`, `PINIT`, `PENA:hhD`, then `TSTART`.
    /// `tools` are `(name, .rom bytes)`.
    pub async fn setup(
        client: NdiClient<T>,
        tools: &[(String, Vec<u8>)],
        mode: ReplyMode,
    ) -> Result<Self, Error> {
        client.init().await?;
        // Take the tracker over: free every handle a previous session left (scikit-
        // surgerynditracker frees only those listed as "to be freed", PHSR:01, and leaves
        // its own loaded tools behind on close).
        if tools.is_empty() {
            return Err(Error::InvalidArgument("no tool definitions given".into()));
        }
        for h in client.port_handles(0x00).await? {
            client.free_handle(h.handle).await?;
        }
        let mut loaded = Vec::with_capacity(tools.len());
        for (name, rom) in tools {
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
        Ok(Self {
            client,
            tools: loaded,
            mode,
            clock: Arc::new(SystemClock::default()),
        })
    }

    /// Use `clock` for frame timestamps (the world's virtual clock in dry runs).
    pub fn with_clock(mut self, clock: Arc<dyn Clock>) -> Self {
        self.clock = clock;
        self
    }

    /// The loaded tools as `(port handle, name)`.
    pub fn tools(&self) -> &[(u8, String)] {
        &self.tools
    }

    /// The underlying session.
    pub fn client(&self) -> &NdiClient<T> {
        &self.client
    }

    /// One raw tracking reply.
    pub async fn tracking_reply(&self) -> Result<TrackingReply, Error> {
        match self.mode {
            ReplyMode::Binary => self.client.bx(TRACKING_OPTIONS).await,
            ReplyMode::Text => self.client.tx(TRACKING_OPTIONS).await,
        }
    }

    /// `TSTOP`.
    pub async fn stop(&self) -> Result<(), Error> {
        self.client.stop_tracking().await
    }

    fn to_frame(&self, reply: &TrackingReply) -> Result<TrackerFrame, Error> {
        let mut tools = Vec::with_capacity(reply.handles.len());
        let mut frame_number = 0u64;
        for rec in &reply.handles {
            let name = self
                .tools
                .iter()
                .find(|(h, _)| *h == rec.handle)
                .map_or_else(|| format!("{:02X}", rec.handle), |(_, n)| n.clone());
            let status =
                tool_status(&rec.state, rec.port_status).map_err(|detail| Error::Malformed {
                    command: "BX/TX".into(),
                    detail: format!("handle {:02X}: {detail}", rec.handle),
                })?;
            frame_number = frame_number.max(u64::from(rec.frame));
            tools.push(ToolObservation { tool: name, status });
        }
        Ok(TrackerFrame {
            frame_number,
            t: self.clock.now(),
            tools,
        })
    }
}

#[async_trait]
impl<T: AsyncRead + AsyncWrite + Unpin + Send> MarkerTracker for NdiTracker<T> {
    async fn frame(&self) -> DriverResult<TrackerFrame> {
        let device = self.client.name().to_string();
        let reply = self
            .tracking_reply()
            .await
            .map_err(|e| DriverError::from_device(device.clone(), e))?;
        self.to_frame(&reply)
            .map_err(|e| DriverError::from_device(device, e))
    }
}
