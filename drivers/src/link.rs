//! The request/reply byte link under the line-oriented clients (NDI Combined API, KEYENCE
//! DL-RS1A): one exchange at a time over any byte stream (serial port, pty, TCP, in-memory
//! duplex), unread input dropped before each command (a late reply to an earlier one), one
//! deadline per exchange, and a receive buffer that the protocol's decoder consumes.

use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::time::Instant;

/// Why an exchange on the link failed; each client maps it to its own error enum.
#[derive(Debug)]
pub(crate) enum LinkError {
    /// The deadline passed.
    Timeout,
    /// The stream failed or ended (`UnexpectedEof`).
    Io(std::io::Error),
}

impl LinkError {
    /// This failure as the client's own error, for `command` under deadline `timeout`.
    pub fn into_error<E: FromLinkError>(self, command: &str, timeout: Duration) -> E {
        match self {
            LinkError::Timeout => E::timeout(command.to_string(), timeout.as_millis() as u64),
            LinkError::Io(source) => E::disconnected(command.to_string(), source),
        }
    }
}

/// A client error enum with the two link failures (`Timeout`, `Disconnected`).
pub(crate) trait FromLinkError {
    /// No reply to `command` within `timeout_ms`.
    fn timeout(command: String, timeout_ms: u64) -> Self;
    /// The link failed or closed during `command`.
    fn disconnected(command: String, source: std::io::Error) -> Self;
}

/// A byte stream and the bytes received but not yet decoded.
pub(crate) struct Link<T> {
    /// The stream.
    pub io: T,
    /// Received, not yet consumed.
    pub buf: Vec<u8>,
}

impl<T: AsyncRead + AsyncWrite + Unpin> Link<T> {
    /// A link over `io` with an empty buffer.
    pub fn new(io: T) -> Self {
        Self {
            io,
            buf: Vec::new(),
        }
    }

    /// Drop the buffer and whatever is already waiting in the stream (without waiting).
    pub async fn flush_input(&mut self) {
        self.buf.clear();
        let mut scratch = [0u8; 4096];
        while let Ok(Ok(n)) = tokio::time::timeout(Duration::ZERO, self.io.read(&mut scratch)).await
        {
            if n == 0 {
                break;
            }
        }
    }

    /// Start an exchange: drop stale input, then send `wire` within `timeout`; returns the
    /// exchange's deadline (for the [`Self::fill`] calls that read the reply).
    pub async fn begin(&mut self, wire: &[u8], timeout: Duration) -> Result<Instant, LinkError> {
        self.flush_input().await;
        let deadline = Instant::now() + timeout;
        self.send(wire, deadline).await?;
        Ok(deadline)
    }

    /// Write `wire` (and flush) by `deadline`.
    pub async fn send(&mut self, wire: &[u8], deadline: Instant) -> Result<(), LinkError> {
        tokio::time::timeout_at(deadline, async {
            self.io.write_all(wire).await?;
            self.io.flush().await
        })
        .await
        .map_err(|_| LinkError::Timeout)?
        .map_err(LinkError::Io)
    }

    /// Append the next bytes the stream delivers to the buffer, by `deadline`.
    pub async fn fill(&mut self, deadline: Instant) -> Result<(), LinkError> {
        let mut scratch = [0u8; 4096];
        let n = tokio::time::timeout_at(deadline, self.io.read(&mut scratch))
            .await
            .map_err(|_| LinkError::Timeout)?
            .map_err(LinkError::Io)?;
        if n == 0 {
            return Err(LinkError::Io(std::io::ErrorKind::UnexpectedEof.into()));
        }
        self.buf.extend_from_slice(&scratch[..n]);
        Ok(())
    }
}

/// Open the serial port `path` at `baud`, 8 data bits, no parity, 1 stop bit, no flow control
/// (the power-up setting of the NDI serial trackers and the DL-RS1A).
pub(crate) fn open_serial_8n1(
    path: &str,
    baud: u32,
) -> Result<tokio_serial::SerialStream, tokio_serial::Error> {
    use tokio_serial::SerialPortBuilderExt;
    tokio_serial::new(path, baud)
        .data_bits(tokio_serial::DataBits::Eight)
        .parity(tokio_serial::Parity::None)
        .stop_bits(tokio_serial::StopBits::One)
        .flow_control(tokio_serial::FlowControl::None)
        .open_native_async()
}
