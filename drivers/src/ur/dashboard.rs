//! Dashboard server (TCP 29999): ASCII lines, one reply line per command.
//!
//! # Contract
//! On connect the server sends a banner line (`Connected: Universal Robots Dashboard Server`),
//! read within the request timeout. Each command is `text\n`; the reply is one line.
//! Expected replies (protocols.md §1.8; ur_rtde `dashboard_client.cpp` checks the same strings):
//! `power on` → `Powering on`, `brake release` → `Brake releasing`, `play` → `Starting
//! program`, `stop` → `Stopped`, `unlock protective stop` → `Protective stop releasing`,
//! `robotmode` → `Robotmode: <MODE>`, `safetystatus` → `Safetystatus: <MODE>`. Any other reply
//! to these is a refusal ([`UrError::Rejected`], kind `DeviceRejected`).

use super::error::{Interface, UrError};
use super::rtde::frame::{RobotMode, SafetyMode};
use super::{tcp_connect, Transport};
use bytes::{Buf, BufMut, BytesMut};
use futures_util::{SinkExt as _, StreamExt as _};
use std::time::Duration;
use tokio::sync::Mutex;
use tokio_util::codec::{Decoder, Encoder, Framed};

/// Longest line accepted (the server's longest reply is well below this).
pub const MAX_LINE: usize = 4096;

/// A malformed dashboard line.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LineError {
    /// More than [`MAX_LINE`] bytes without a newline.
    #[error("line longer than {MAX_LINE} bytes")]
    TooLong,
    /// Not UTF-8.
    #[error("line is not UTF-8")]
    NotUtf8,
    /// The transport failed.
    #[error("i/o: {0}")]
    Io(#[from] std::io::Error),
}

/// `\n`-terminated lines (a trailing `\r` is dropped), capped at [`MAX_LINE`] bytes.
#[derive(Debug, Default, Clone, Copy)]
pub struct LineCodec;

impl Decoder for LineCodec {
    type Item = String;
    type Error = LineError;
    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<String>, LineError> {
        match src.iter().position(|&b| b == b'\n') {
            Some(i) if i > MAX_LINE => Err(LineError::TooLong),
            Some(i) => {
                let mut line = src.split_to(i + 1);
                line.truncate(i);
                if line.last() == Some(&b'\r') {
                    line.truncate(i - 1);
                }
                String::from_utf8(line.to_vec())
                    .map(Some)
                    .map_err(|_| LineError::NotUtf8)
            }
            None if src.len() > MAX_LINE => Err(LineError::TooLong),
            None => Ok(None),
        }
    }
}

impl Encoder<String> for LineCodec {
    type Error = LineError;
    fn encode(&mut self, item: String, dst: &mut BytesMut) -> Result<(), LineError> {
        dst.reserve(item.len() + 1);
        dst.put_slice(item.as_bytes());
        dst.put_u8(b'\n');
        Ok(())
    }
}

impl LineCodec {
    /// Decode every complete line of `bytes` (testing / fuzzing helper).
    pub fn decode_all(bytes: &[u8]) -> Result<Vec<String>, LineError> {
        let mut buf = BytesMut::from(bytes);
        let mut out = Vec::new();
        let mut c = LineCodec;
        while let Some(l) = c.decode(&mut buf)? {
            out.push(l);
        }
        let _ = buf.remaining();
        Ok(out)
    }
}

/// Parse `Robotmode: RUNNING`.
pub fn parse_robot_mode(line: &str) -> Option<RobotMode> {
    let rest = line.trim().strip_prefix("Robotmode:")?;
    RobotMode::from_name(rest.trim())
}

/// Parse `Safetystatus: NORMAL` or `Safetymode: NORMAL`.
pub fn parse_safety(line: &str) -> Option<SafetyMode> {
    let l = line.trim();
    let rest = l
        .strip_prefix("Safetystatus:")
        .or_else(|| l.strip_prefix("Safetymode:"))?;
    SafetyMode::from_name(rest.trim())
}

