//! The DL-RS1A session: one command at a time, each with a deadline.
//!
//! ```text
//! host              DL-RS1A
//! M0\r\n      ->
//!             <-    M0,+123.45\r\n
//! ```
//! Before each command the client drops unread bytes (a late reply to an earlier command).
//! While waiting it skips every line that is not a reply to the pending command (garbage on
//! the line, a stray echo): the read resynchronises on the next `\r\n`.

use super::codec;
use super::error::Error;
use super::frame::{Reply, Request, Value};
use crate::error::{DriverError, DriverResult};
use crate::link::{open_serial_8n1, Link, LinkError};
use crate::traits::{RangeReading, RangeSensor};
use async_trait::async_trait;
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::sync::Mutex;

/// Client settings.
#[derive(Debug, Clone)]
pub struct KeyenceConfig {
    /// Deadline per reply (the manual's IG edition: the unit answers within 1 s).
    pub reply_timeout: Duration,
    /// Serial speed (DIP switches; default 9600).
    pub baud: u32,
}

impl Default for KeyenceConfig {
    fn default() -> Self {
        Self {
            reply_timeout: Duration::from_secs(1),
            baud: 9600,
        }
    }
}

/// A DL-RS1A session over any byte stream (serial port, pty, in-memory duplex).
pub struct KeyenceClient<T> {
    link: Mutex<Link<T>>,
    config: KeyenceConfig,
    name: String,
}

impl<T> std::fmt::Debug for KeyenceClient<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("KeyenceClient")
            .field("name", &self.name)
            .field("config", &self.config)
            .finish()
    }
}

impl KeyenceClient<tokio_serial::SerialStream> {
    /// Open the DL-RS1A at `path` (8N1, speed from the config).
    pub fn open_serial(path: &str, config: KeyenceConfig) -> Result<Self, Error> {
        let port = open_serial_8n1(path, config.baud).map_err(|e| Error::Open {
            path: path.to_string(),
            message: e.to_string(),
        })?;
        Ok(Self::attach_named(port, config, format!("dl-rs1a@{path}")))
    }
}

impl<T: AsyncRead + AsyncWrite + Unpin + Send> KeyenceClient<T> {
    /// Use an already open byte stream.
    pub fn attach(io: T, config: KeyenceConfig) -> Self {
        Self::attach_named(io, config, "dl-rs1a".into())
    }

    fn attach_named(io: T, config: KeyenceConfig, name: String) -> Self {
        Self {
            link: Mutex::new(Link::new(io)),
            config,
            name,
        }
    }

    /// Device name for messages.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Send one request and return its reply; `ER` becomes [`Error::Device`].
    pub async fn request(&self, req: &Request) -> Result<Reply, Error> {
        let command = req.command();
        let mut guard = self.link.lock().await;
        let link = &mut *guard;
        let timeout = self.config.reply_timeout;
        let lift = |e: LinkError| e.into_error::<Error>(command, timeout);
        let deadline = link
            .begin(&codec::encode_request(req), timeout)
            .await
            .map_err(lift)?;
        loop {
            while let Some((line, used)) = codec::take_line(&link.buf) {
                if codec::is_reply_to(line, command) {
                    let decoded = codec::decode_line(line);
                    link.buf.drain(..used);
                    return match decoded {
                        Ok(Reply::Er { command: c, code }) => {
                            Err(Error::Device { command: c, code })
                        }
                        Ok(reply) => Ok(reply),
                        Err(e) => Err(Error::Malformed {
                            command: command.to_string(),
                            detail: e.to_string(),
                        }),
                    };
                }
                tracing::debug!(
                    command,
                    skipped = used,
                    "dl-rs1a: skipping a line that is not the reply"
                );
                link.buf.drain(..used);
            }
            link.fill(deadline).await.map_err(lift)?;
        }
    }

    fn unexpected(req: &Request, reply: &Reply) -> Error {
        Error::Malformed {
            command: req.command().into(),
            detail: format!("unexpected reply {reply:?}"),
        }
    }

