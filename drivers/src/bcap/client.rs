//! b-CAP session over TCP: one request at a time, serials 1..65535 (never 0), replies matched
//! by serial, `S_EXECUTING` keepalives skipped (each one restarts the reply deadline, up to
//! the call's overall limit), negative HRESULTs returned as [`BcapError::Hresult`].
//!
//! # Contract (wire sequence of a call)
//! Request packet `func(args…)` → zero or more `S_EXECUTING` replies with the same serial →
//! one final reply with the same serial. Replies with another serial (late answers to an
//! earlier call that timed out) are discarded.

use super::codec::{BcapCodec, CodecError};
use super::error::BcapError;
use super::frame::{func, hresult, Packet, Variant};
use crate::ur::Transport;
use futures_util::{SinkExt as _, StreamExt as _};
use std::time::{Duration, Instant};
use tokio::sync::Mutex;
use tokio_util::codec::Framed;

/// Default b-CAP TCP port.
pub const PORT: u16 = 5007;

struct Conn {
    framed: Framed<Box<dyn Transport>, BcapCodec>,
    serial: u16,
    broken: bool,
}

/// A b-CAP connection.
pub struct BcapClient {
    conn: Mutex<Conn>,
    /// Deadline for each reply (restarted by every `S_EXECUTING`).
    pub timeout: Duration,
}

impl std::fmt::Debug for BcapClient {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BcapClient")
            .field("timeout", &self.timeout)
            .finish()
    }
}

fn codec_err(e: CodecError) -> BcapError {
    match e {
        CodecError::Io(e) => BcapError::Disconnected {
            detail: e.to_string(),
        },
        e => BcapError::Protocol {
            detail: e.to_string(),
        },
    }
}

fn fname(f: i32) -> String {
    match f {
        func::SERVICE_START => "Service_Start".into(),
        func::SERVICE_STOP => "Service_Stop".into(),
        func::CONTROLLER_CONNECT => "Controller_Connect".into(),
        func::CONTROLLER_DISCONNECT => "Controller_Disconnect".into(),
        func::CONTROLLER_GET_ROBOT => "Controller_GetRobot".into(),
        func::CONTROLLER_GET_VARIABLE => "Controller_GetVariable".into(),
        func::CONTROLLER_EXECUTE => "Controller_Execute".into(),
        func::ROBOT_GET_VARIABLE => "Robot_GetVariable".into(),
        func::ROBOT_EXECUTE => "Robot_Execute".into(),
        func::ROBOT_HALT => "Robot_Halt".into(),
        func::ROBOT_MOVE => "Robot_Move".into(),
        func::ROBOT_RELEASE => "Robot_Release".into(),
        func::VARIABLE_GET_VALUE => "Variable_GetValue".into(),
        func::VARIABLE_PUT_VALUE => "Variable_PutValue".into(),
        func::VARIABLE_RELEASE => "Variable_Release".into(),
        other => format!("function {other}"),
    }
}

impl BcapClient {
    /// Connect over TCP (`host:5007`).
    pub async fn connect(addr: &str, timeout: Duration) -> Result<Self, BcapError> {
        let s = tokio::time::timeout(timeout, tokio::net::TcpStream::connect(addr))
            .await
            .map_err(|_| BcapError::Timeout {
                what: format!("connecting to {addr}"),
                secs: timeout.as_secs_f64(),
            })?
            .map_err(|source| BcapError::Connect {
                addr: addr.to_string(),
                source,
            })?;
        let _ = s.set_nodelay(true);
        Ok(Self::attach(s, timeout))
    }

    /// Use any byte stream.
    pub fn attach<T: Transport>(io: T, timeout: Duration) -> Self {
        let boxed: Box<dyn Transport> = Box::new(io);
        Self {
            conn: Mutex::new(Conn {
                framed: Framed::new(boxed, BcapCodec),
                serial: 0,
                broken: false,
            }),
            timeout,
        }
    }

    /// Whether a previous call broke the link (the session must be rebuilt).
    pub async fn is_broken(&self) -> bool {
        self.conn.lock().await.broken
    }

    /// One call with the client's reply deadline.
    pub async fn call(&self, function: i32, args: Vec<Variant>) -> Result<Vec<Variant>, BcapError> {
        self.call_with(function, args, self.timeout, self.timeout)
            .await
    }

