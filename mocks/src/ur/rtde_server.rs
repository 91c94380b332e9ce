//! RTDE server (30004) over the simulated controller.
//!
//! Per connection: answers `V`/`v`/`O`/`I`/`S`/`P`, applies `U` packages of configured input
//! recipes (even when `S` was never sent, as ur_rtde's IO interface needs), and after `S`
//! streams the output recipe at the requested rate (≤ 500 Hz) on the wall clock, with the
//! world's time as `timestamp`. Input recipe ids are 1, 2, 3, … per connection (ur_rtde
//! addresses them by hard-coded ids); the output recipe id is 1.
//!
//! Faults (queue `<device>`), taken before every reply and every data package:
//! `DropLink` closes; `Truncated` sends half a package then closes; `Garbage` sends the bytes
//! instead; `BadCrc` (RTDE has no CRC) sends a package whose size field is corrupt;
//! `ErrorReply` answers a request with "not accepted" (and sends an error `M` in the stream);
//! `Delay`/`Silence` hold the next output for that many wall-clock seconds.

use super::controller::{Controller, Snapshot, REGISTERS};
use crate::world::Fault;
use bytes::BytesMut;
use futures_util::StreamExt as _;
use robocal_drivers::ur::rtde::codec::{decode_fields, encode_fields, encode_reply, ServerCodec};
use robocal_drivers::ur::rtde::frame::{
    register_index, variable_type, DataType, Reply, Request, TextMessage, Value,
};
use std::sync::Arc;
use std::time::Duration;
use tokio::io::AsyncWriteExt;
use tokio::net::{TcpListener, TcpStream};
use tokio_util::codec::FramedRead;

