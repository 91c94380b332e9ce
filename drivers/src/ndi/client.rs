//! The NDI session: one command at a time, each with a deadline.
//!
//! ```text
//! host                               tracker
//! INIT:E3A5\r                 ->
//!                             <-     OKAYA896\r
//! BX:0801<crc>\r              ->
//!                             <-     C4 A5 len hcrc body bcrc
//! ```
//! Before each command the client drops any unread bytes (a late or garbled reply to an
//! earlier command), exactly as ndicapi flushes its input. Binary replies resynchronise on
//! the `C4 A5` start sequence plus a valid header CRC, so garbage on a serial line before a
//! reply is skipped; garbage inside a text reply fails its CRC (`Protocol`) and the next
//! command starts clean.

use super::codec::{self, DecodeError, Decoded};
use super::error::Error;
use super::frame::{PortHandleStatus, Reply, TrackingReply};
use crate::link::{open_serial_8n1, Link, LinkError};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::sync::Mutex;

/// Client settings.
#[derive(Debug, Clone)]
pub struct NdiConfig {
    /// Deadline for each reply (ndicapi uses 5 s).
    pub reply_timeout: Duration,
    /// Deadline for opening the link.
    pub connect_timeout: Duration,
}

impl Default for NdiConfig {
    fn default() -> Self {
        Self {
            reply_timeout: Duration::from_secs(5),
            connect_timeout: Duration::from_secs(5),
        }
    }
}

/// A Combined API session over any byte stream (TCP, serial, in-memory duplex).
pub struct NdiClient<T> {
    link: Mutex<Link<T>>,
    config: NdiConfig,
    name: String,
}

impl<T> std::fmt::Debug for NdiClient<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NdiClient")
            .field("name", &self.name)
            .field("config", &self.config)
            .finish()
    }
}

impl NdiClient<tokio::net::TcpStream> {
    /// Connect to a Polaris Vega (port 8765 by default).
    pub async fn connect(addr: &str, config: NdiConfig) -> Result<Self, Error> {
        let open = |message: String| Error::Open {
            target: addr.to_string(),
            message,
        };
        let stream =
            tokio::time::timeout(config.connect_timeout, tokio::net::TcpStream::connect(addr))
                .await
                .map_err(|_| open("connect timed out".into()))?
                .map_err(|e| open(e.to_string()))?;
        stream.set_nodelay(true).map_err(|e| open(e.to_string()))?;
        Ok(Self::attach_named(stream, config, format!("ndi@{addr}")))
    }
}

impl NdiClient<tokio_serial::SerialStream> {
    /// Open a serial Polaris (Spectra / Vicra) at `path`, 9600 8N1 (the power-up setting).
    pub fn open_serial(path: &str, config: NdiConfig) -> Result<Self, Error> {
        let port = open_serial_8n1(path, 9600).map_err(|e| Error::Open {
            target: path.to_string(),
            message: e.to_string(),
        })?;
        Ok(Self::attach_named(port, config, format!("ndi@{path}")))
    }

    /// `COMM:<b>0000`: switch the serial speed. The device answers `OKAY` at the old speed,
    /// then the host waits 100 ms and switches (as ndicapi does).
    pub async fn set_baud(&self, baud: u32) -> Result<(), Error> {
        use tokio_serial::SerialPort;
        let digit = match baud {
            9600 => '0',
            14400 => '1',
            19200 => '2',
            38400 => '3',
            57600 => '4',
            115200 => '5',
            921600 => '6',
            1228739 => '7',
            230400 => 'A',
            other => {
                return Err(Error::InvalidArgument(format!(
                    "baud {other} is not an NDI COMM speed"
                )))
            }
        };
        let cmd = format!("COMM:{digit}0000");
        self.expect_okay(&cmd).await?;
        tokio::time::sleep(Duration::from_millis(100)).await;
        let mut link = self.link.lock().await;
        link.io
            .set_baud_rate(baud)
            .map_err(|e| Error::Disconnected {
                command: cmd,
                source: std::io::Error::other(e.to_string()),
            })
    }
}

impl<T: AsyncRead + AsyncWrite + Unpin + Send> NdiClient<T> {
    /// Use an already open byte stream.
    pub fn attach(io: T, config: NdiConfig) -> Self {
        Self::attach_named(io, config, "ndi".into())
    }

    fn attach_named(io: T, config: NdiConfig, name: String) -> Self {
        Self {
            link: Mutex::new(Link::new(io)),
            config,
            name,
        }
    }

