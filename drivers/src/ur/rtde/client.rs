//! RTDE session: protocol-v2 negotiation, controller version, one output recipe, streaming.
//!
//! # Contract (wire sequence of [`RtdeClient::attach`])
//! `V(2)` → `V(1)`; `v` → version; `O(freq, names)` → recipe id + types (any `NOT_FOUND`
//! fails with [`UrError::UnknownVariable`]); `S` → `S(1)`; then a reader task decodes every
//! `U` of the output recipe. Every request waits at most `request_timeout`; every stream read
//! ([`RtdeClient::next_sample`]) at most `stream_timeout`.

use super::codec::ClientCodec;
use super::frame::{variable_type, ControllerVersion, DataType, Reply, Request, Value};
use crate::ur::error::{Interface, UrError};
use crate::ur::{tcp_connect, Transport};
use futures_util::StreamExt as _;
use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::io::WriteHalf;
use tokio::sync::{watch, Mutex};
use tokio_util::codec::{FramedRead, FramedWrite};

/// The output variables the arm driver needs.
pub const ARM_OUTPUTS: [&str; 11] = [
    "timestamp",
    "actual_q",
    "actual_qd",
    "target_q",
    "actual_TCP_pose",
    "tcp_offset",
    "robot_mode",
    "safety_mode",
    "runtime_state",
    "robot_status_bits",
    "safety_status_bits",
];

/// RTDE session settings.
#[derive(Debug, Clone)]
pub struct RtdeConfig {
    /// Output rate (Hz); `0` = the controller's rate (125 Hz CB3, 500 Hz e-Series).
    pub frequency_hz: f64,
    /// Output variables.
    pub outputs: Vec<String>,
    /// Deadline of each request (handshake steps).
    pub request_timeout: Duration,
    /// Longest gap allowed between two streamed samples.
    pub stream_timeout: Duration,
}

impl Default for RtdeConfig {
    fn default() -> Self {
        Self {
            frequency_hz: 125.0,
            outputs: ARM_OUTPUTS.iter().map(|s| s.to_string()).collect(),
            request_timeout: Duration::from_secs(2),
            stream_timeout: Duration::from_secs(1),
        }
    }
}

/// One decoded output package.
#[derive(Debug, Clone)]
pub struct RtdeSample {
    /// Sequence number (1 for the first sample of the session).
    pub seq: u64,
    /// Values in recipe order.
    pub values: Vec<Value>,
    /// When it was received (local clock).
    pub received: Instant,
    index: Arc<HashMap<String, usize>>,
}

impl RtdeSample {
    /// Value of a variable of the recipe.
    pub fn get(&self, name: &str) -> Option<&Value> {
        self.index.get(name).and_then(|&i| self.values.get(i))
    }
    /// A `VECTOR6D` variable.
    pub fn vec6(&self, name: &str) -> Option<[f64; 6]> {
        self.get(name).and_then(Value::as_vector6d)
    }
    /// An integer variable.
    pub fn int(&self, name: &str) -> Option<i64> {
        self.get(name).and_then(Value::as_i64)
    }
    /// A `DOUBLE` variable.
    pub fn double(&self, name: &str) -> Option<f64> {
        self.get(name).and_then(Value::as_f64)
    }
}

#[derive(Debug, Clone, Default)]
struct StreamState {
    seq: u64,
    sample: Option<Arc<RtdeSample>>,
    /// `(is_protocol_error, detail)` once the reader stopped.
    failed: Option<(bool, String)>,
}

type Reader = FramedRead<tokio::io::ReadHalf<Box<dyn Transport>>, ClientCodec>;
type Writer = FramedWrite<WriteHalf<Box<dyn Transport>>, ClientCodec>;

/// A running RTDE session. Dropping it stops the reader task (the socket closes).
pub struct RtdeClient {
    version: ControllerVersion,
    recipe_id: u8,
    types: Vec<DataType>,
    names: Vec<String>,
    rx: watch::Receiver<StreamState>,
    writer: Mutex<Writer>,
    reader: tokio::task::JoinHandle<()>,
    cfg: RtdeConfig,
}

impl std::fmt::Debug for RtdeClient {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RtdeClient")
            .field("version", &self.version)
            .field("recipe_id", &self.recipe_id)
            .field("names", &self.names)
            .finish()
    }
}

impl Drop for RtdeClient {
    fn drop(&mut self) {
        self.reader.abort();
    }
}