/// A dashboard session.
pub struct DashboardClient {
    framed: Mutex<Framed<Box<dyn Transport>, LineCodec>>,
    banner: String,
    timeout: Duration,
}

impl std::fmt::Debug for DashboardClient {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DashboardClient")
            .field("banner", &self.banner)
            .finish()
    }
}

fn line_err(e: LineError) -> UrError {
    match e {
        LineError::Io(e) => UrError::io(Interface::Dashboard, e),
        e => UrError::Protocol {
            interface: Interface::Dashboard,
            detail: e.to_string(),
        },
    }
}

impl DashboardClient {
    /// Connect over TCP (`host:29999`) and read the banner.
    pub async fn connect(addr: &str, timeout: Duration) -> Result<Self, UrError> {
        let s = tcp_connect(Interface::Dashboard, addr, timeout).await?;
        Self::attach(s, timeout).await
    }

    /// Use any byte stream; reads the banner line.
    pub async fn attach<T: Transport>(io: T, timeout: Duration) -> Result<Self, UrError> {
        let boxed: Box<dyn Transport> = Box::new(io);
        let mut framed = Framed::new(boxed, LineCodec);
        let banner = read_line(&mut framed, timeout, "the banner").await?;
        if !banner.contains("Dashboard") {
            return Err(UrError::Protocol {
                interface: Interface::Dashboard,
                detail: format!("unexpected banner {banner:?}"),
            });
        }
        Ok(Self {
            framed: Mutex::new(framed),
            banner,
            timeout,
        })
    }

    /// The banner line.
    pub fn banner(&self) -> &str {
        &self.banner
    }

    /// Send one command, return its reply line.
    pub async fn command(&self, cmd: &str) -> Result<String, UrError> {
        if cmd.contains('\n') || cmd.contains('\r') {
            return Err(UrError::InvalidArgument(format!(
                "dashboard command with a line break: {cmd:?}"
            )));
        }
        let mut f = self.framed.lock().await;
        tokio::time::timeout(self.timeout, f.send(cmd.to_string()))
            .await
            .map_err(|_| UrError::Timeout {
                interface: Interface::Dashboard,
                what: format!("sending `{cmd}`"),
                secs: self.timeout.as_secs_f64(),
            })?
            .map_err(line_err)?;
        read_line(&mut f, self.timeout, cmd).await
    }

    async fn expect(&self, cmd: &str, ok: &str) -> Result<(), UrError> {
        let reply = self.command(cmd).await?;
        if reply.trim().starts_with(ok) {
            Ok(())
        } else {
            Err(UrError::Rejected {
                interface: Interface::Dashboard,
                what: cmd.to_string(),
                reply,
            })
        }
    }

    /// `power on`.
    pub async fn power_on(&self) -> Result<(), UrError> {
        self.expect("power on", "Powering on").await
    }
    /// `power off`.
    pub async fn power_off(&self) -> Result<(), UrError> {
        self.expect("power off", "Powering off").await
    }
    /// `brake release`.
    pub async fn brake_release(&self) -> Result<(), UrError> {
        self.expect("brake release", "Brake releasing").await
    }
    /// `play` (the loaded program).
    pub async fn play(&self) -> Result<(), UrError> {
        self.expect("play", "Starting program").await
    }
    /// `stop` (the running program).
    pub async fn stop(&self) -> Result<(), UrError> {
        self.expect("stop", "Stopped").await
    }
    /// `unlock protective stop`.
    pub async fn unlock_protective_stop(&self) -> Result<(), UrError> {
        self.expect("unlock protective stop", "Protective stop releasing")
            .await
    }
    /// `close safety popup`.
    pub async fn close_safety_popup(&self) -> Result<(), UrError> {
        self.expect("close safety popup", "closing safety popup")
            .await
    }
    /// `robotmode`.
    pub async fn robot_mode(&self) -> Result<RobotMode, UrError> {
        let r = self.command("robotmode").await?;
        parse_robot_mode(&r).ok_or_else(|| UrError::Protocol {
            interface: Interface::Dashboard,
            detail: format!("cannot parse robotmode reply {r:?}"),
        })
    }
    /// `safetystatus`.
    pub async fn safety_status(&self) -> Result<SafetyMode, UrError> {
        let r = self.command("safetystatus").await?;
        parse_safety(&r).ok_or_else(|| UrError::Protocol {
            interface: Interface::Dashboard,
            detail: format!("cannot parse safetystatus reply {r:?}"),
        })
    }
}