    /// One call: `reply_timeout` between packets (restarted by `S_EXECUTING`), `total` overall.
    pub async fn call_with(
        &self,
        function: i32,
        args: Vec<Variant>,
        reply_timeout: Duration,
        total: Duration,
    ) -> Result<Vec<Variant>, BcapError> {
        let mut c = self.conn.lock().await;
        if c.broken {
            return Err(BcapError::Disconnected {
                detail: "session broken by an earlier failure".into(),
            });
        }
        c.serial = if c.serial == u16::MAX {
            1
        } else {
            c.serial + 1
        };
        let serial = c.serial;
        let name = fname(function);
        let r = Self::exchange(&mut c, serial, function, args, reply_timeout, total, &name).await;
        if let Err(e) = &r {
            if matches!(
                e,
                BcapError::Disconnected { .. } | BcapError::Protocol { .. }
            ) {
                c.broken = true;
            }
        }
        r
    }

    async fn exchange(
        c: &mut Conn,
        serial: u16,
        function: i32,
        args: Vec<Variant>,
        reply_timeout: Duration,
        total: Duration,
        name: &str,
    ) -> Result<Vec<Variant>, BcapError> {
        let t0 = Instant::now();
        tokio::time::timeout(
            reply_timeout,
            c.framed.send(Packet::request(serial, function, args)),
        )
        .await
        .map_err(|_| BcapError::Timeout {
            what: format!("sending {name}"),
            secs: reply_timeout.as_secs_f64(),
        })?
        .map_err(codec_err)?;
        loop {
            let left = total.saturating_sub(t0.elapsed());
            let wait = reply_timeout.min(left);
            let p = match tokio::time::timeout(wait, c.framed.next()).await {
                Err(_) => {
                    return Err(BcapError::Timeout {
                        what: name.to_string(),
                        secs: wait.as_secs_f64(),
                    })
                }
                Ok(None) => {
                    return Err(BcapError::Disconnected {
                        detail: format!("closed while waiting for the reply to {name}"),
                    })
                }
                Ok(Some(r)) => r.map_err(codec_err)?,
            };
            if p.serial != serial {
                tracing::debug!(
                    "b-CAP: discarding reply with serial {} (want {serial})",
                    p.serial
                );
                continue;
            }
            if p.code == hresult::S_EXECUTING {
                continue;
            }
            if p.code < 0 {
                return Err(BcapError::Hresult {
                    function: name.to_string(),
                    code: p.code,
                });
            }
            return Ok(p.args);
        }
    }

    fn one(function: &str, mut v: Vec<Variant>) -> Result<Variant, BcapError> {
        match v.len() {
            0 => Ok(Variant::Empty),
            1 => Ok(v.remove(0)),
            n => Err(BcapError::Protocol {
                detail: format!("{function} returned {n} values"),
            }),
        }
    }

    fn handle(function: &str, v: Vec<Variant>) -> Result<i32, BcapError> {
        let h = Self::one(function, v)?;
        h.as_handle().ok_or_else(|| BcapError::Protocol {
            detail: format!("{function} returned {h:?}, not a handle"),
        })
    }