async fn recv(
    reader: &mut Reader,
    want: &str,
    timeout: Duration,
    pred: impl Fn(&Reply) -> bool,
) -> Result<Reply, UrError> {
    let fut = async {
        loop {
            match reader.next().await {
                Some(Ok(r)) if pred(&r) => return Ok(r),
                Some(Ok(Reply::Text(t))) => {
                    tracing::debug!(level = t.level, "RTDE text: {}: {}", t.source, t.message)
                }
                Some(Ok(_)) => {} // stray package of another type: skip, as the official client does
                Some(Err(e)) => return Err(codec_err(e)),
                None => {
                    return Err(UrError::Disconnected {
                        interface: Interface::Rtde,
                        detail: format!("closed while waiting for {want}"),
                    })
                }
            }
        }
    };
    tokio::time::timeout(timeout, fut)
        .await
        .map_err(|_| UrError::Timeout {
            interface: Interface::Rtde,
            what: format!("waiting for {want}"),
            secs: timeout.as_secs_f64(),
        })?
}

fn codec_err(e: super::codec::CodecError) -> UrError {
    match e {
        super::codec::CodecError::Io(e) => UrError::io(Interface::Rtde, e),
        e => UrError::Protocol {
            interface: Interface::Rtde,
            detail: e.to_string(),
        },
    }
}

impl RtdeClient {
    /// Connect over TCP (`host:30004`) and run the handshake.
    pub async fn connect(addr: &str, cfg: RtdeConfig) -> Result<Self, UrError> {
        let s = tcp_connect(Interface::Rtde, addr, cfg.request_timeout).await?;
        Self::attach(s, cfg).await
    }

    /// Run the handshake over any byte stream (TCP, `tokio::io::duplex`, …).
    pub async fn attach<T: Transport>(io: T, cfg: RtdeConfig) -> Result<Self, UrError> {
        if cfg.outputs.is_empty() {
            return Err(UrError::InvalidArgument("no RTDE outputs requested".into()));
        }
        let boxed: Box<dyn Transport> = Box::new(io);
        let (r, w) = tokio::io::split(boxed);
        let mut reader = FramedRead::new(r, ClientCodec);
        let mut writer = FramedWrite::new(w, ClientCodec);
        let t = cfg.request_timeout;
        send(
            &mut writer,
            Request::ProtocolVersion(super::frame::PROTOCOL_VERSION),
            t,
        )
        .await?;
        match recv(&mut reader, "V reply", t, |r| {
            matches!(r, Reply::ProtocolVersion(_))
        })
        .await?
        {
            Reply::ProtocolVersion(true) => {}
            _ => {
                return Err(UrError::Rejected {
                    interface: Interface::Rtde,
                    what: "protocol version 2".into(),
                    reply: "0".into(),
                })
            }
        }
        send(&mut writer, Request::GetControllerVersion, t).await?;
        let version = match recv(&mut reader, "v reply", t, |r| {
            matches!(r, Reply::ControllerVersion(_))
        })
        .await?
        {
            Reply::ControllerVersion(v) => v,
            _ => unreachable!("filtered by predicate"),
        };
        let frequency = if cfg.frequency_hz > 0.0 {
            cfg.frequency_hz
        } else if version.major <= 3 {
            125.0
        } else {
            500.0
        };
        send(
            &mut writer,
            Request::SetupOutputs {
                frequency,
                names: cfg.outputs.clone(),
            },
            t,
        )
        .await?;
        let (recipe_id, types) = match recv(&mut reader, "O reply", t, |r| {
            matches!(r, Reply::SetupOutputs { .. })
        })
        .await?
        {
            Reply::SetupOutputs { recipe_id, types } => (recipe_id, types),
            _ => unreachable!("filtered by predicate"),
        };
        if types.len() != cfg.outputs.len() {
            return Err(UrError::Protocol {
                interface: Interface::Rtde,
                detail: format!(
                    "asked for {} outputs, controller typed {}",
                    cfg.outputs.len(),
                    types.len()
                ),
            });
        }
        let mut dtypes = Vec::with_capacity(types.len());
        for (name, ty) in cfg.outputs.iter().zip(&types) {
            match DataType::from_name(ty) {
                Some(d) => {
                    if let Some(expected) = variable_type(name) {
                        if expected != d {
                            return Err(UrError::Protocol {
                                interface: Interface::Rtde,
                                detail: format!(
                                    "`{name}` typed {ty}, expected {}",
                                    expected.name()
                                ),
                            });
                        }
                    }
                    dtypes.push(d)
                }
                None => {
                    return Err(UrError::UnknownVariable {
                        name: name.clone(),
                        answer: ty.clone(),
                    })
                }
            }
        }
        send(&mut writer, Request::Start, t).await?;
        match recv(&mut reader, "S reply", t, |r| matches!(r, Reply::Start(_))).await? {
            Reply::Start(true) => {}
            _ => {
                return Err(UrError::Rejected {
                    interface: Interface::Rtde,
                    what: "start".into(),
                    reply: "0".into(),
                })
            }
        }
        let index: Arc<HashMap<String, usize>> = Arc::new(
            cfg.outputs
                .iter()
                .enumerate()
                .map(|(i, n)| (n.clone(), i))
                .collect(),
        );
        let (tx, rx) = watch::channel(StreamState::default());
        let task_types = dtypes.clone();
        let reader_task = tokio::spawn(async move {
            let mut seq = 0u64;
            loop {
                let failed = match reader.next().await {
                    Some(Ok(Reply::Data {
                        recipe_id: id,
                        payload,
                    })) if id == recipe_id => {
                        match super::codec::decode_fields(&task_types, &payload) {
                            Ok(values) => {
                                seq += 1;
                                let s = Arc::new(RtdeSample {
                                    seq,
                                    values,
                                    received: Instant::now(),
                                    index: index.clone(),
                                });
                                tx.send_modify(|st| {
                                    st.seq = seq;
                                    st.sample = Some(s);
                                });
                                continue;
                            }
                            Err(e) => (true, e.to_string()),
                        }
                    }
                    Some(Ok(Reply::Text(m))) => {
                        tracing::info!(level = m.level, "RTDE text: {}: {}", m.source, m.message);
                        continue;
                    }
                    Some(Ok(_)) => continue,
                    Some(Err(super::codec::CodecError::Io(e))) => (false, e.to_string()),
                    Some(Err(e)) => (true, e.to_string()),
                    None => (false, "controller closed the RTDE connection".to_string()),
                };
                tx.send_modify(|st| st.failed = Some(failed));
                break;
            }
        });
        Ok(Self {
            version,
            recipe_id,
            types: dtypes,
            names: cfg.outputs.clone(),
            rx,
            writer: Mutex::new(writer),
            reader: reader_task,
            cfg,
        })
    }

