//! Script interface (TCP 30003; 30001/30002 accept the same): URScript text in, nothing read.
//!
//! A program is `def name():` in column 1, indented body, `end` in column 1; a new program
//! replaces the running one (`docs/protocols.md` §1.9). The controller sends no acknowledgement:
//! completion is observed on RTDE (`runtime_state`, `actual_q`).

use super::error::{Interface, UrError};
use super::{tcp_connect, Transport};
use std::time::Duration;
use tokio::io::AsyncWriteExt;
use tokio::sync::Mutex;

/// Format a `movej` program (joint targets in rad, `a` rad/s², `v` rad/s).
pub fn movej_program(q: &[f64], acc: f64, vel: f64) -> String {
    let qs: Vec<String> = q.iter().map(|x| format!("{x:.9}")).collect();
    format!(
        "def robocal_move():\n  movej([{}], a={acc:.6}, v={vel:.6})\nend\n",
        qs.join(", ")
    )
}

/// Format a `stopj` program (deceleration in rad/s²).
pub fn stopj_program(acc: f64) -> String {
    format!("def robocal_stop():\n  stopj({acc:.6})\nend\n")
}

/// A script-interface connection (write only).
pub struct ScriptClient {
    addr: Option<String>,
    io: Mutex<Option<Box<dyn Transport>>>,
    timeout: Duration,
}

impl std::fmt::Debug for ScriptClient {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ScriptClient")
            .field("addr", &self.addr)
            .finish()
    }
}

impl ScriptClient {
    /// Connect over TCP (`host:30003`). Reconnects once on a broken pipe.
    pub async fn connect(addr: &str, timeout: Duration) -> Result<Self, UrError> {
        let s = tcp_connect(Interface::Script, addr, timeout).await?;
        Ok(Self {
            addr: Some(addr.to_string()),
            io: Mutex::new(Some(Box::new(s))),
            timeout,
        })
    }

    /// Use any byte stream (no reconnect).
    pub fn attach<T: Transport>(io: T, timeout: Duration) -> Self {
        Self {
            addr: None,
            io: Mutex::new(Some(Box::new(io))),
            timeout,
        }
    }

    /// Send a complete program.
    pub async fn send(&self, program: &str) -> Result<(), UrError> {
        if !program.starts_with("def ") && !program.starts_with("sec ") {
            return Err(UrError::InvalidArgument(
                "a URScript program starts with `def` or `sec` in column 1".into(),
            ));
        }
        let mut guard = self.io.lock().await;
        for attempt in 0..2 {
            if guard.is_none() {
                match &self.addr {
                    Some(a) => {
                        *guard = Some(Box::new(
                            tcp_connect(Interface::Script, a, self.timeout).await?,
                        ))
                    }
                    None => {
                        return Err(UrError::Disconnected {
                            interface: Interface::Script,
                            detail: "script connection closed".into(),
                        })
                    }
                }
            }
            let io = guard.as_mut().expect("set above");
            let r = tokio::time::timeout(self.timeout, async {
                io.write_all(program.as_bytes()).await?;
                io.flush().await
            })
            .await;
            match r {
                Ok(Ok(())) => return Ok(()),
                Err(_) => {
                    *guard = None;
                    return Err(UrError::Timeout {
                        interface: Interface::Script,
                        what: "writing a program".into(),
                        secs: self.timeout.as_secs_f64(),
                    });
                }
                Ok(Err(e)) => {
                    *guard = None;
                    if attempt == 1 || self.addr.is_none() {
                        return Err(UrError::io(Interface::Script, e));
                    }
                }
            }
        }
        unreachable!("loop returns")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn movej_text() {
        let p = movej_program(&[0.0, -1.5, 1.0, 0.0, 0.5, 0.25], 1.2, 0.5);
        assert!(p.starts_with("def robocal_move():\n  movej([0.000000000, -1.500000000,"));
        assert!(p.ends_with("a=1.200000, v=0.500000)\nend\n"));
    }
}