    /// `Service_Start(option)` (e.g. `",WDT=400,InvokeTimeout=180000"`).
    pub async fn service_start(&self, option: &str) -> Result<(), BcapError> {
        self.call(func::SERVICE_START, vec![Variant::Bstr(option.into())])
            .await
            .map(drop)
    }
    /// `Service_Stop()`.
    pub async fn service_stop(&self) -> Result<(), BcapError> {
        self.call(func::SERVICE_STOP, vec![]).await.map(drop)
    }
    /// `Controller_Connect(name, provider, machine, option)` → controller handle.
    pub async fn controller_connect(
        &self,
        name: &str,
        provider: &str,
        machine: &str,
        option: &str,
    ) -> Result<i32, BcapError> {
        let v = self
            .call(
                func::CONTROLLER_CONNECT,
                vec![
                    Variant::Bstr(name.into()),
                    Variant::Bstr(provider.into()),
                    Variant::Bstr(machine.into()),
                    Variant::Bstr(option.into()),
                ],
            )
            .await?;
        Self::handle("Controller_Connect", v)
    }
    /// `Controller_Disconnect(h)`.
    pub async fn controller_disconnect(&self, h: i32) -> Result<(), BcapError> {
        self.call(func::CONTROLLER_DISCONNECT, vec![Variant::I4(h)])
            .await
            .map(drop)
    }
    /// The `*_GetRobot` / `*_GetVariable` shape: `(h, name, "")` → a new handle.
    async fn get_handle(
        &self,
        id: i32,
        what: &'static str,
        h: i32,
        name: &str,
    ) -> Result<i32, BcapError> {
        let v = self
            .call(
                id,
                vec![
                    Variant::I4(h),
                    Variant::Bstr(name.into()),
                    Variant::Bstr(String::new()),
                ],
            )
            .await?;
        Self::handle(what, v)
    }
    /// `Controller_GetRobot(h, name, option)` → robot handle.
    pub async fn controller_get_robot(&self, h: i32, name: &str) -> Result<i32, BcapError> {
        self.get_handle(func::CONTROLLER_GET_ROBOT, "Controller_GetRobot", h, name)
            .await
    }
    /// `Controller_GetVariable(h, name, option)` → variable handle.
    pub async fn controller_get_variable(&self, h: i32, name: &str) -> Result<i32, BcapError> {
        self.get_handle(
            func::CONTROLLER_GET_VARIABLE,
            "Controller_GetVariable",
            h,
            name,
        )
        .await
    }
    /// `Controller_Execute(h, command, param)`.
    pub async fn controller_execute(
        &self,
        h: i32,
        command: &str,
        param: Variant,
    ) -> Result<Variant, BcapError> {
        let v = self
            .call(
                func::CONTROLLER_EXECUTE,
                vec![Variant::I4(h), Variant::Bstr(command.into()), param],
            )
            .await?;
        Self::one("Controller_Execute", v)
    }
    /// `Robot_GetVariable(h, name, option)` → variable handle.
    pub async fn robot_get_variable(&self, h: i32, name: &str) -> Result<i32, BcapError> {
        self.get_handle(func::ROBOT_GET_VARIABLE, "Robot_GetVariable", h, name)
            .await
    }
    /// `Robot_Execute(h, command, param)`.
    pub async fn robot_execute(
        &self,
        h: i32,
        command: &str,
        param: Variant,
    ) -> Result<Variant, BcapError> {
        let v = self
            .call(
                func::ROBOT_EXECUTE,
                vec![Variant::I4(h), Variant::Bstr(command.into()), param],
            )
            .await
            .map_err(|e| match e {
                BcapError::Hresult { code, .. } => BcapError::Hresult {
                    function: format!("Robot_Execute({command})"),
                    code,
                },
                e => e,
            })?;
        Self::one("Robot_Execute", v)
    }
    /// `Robot_Move(h, comp, pose, option)`; synchronous: returns when the motion ended.
    /// `total` bounds the whole call (keepalives restart the per-reply deadline).
    pub async fn robot_move(
        &self,
        h: i32,
        comp: i32,
        pose: Variant,
        option: &str,
        total: Duration,
    ) -> Result<(), BcapError> {
        // Without WDT keepalives the only reply comes at the end: allow the whole duration.
        self.call_with(
            func::ROBOT_MOVE,
            vec![
                Variant::I4(h),
                Variant::I4(comp),
                pose,
                Variant::Bstr(option.into()),
            ],
            total,
            total,
        )
        .await
        .map(drop)
    }
    /// `Robot_Halt(h, option)`.
    pub async fn robot_halt(&self, h: i32) -> Result<(), BcapError> {
        self.call(
            func::ROBOT_HALT,
            vec![Variant::I4(h), Variant::Bstr(String::new())],
        )
        .await
        .map(drop)
    }
    /// `Robot_Release(h)`.
    pub async fn robot_release(&self, h: i32) -> Result<(), BcapError> {
        self.call(func::ROBOT_RELEASE, vec![Variant::I4(h)])
            .await
            .map(drop)
    }
    /// `Variable_GetValue(h)`.
    pub async fn variable_get_value(&self, h: i32) -> Result<Variant, BcapError> {
        let v = self
            .call(func::VARIABLE_GET_VALUE, vec![Variant::I4(h)])
            .await?;
        Self::one("Variable_GetValue", v)
    }
    /// `Variable_PutValue(h, value)`.
    pub async fn variable_put_value(&self, h: i32, value: Variant) -> Result<(), BcapError> {
        self.call(func::VARIABLE_PUT_VALUE, vec![Variant::I4(h), value])
            .await
            .map(drop)
    }
    /// `Variable_Release(h)`.
    pub async fn variable_release(&self, h: i32) -> Result<(), BcapError> {
        self.call(func::VARIABLE_RELEASE, vec![Variant::I4(h)])
            .await
            .map(drop)
    }
}