    /// The controller version reported by `v`.
    pub fn version(&self) -> ControllerVersion {
        self.version
    }

    /// The output variables, in recipe order.
    pub fn outputs(&self) -> &[String] {
        &self.names
    }

    /// The output types, in recipe order.
    pub fn output_types(&self) -> &[DataType] {
        &self.types
    }

    /// Whether the stream has stopped (link broke or bad bytes).
    pub fn is_closed(&self) -> bool {
        self.rx.borrow().failed.is_some()
    }

    fn failure(&self, failed: &(bool, String)) -> UrError {
        if failed.0 {
            UrError::Protocol {
                interface: Interface::Rtde,
                detail: failed.1.clone(),
            }
        } else {
            UrError::Disconnected {
                interface: Interface::Rtde,
                detail: failed.1.clone(),
            }
        }
    }

    /// The next sample received after this call (waits at most `stream_timeout`).
    pub async fn next_sample(&self) -> Result<Arc<RtdeSample>, UrError> {
        let mut rx = self.rx.clone();
        let start = rx.borrow_and_update().seq;
        let wait = async {
            loop {
                {
                    let st = rx.borrow_and_update();
                    if let Some(f) = &st.failed {
                        return Err(self.failure(f));
                    }
                    if st.seq > start {
                        if let Some(s) = &st.sample {
                            return Ok(s.clone());
                        }
                    }
                }
                if rx.changed().await.is_err() {
                    let st = rx.borrow();
                    return Err(st.failed.as_ref().map_or_else(
                        || UrError::Disconnected {
                            interface: Interface::Rtde,
                            detail: "reader stopped".into(),
                        },
                        |f| self.failure(f),
                    ));
                }
            }
        };
        let secs = self.cfg.stream_timeout.as_secs_f64();
        tokio::time::timeout(self.cfg.stream_timeout, wait)
            .await
            .map_err(|_| UrError::Timeout {
                interface: Interface::Rtde,
                what: "waiting for the next data package".into(),
                secs,
            })?
    }

    /// The newest sample if it is younger than `stream_timeout`, else the next one.
    pub async fn latest(&self) -> Result<Arc<RtdeSample>, UrError> {
        {
            let st = self.rx.borrow();
            if let Some(f) = &st.failed {
                return Err(self.failure(f));
            }
            if let Some(s) = &st.sample {
                if s.received.elapsed() < self.cfg.stream_timeout {
                    return Ok(s.clone());
                }
            }
        }
        self.next_sample().await
    }

    /// Send `P` (pause streaming). The reply is consumed by the reader task.
    pub async fn pause(&self) -> Result<(), UrError> {
        let mut w = self.writer.lock().await;
        send(&mut w, Request::Pause, self.cfg.request_timeout).await
    }
}

async fn send(w: &mut Writer, req: Request, timeout: Duration) -> Result<(), UrError> {
    use futures_util::SinkExt as _;
    tokio::time::timeout(timeout, async { w.send(req).await.map_err(codec_err) })
        .await
        .map_err(|_| UrError::Timeout {
            interface: Interface::Rtde,
            what: "sending a request".into(),
            secs: timeout.as_secs_f64(),
        })?
}
