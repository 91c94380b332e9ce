//! Universal Robots (CB3 / e-Series) over RTDE (30004), the dashboard server (29999) and the
//! script interface (30003).
//!
//! Layers: [`rtde::frame`] (pure data) / [`rtde::codec`] (bytes) / [`rtde::client`] (session),
//! [`dashboard`] (line codec + client), [`script`] (URScript sender), and [`arm::UrArm`], which
//! implements the capability traits on top of the three clients.
//!
//! # Motion: `movej` URScript, completion confirmed from RTDE
//! [`arm::UrArm::move_joints`] sends a one-line `movej` program over the script interface and
//! confirms arrival from the RTDE stream (`runtime_state` back to STOPPED with `actual_q` at
//! the target). ur_rtde's alternative (upload a 1300-line control script and drive it through
//! input registers) buys servo/force modes the calibration cell never uses; point-to-point
//! moves need only `movej`, and the program state plus `actual_q` are already streamed.
//!
//! # Safety
//! The raw clients and [`arm::UrArm`] move the robot without any limit checks. The
//! acquisition engine must only ever hold a UR arm wrapped by
//! [`crate::safety::guard`]; never call `move_joints` on these types directly.
//!
//! Units: radians and millimetres at the trait boundary; the wire speaks radians and metres.

pub mod arm;
pub mod dashboard;
pub mod error;
pub mod rtde;
pub mod script;

pub use arm::{UrArm, UrConfig};
pub use error::{Interface, UrError};

use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite};

/// Any byte stream a client can run over (TCP, duplex pipe, …).
pub trait Transport: AsyncRead + AsyncWrite + Send + Unpin + 'static {}
impl<T: AsyncRead + AsyncWrite + Send + Unpin + 'static> Transport for T {}

/// Default ports.
pub mod ports {
    /// RTDE.
    pub const RTDE: u16 = 30004;
    /// Dashboard server.
    pub const DASHBOARD: u16 = 29999;
    /// Real-time interface (accepts URScript).
    pub const SCRIPT: u16 = 30003;
}

pub(crate) async fn tcp_connect(
    interface: Interface,
    addr: &str,
    timeout: Duration,
) -> Result<tokio::net::TcpStream, UrError> {
    let s = tokio::time::timeout(timeout, tokio::net::TcpStream::connect(addr))
        .await
        .map_err(|_| UrError::Timeout {
            interface,
            what: format!("connecting to {addr}"),
            secs: timeout.as_secs_f64(),
        })?
        .map_err(|source| UrError::Connect {
            interface,
            addr: addr.to_string(),
            source,
        })?;
    let _ = s.set_nodelay(true);
    Ok(s)
}

/// Reconnect policy: `attempts` tries, waiting `initial`, then doubling up to `max`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Backoff {
    /// Number of connection attempts (≥ 1).
    pub attempts: u32,
    /// First wait between attempts.
    pub initial: Duration,
    /// Longest wait between attempts.
    pub max: Duration,
}

impl Default for Backoff {
    fn default() -> Self {
        Self {
            attempts: 5,
            initial: Duration::from_millis(50),
            max: Duration::from_secs(2),
        }
    }
}

impl Backoff {
    /// The wait before attempt `i` (0-based; attempt 0 has none).
    pub fn delay(&self, i: u32) -> Duration {
        if i == 0 {
            return Duration::ZERO;
        }
        let d = self.initial.saturating_mul(1u32 << (i - 1).min(16));
        d.min(self.max)
    }

    /// Run `f` until it succeeds or the attempts are used up; returns the last error.
    pub async fn retry<T, E, F, Fut>(&self, mut f: F) -> Result<T, E>
    where
        F: FnMut() -> Fut,
        Fut: std::future::Future<Output = Result<T, E>>,
    {
        let mut i = 0;
        loop {
            tokio::time::sleep(self.delay(i)).await;
            match f().await {
                Ok(v) => return Ok(v),
                Err(e) if i + 1 >= self.attempts.max(1) => return Err(e),
                Err(_) => i += 1,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backoff_doubles_and_caps() {
        let b = Backoff {
            attempts: 10,
            initial: Duration::from_millis(10),
            max: Duration::from_millis(50),
        };
        assert_eq!(b.delay(0), Duration::ZERO);
        assert_eq!(b.delay(1), Duration::from_millis(10));
        assert_eq!(b.delay(2), Duration::from_millis(20));
        assert_eq!(b.delay(3), Duration::from_millis(40));
        assert_eq!(b.delay(4), Duration::from_millis(50));
        assert_eq!(b.delay(40), Duration::from_millis(50));
    }

    #[tokio::test]
    async fn retry_stops_after_attempts() {
        let b = Backoff {
            attempts: 3,
            initial: Duration::from_millis(1),
            max: Duration::from_millis(2),
        };
        let mut n = 0;
        let r: Result<(), u32> = b
            .retry(|| {
                n += 1;
                let k = n;
                async move { Err(k) }
            })
            .await;
        assert_eq!(r, Err(3));
        let mut n = 0;
        let r: Result<u32, u32> = b
            .retry(|| {
                n += 1;
                let k = n;
                async move {
                    if k == 2 {
                        Ok(k)
                    } else {
                        Err(k)
                    }
                }
            })
            .await;
        assert_eq!(r, Ok(2));
    }
}