async fn read_line(
    f: &mut Framed<Box<dyn Transport>, LineCodec>,
    timeout: Duration,
    what: &str,
) -> Result<String, UrError> {
    match tokio::time::timeout(timeout, f.next()).await {
        Err(_) => Err(UrError::Timeout {
            interface: Interface::Dashboard,
            what: format!("waiting for the reply to `{what}`"),
            secs: timeout.as_secs_f64(),
        }),
        Ok(None) => Err(UrError::Disconnected {
            interface: Interface::Dashboard,
            detail: format!("closed while waiting for the reply to `{what}`"),
        }),
        Ok(Some(r)) => r.map_err(line_err),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};

    #[test]
    fn lines_split_and_cap() {
        assert_eq!(
            LineCodec::decode_all(b"Robotmode: RUNNING\nStopped\r\npartial").unwrap(),
            vec!["Robotmode: RUNNING".to_string(), "Stopped".to_string()]
        );
        assert!(LineCodec::decode_all(&vec![b'a'; MAX_LINE + 2]).is_err());
        assert!(LineCodec::decode_all(b"\xff\xfe\n").is_err());
        assert_eq!(
            parse_robot_mode("Robotmode: POWER_OFF"),
            Some(RobotMode::PowerOff)
        );
        assert_eq!(
            parse_safety("Safetystatus: PROTECTIVE_STOP"),
            Some(SafetyMode::ProtectiveStop)
        );
        assert_eq!(parse_safety("Robotmode: RUNNING"), None);
    }

    #[tokio::test]
    async fn commands_over_a_pipe_and_refusals_are_device_rejected() {
        use crate::error::{DeviceError, ErrorKind};
        let (a, b) = tokio::io::duplex(1024);
        let server = tokio::spawn(async move {
            let (r, mut w) = tokio::io::split(b);
            w.write_all(b"Connected: Universal Robots Dashboard Server\n")
                .await
                .unwrap();
            let mut lines = BufReader::new(r).lines();
            while let Some(l) = lines.next_line().await.unwrap() {
                let reply = match l.as_str() {
                    "power on" => "Powering on",
                    "robotmode" => "Robotmode: IDLE",
                    _ => "Cannot unlock protective stop until 5s after occurrence. Always inspect cause of protective stop before unlocking",
                };
                w.write_all(format!("{reply}\n").as_bytes()).await.unwrap();
            }
        });
        let c = DashboardClient::attach(a, Duration::from_secs(1))
            .await
            .unwrap();
        c.power_on().await.unwrap();
        assert_eq!(c.robot_mode().await.unwrap(), RobotMode::Idle);
        let e = c.unlock_protective_stop().await.unwrap_err();
        assert_eq!(e.kind(), ErrorKind::DeviceRejected);
        drop(c);
        server.await.unwrap();
    }

    #[tokio::test]
    async fn silence_is_a_timeout() {
        use crate::error::{DeviceError, ErrorKind};
        let (a, _b) = tokio::io::duplex(64);
        let e = DashboardClient::attach(a, Duration::from_millis(50))
            .await
            .unwrap_err();
        assert_eq!(e.kind(), ErrorKind::Timeout);
    }
}