    /// A short name for error messages (`ndi@127.0.0.1:8765`).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Send one command (without CRC or `\r`; the CRC is added when a `:` follows the
    /// command word) and return its reply. `ERRORxx` becomes [`Error::Device`].
    pub async fn command(&self, command: &str) -> Result<Reply, Error> {
        let binary = codec::is_binary_command(command);
        let mut link = self.link.lock().await;
        let link = &mut *link;
        // Drop whatever a previous (failed) exchange left behind, then send.
        let timeout = self.config.reply_timeout;
        let lift = |e: LinkError| e.into_error::<Error>(command, timeout);
        let deadline = link
            .begin(&codec::encode_command(command), timeout)
            .await
            .map_err(lift)?;
        loop {
            match codec::decode_reply(&link.buf, binary) {
                Decoded::Reply { reply, consumed } => {
                    link.buf.drain(..consumed);
                    return match reply {
                        Reply::Error(code) => Err(Error::Device {
                            command: command.to_string(),
                            code,
                        }),
                        other => Ok(other),
                    };
                }
                Decoded::Garbage { skip } => {
                    tracing::debug!(skip, command, "ndi: skipping garbage before a reply");
                    link.buf.drain(..skip);
                    continue;
                }
                Decoded::Invalid { error, .. } => {
                    link.buf.clear();
                    return Err(match error {
                        DecodeError::BadCrc { sent, computed } => Error::BadCrc {
                            command: command.to_string(),
                            sent,
                            computed,
                        },
                        DecodeError::Malformed(detail) => Error::Malformed {
                            command: command.to_string(),
                            detail,
                        },
                    });
                }
                Decoded::Incomplete => {}
            }
            link.fill(deadline).await.map_err(lift)?;
        }
    }

    fn unexpected(command: &str, reply: &Reply, wanted: &str) -> Error {
        Error::Malformed {
            command: command.to_string(),
            detail: format!("expected {wanted}, got {reply:?}"),
        }
    }

    /// Send `command` and require `OKAY`.
    pub async fn expect_okay(&self, command: &str) -> Result<(), Error> {
        match self.command(command).await? {
            Reply::Okay => Ok(()),
            other => Err(Self::unexpected(command, &other, "OKAY")),
        }
    }

    /// Send `command` and require a text reply.
    pub async fn expect_text(&self, command: &str) -> Result<String, Error> {
        match self.command(command).await? {
            Reply::Text(t) => Ok(t),
            other => Err(Self::unexpected(command, &other, "a text reply")),
        }
    }

    fn decode_err(command: &str, e: DecodeError) -> Error {
        Error::Malformed {
            command: command.to_string(),
            detail: e.to_string(),
        }
    }

    /// `INIT:`.
    pub async fn init(&self) -> Result<(), Error> {
        self.expect_okay("INIT:").await
    }

    /// `VER:n` (n = 0: main processor). Lines are separated by `\n`.
    pub async fn version(&self, n: u8) -> Result<String, Error> {
        self.expect_text(&format!("VER:{n}")).await
    }

    /// `PHSR:mm` (00 all, 01 to free, 02 not initialised, 03 not enabled, 04 enabled).
    pub async fn port_handles(&self, which: u8) -> Result<Vec<PortHandleStatus>, Error> {
        let cmd = format!("PHSR:{which:02X}");
        let text = self.expect_text(&cmd).await?;
        codec::parse_phsr(&text).map_err(|e| Self::decode_err(&cmd, e))
    }

    /// `PHF:hh`: free a handle.
    pub async fn free_handle(&self, handle: u8) -> Result<(), Error> {
        self.expect_okay(&format!("PHF:{handle:02X}")).await
    }

    /// `PHRQ:*********1****` then `PVWR` per 64 bytes: load a passive / wireless tool
    /// definition (`.rom`) and return its new port handle.
    pub async fn load_tool(&self, rom: &[u8]) -> Result<u8, Error> {
        if rom.is_empty() || rom.len() > 64 * 1024 {
            return Err(Error::InvalidArgument(format!(
                "a tool definition has {} bytes (expected 1..=65536)",
                rom.len()
            )));
        }
        let cmd = "PHRQ:*********1****";
        let text = self.expect_text(cmd).await?;
        let handle = codec::parse_phrq(&text).map_err(|e| Self::decode_err(cmd, e))?;
        for pvwr in codec::pvwr_commands(handle, rom) {
            self.expect_okay(&pvwr).await?;
        }
        Ok(handle)
    }

    /// `PINIT:hh`.
    pub async fn init_handle(&self, handle: u8) -> Result<(), Error> {
        self.expect_okay(&format!("PINIT:{handle:02X}")).await
    }

    /// `PENA:hhD`: enable a dynamic tool.
    pub async fn enable_handle(&self, handle: u8) -> Result<(), Error> {
        self.expect_okay(&format!("PENA:{handle:02X}D")).await
    }

    /// `TSTART:`.
    pub async fn start_tracking(&self) -> Result<(), Error> {
        self.expect_okay("TSTART:").await
    }

    /// `TSTOP:`.
    pub async fn stop_tracking(&self) -> Result<(), Error> {
        self.expect_okay("TSTOP:").await
    }

    /// `BX:oooo` (binary tracking data).
    pub async fn bx(&self, options: u16) -> Result<TrackingReply, Error> {
        let cmd = format!("BX:{options:04X}");
        match self.command(&cmd).await? {
            Reply::Binary(body) => {
                codec::parse_bx(&body, options).map_err(|e| Self::decode_err(&cmd, e))
            }
            other => Err(Self::unexpected(&cmd, &other, "a binary reply")),
        }
    }

    /// `TX:oooo` (text tracking data).
    pub async fn tx(&self, options: u16) -> Result<TrackingReply, Error> {
        let cmd = format!("TX:{options:04X}");
        let text = self.expect_text(&cmd).await?;
        codec::parse_tx(&text, options).map_err(|e| Self::decode_err(&cmd, e))
    }
}