    /// `M0`: the measured value of every amplifier, in ID order.
    pub async fn read_all(&self) -> Result<Vec<Value>, Error> {
        match self.request(&Request::M0).await? {
            Reply::M0(v) => Ok(v),
            other => Err(Self::unexpected(&Request::M0, &other)),
        }
    }

    /// `MS`: control output and value of every amplifier.
    pub async fn read_outputs(&self) -> Result<Vec<(u8, Value)>, Error> {
        match self.request(&Request::Ms).await? {
            Reply::Ms(v) => Ok(v),
            other => Err(Self::unexpected(&Request::Ms, &other)),
        }
    }

    /// `SR,<id>,<data no>`: one item, as text.
    pub async fn read_item(&self, id: u8, data_no: u16) -> Result<String, Error> {
        let req = Request::Sr { id, data_no };
        match self.request(&req).await? {
            Reply::Sr {
                id: rid,
                data_no: rno,
                data,
            } if rid == id && rno == data_no => Ok(data),
            other => Err(Self::unexpected(&req, &other)),
        }
    }

    /// `SW,<id>,<data no>,<value>`.
    pub async fn write_item(&self, id: u8, data_no: u16, value: &str) -> Result<(), Error> {
        if value.is_empty() || value.len() > 10 || value.contains([',', '\r', '\n']) {
            return Err(Error::InvalidArgument(format!("SW value `{value}`")));
        }
        let req = Request::Sw {
            id,
            data_no,
            value: value.into(),
        };
        match self.request(&req).await? {
            Reply::Sw {
                id: rid,
                data_no: rno,
            } if rid == id && rno == data_no => Ok(()),
            other => Err(Self::unexpected(&req, &other)),
        }
    }
}

/// Settings of the IL-600 range sensor view.
#[derive(Debug, Clone)]
pub struct Il600Config {
    /// Which amplifier's value (index in the `M0` reply; 0 = main unit ID 00).
    pub amplifier: usize,
    /// Added to the displayed value to give the distance from the head (mm). The IL-600
    /// displays the deviation from its 600 mm reference distance unless shifted.
    pub offset_mm: f64,
}

impl Default for Il600Config {
    fn default() -> Self {
        Self {
            amplifier: 0,
            offset_mm: 600.0,
        }
    }
}

/// An IL-600 head behind a DL-RS1A: the [`RangeSensor`] capability (one `M0` per reading).
///
/// Display limits and "no measurement" give [`RangeReading::OutOfRange`]; `+EEE.EE` gives
/// an [`Error::AmplifierError`] (kind `DeviceRejected`).
#[derive(Debug)]
pub struct Il600<T> {
    client: KeyenceClient<T>,
    config: Il600Config,
}

impl<T: AsyncRead + AsyncWrite + Unpin + Send> Il600<T> {
    /// Wrap a session.
    pub fn new(client: KeyenceClient<T>, config: Il600Config) -> Self {
        Self { client, config }
    }

    /// The session.
    pub fn client(&self) -> &KeyenceClient<T> {
        &self.client
    }

    /// One reading.
    pub async fn reading(&self) -> Result<RangeReading, Error> {
        let values = self.client.read_all().await?;
        let v = values.get(self.config.amplifier).ok_or_else(|| {
            Error::InvalidArgument(format!(
                "amplifier {} not in a reply with {} values",
                self.config.amplifier,
                values.len()
            ))
        })?;
        Ok(match v {
            Value::Measured(mm) => RangeReading::Distance(mm + self.config.offset_mm),
            Value::UpperLimit | Value::LowerLimit | Value::NoMeasurement(_) => {
                RangeReading::OutOfRange
            }
            Value::AmplifierError => {
                return Err(Error::AmplifierError {
                    amplifier: self.config.amplifier,
                })
            }
        })
    }
}

#[async_trait]
impl<T: AsyncRead + AsyncWrite + Unpin + Send> RangeSensor for Il600<T> {
    async fn read_range(&self) -> DriverResult<RangeReading> {
        self.reading()
            .await
            .map_err(|e| DriverError::from_device(self.client.name().to_string(), e))
    }
}