/// Accept RTDE clients forever.
pub async fn serve(listener: TcpListener, ctrl: Arc<Controller>) {
    loop {
        match listener.accept().await {
            Ok((sock, _)) => {
                let _ = sock.set_nodelay(true);
                tokio::spawn(connection(sock, ctrl.clone()));
            }
            Err(e) => {
                tracing::warn!("RTDE accept failed: {e}");
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
        }
    }
}

struct Outputs {
    names: Vec<String>,
    types: Vec<DataType>,
    period: Duration,
}

/// Value of an output variable for one snapshot (zero of its type when not simulated).
pub fn output_value(name: &str, t: DataType, s: &Snapshot) -> Value {
    let v6 = |v: &[f64]| {
        let mut a = [0.0; 6];
        for (d, x) in a.iter_mut().zip(v) {
            *d = *x;
        }
        Value::Vector6d(a)
    };
    let v = match name {
        "timestamp" => Value::Double(s.t),
        "actual_q" | "target_q" => v6(&s.q),
        "actual_qd" | "target_qd" => v6(&s.qd),
        "actual_TCP_pose" | "target_TCP_pose" => {
            let p = s.flange.translation.vector / 1000.0;
            let r = s.flange.rotation.scaled_axis();
            Value::Vector6d([p.x, p.y, p.z, r.x, r.y, r.z])
        }
        "robot_mode" => Value::Int32(s.robot_mode),
        "safety_mode" | "safety_status" => Value::Int32(s.safety_mode),
        "runtime_state" => Value::Uint32(s.runtime),
        "robot_status_bits" => {
            let powered = s.robot_mode >= 4;
            let running = s.runtime == 2;
            Value::Uint32(powered as u32 | ((running as u32) << 1))
        }
        "safety_status_bits" => Value::Uint32(match s.safety_mode {
            1 => 1,
            2 => 1 << 1,
            3 => 1 << 2,
            4 => 1 << 3,
            5 => 1 << 4,
            6 => (1 << 5) | (1 << 7),
            7 => (1 << 6) | (1 << 7),
            8 => 1 << 8,
            9 => 1 << 9,
            _ => 1 << 10,
        }),
        "speed_scaling" | "target_speed_fraction" => Value::Double(1.0),
        "joint_mode" => Value::Vector6Int32([255; 6]),
        "joint_temperatures" => Value::Vector6d([30.0; 6]),
        "actual_main_voltage" | "actual_robot_voltage" => Value::Double(48.0),
        _ => {
            if let Some(i) = register_index(name, "output_int_register_") {
                Value::Int32(if i < REGISTERS { s.out_int[i] } else { 0 })
            } else if let Some(i) = register_index(name, "output_double_register_") {
                Value::Double(if i < REGISTERS { s.out_double[i] } else { 0.0 })
            } else if let Some(i) = register_index(name, "input_int_register_") {
                Value::Int32(if i < REGISTERS { s.in_int[i] } else { 0 })
            } else if let Some(i) = register_index(name, "input_double_register_") {
                Value::Double(if i < REGISTERS { s.in_double[i] } else { 0.0 })
            } else {
                Value::zero(t)
            }
        }
    };
    if v.data_type() == t {
        v
    } else {
        Value::zero(t)
    }
}

enum Outcome {
    Sent,
    Close,
}

/// Write one reply, applying the next queued fault.
async fn write_reply(
    sock: &mut tokio::net::tcp::OwnedWriteHalf,
    ctrl: &Controller,
    reply: Reply,
    in_stream: bool,
) -> std::io::Result<Outcome> {
    let mut buf = BytesMut::new();
    let mut reply = reply;
    if let Some(f) = ctrl.world.take_fault(&ctrl.device) {
        match f {
            Fault::DropLink => return Ok(Outcome::Close),
            Fault::Delay { secs } | Fault::Silence { secs } => {
                tokio::time::sleep(Duration::from_secs_f64(secs.clamp(0.0, 600.0))).await;
            }
            Fault::Garbage { bytes } => {
                sock.write_all(&bytes).await?;
                return Ok(Outcome::Sent);
            }
            Fault::BadCrc => {
                // A size field below the 3-byte header.
                sock.write_all(&[0x00, 0x02, b'U']).await?;
                return Ok(Outcome::Sent);
            }
            Fault::Truncated => {
                let _ = encode_reply(&reply, &mut buf);
                let half = (buf.len() / 2).max(1);
                sock.write_all(&buf[..half]).await?;
                sock.flush().await?;
                return Ok(Outcome::Close);
            }
            Fault::ErrorReply { code } => {
                reply = match reply {
                    Reply::ProtocolVersion(_) => Reply::ProtocolVersion(false),
                    Reply::Start(_) => Reply::Start(false),
                    Reply::Pause(_) => Reply::Pause(false),
                    Reply::SetupOutputs { recipe_id, types } => Reply::SetupOutputs {
                        recipe_id,
                        types: types.iter().map(|_| "NOT_FOUND".to_string()).collect(),
                    },
                    Reply::SetupInputs { recipe_id, types } => Reply::SetupInputs {
                        recipe_id,
                        types: types.iter().map(|_| "IN_USE".to_string()).collect(),
                    },
                    other if in_stream => {
                        let _ = encode_reply(
                            &Reply::Text(TextMessage {
                                message: format!("simulated controller error {code}"),
                                source: "robocal-sim".into(),
                                level: 1,
                            }),
                            &mut buf,
                        );
                        other
                    }
                    other => other,
                };
            }
        }
    }
    if encode_reply(&reply, &mut buf).is_err() {
        return Ok(Outcome::Close);
    }
    sock.write_all(&buf).await?;
    Ok(Outcome::Sent)
}

async fn connection(sock: TcpStream, ctrl: Arc<Controller>) {
    let (r, mut w) = sock.into_split();
    let mut reader = FramedRead::new(r, ServerCodec);
    let mut outputs: Option<Outputs> = None;
    let mut inputs: Vec<(Vec<String>, Vec<DataType>)> = Vec::new();
    let mut streaming = false;
    let mut ticker = tokio::time::interval(Duration::from_millis(2));
    ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    loop {
        let reply = tokio::select! {
            pkt = reader.next() => match pkt {
                None | Some(Err(_)) => return,
                Some(Ok(req)) => match handle(req, &ctrl, &mut outputs, &mut inputs, &mut streaming) {
                    Some(r) => {
                        if streaming {
                            if let Some(o) = &outputs {
                                ticker = tokio::time::interval(o.period);
                                ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
                            }
                        }
                        (r, false)
                    }
                    None => continue,
                },
            },
            _ = ticker.tick(), if streaming && outputs.is_some() => {
                let o = outputs.as_ref().expect("checked");
                let snap = ctrl.snapshot();
                let values: Vec<Value> = o
                    .names
                    .iter()
                    .zip(&o.types)
                    .map(|(n, t)| output_value(n, *t, &snap))
                    .collect();
                let mut payload = Vec::new();
                encode_fields(&values, &mut payload);
                (Reply::Data { recipe_id: 1, payload }, true)
            }
        };
        match write_reply(&mut w, &ctrl, reply.0, reply.1).await {
            Ok(Outcome::Sent) => {}
            Ok(Outcome::Close) | Err(_) => return,
        }
    }
}

fn handle(
    req: Request,
    ctrl: &Controller,
    outputs: &mut Option<Outputs>,
    inputs: &mut Vec<(Vec<String>, Vec<DataType>)>,
    streaming: &mut bool,
) -> Option<Reply> {
    Some(match req {
        Request::ProtocolVersion(v) => Reply::ProtocolVersion(v == 1 || v == 2),
        Request::GetControllerVersion => Reply::ControllerVersion(super::controller::VERSION),
        Request::Text(_) => return None,
        Request::SetupOutputs { frequency, names } => {
            let typed: Vec<Option<DataType>> = names.iter().map(|n| variable_type(n)).collect();
            let types = typed
                .iter()
                .map(|t| t.map_or("NOT_FOUND", DataType::name).to_string())
                .collect();
            let hz = if frequency.is_finite() && frequency > 0.0 {
                frequency.clamp(1.0, 500.0)
            } else {
                125.0
            };
            *outputs = if typed.iter().all(Option::is_some) && !names.is_empty() {
                Some(Outputs {
                    types: typed.into_iter().map(|t| t.expect("checked")).collect(),
                    names,
                    period: Duration::from_secs_f64(1.0 / hz),
                })
            } else {
                None
            };
            Reply::SetupOutputs {
                recipe_id: 1,
                types,
            }
        }
        Request::SetupInputs { names } => {
            let typed: Vec<Option<DataType>> = names.iter().map(|n| variable_type(n)).collect();
            let types = typed
                .iter()
                .map(|t| t.map_or("NOT_FOUND", DataType::name).to_string())
                .collect();
            if typed.iter().all(Option::is_some) && inputs.len() < 255 {
                inputs.push((
                    names,
                    typed.into_iter().map(|t| t.expect("checked")).collect(),
                ));
                Reply::SetupInputs {
                    recipe_id: inputs.len() as u8,
                    types,
                }
            } else {
                Reply::SetupInputs {
                    recipe_id: 0,
                    types,
                }
            }
        }
        Request::Start => {
            *streaming = outputs.is_some();
            Reply::Start(true)
        }
        Request::Pause => {
            *streaming = false;
            Reply::Pause(true)
        }
        Request::Data { recipe_id, payload } => {
            if let Some((names, types)) = inputs.get((recipe_id as usize).wrapping_sub(1)) {
                if let Ok(values) = decode_fields(types, &payload) {
                    for (n, v) in names.iter().zip(&values) {
                        ctrl.set_input(n, v);
                    }
                    ctrl.inputs_changed.notify_waiters();
                }
            }
            return None;
        }
    })
}
