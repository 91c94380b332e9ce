//! The b-CAP connection handler and the simulated RC8 object model.

use crate::world::{Fault, SafetyState, WorldError, WorldHandle};
use bytes::BytesMut;
use futures_util::{SinkExt as _, StreamExt as _};
use robocal_drivers::bcap::codec::{encode_packet, BcapCodec};
use robocal_drivers::bcap::frame::{func, hresult, Packet, Variant};
use robocal_drivers::bcap::{NOMINAL_MAX_ACC_DEG_S2, NOMINAL_MAX_VEL_DEG_S};
use robocal_drivers::MoveSpeed;
use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::io::AsyncWriteExt;
use tokio::net::{TcpListener, TcpStream};
use tokio_util::codec::{FramedRead, FramedWrite};

/// The controller shared by every connection.
pub struct BcapController {
    world: WorldHandle,
    arm: usize,
    device: String,
    st: Mutex<Shared>,
    conn_ids: AtomicU64,
}

#[derive(Debug, Default)]
struct Shared {
    taken_by: Option<u64>,
    motor_on: bool,
}

#[derive(Debug, Clone, PartialEq)]
enum Obj {
    Controller,
    Robot,
    Variable { robot: bool, name: String },
}

struct Session {
    id: u64,
    wdt: Option<Duration>,
    objs: HashMap<i32, Obj>,
    next: i32,
}

type Res = Result<Vec<Variant>, i32>;

impl BcapController {
    /// A controller for arm `arm` (motor off, arm free).
    pub fn new(world: WorldHandle, arm: usize, device: &str) -> Arc<Self> {
        Arc::new(Self {
            world,
            arm,
            device: device.to_string(),
            st: Mutex::new(Shared::default()),
            conn_ids: AtomicU64::new(1),
        })
    }

    fn with<R>(&self, f: impl FnOnce(&mut Shared) -> R) -> R {
        f(&mut self.st.lock().unwrap_or_else(|e| e.into_inner()))
    }

    fn pstop(&self) -> bool {
        self.world.arm_state(self.arm).safety != SafetyState::Normal
    }

    fn joints_deg(&self) -> Vec<f64> {
        self.world
            .arm_joint_state(self.arm)
            .q
            .iter()
            .map(|x| x.to_degrees())
            .collect()
    }

    fn position(&self) -> Vec<f64> {
        let f = self.world.arm_controller_flange(self.arm);
        let (r, p, y) = f.rotation.euler_angles();
        let t = f.translation.vector;
        vec![
            t.x,
            t.y,
            t.z,
            r.to_degrees(),
            p.to_degrees(),
            y.to_degrees(),
            -1.0,
        ]
    }
}

/// Accept b-CAP clients forever.
pub async fn serve(listener: TcpListener, ctrl: Arc<BcapController>) {
    loop {
        match listener.accept().await {
            Ok((sock, _)) => {
                let _ = sock.set_nodelay(true);
                tokio::spawn(connection(sock, ctrl.clone()));
            }
            Err(_) => tokio::time::sleep(Duration::from_millis(50)).await,
        }
    }
}

type Writer = FramedWrite<tokio::net::tcp::OwnedWriteHalf, BcapCodec>;

/// Send a final reply, applying the next queued fault. `false` = close the connection.
async fn send_reply(w: &mut Writer, ctrl: &BcapController, serial: u16, res: Res) -> bool {
    let mut pkt = match res {
        Ok(args) => Packet::reply(serial, hresult::S_OK, args),
        Err(code) => Packet::reply(serial, code, vec![]),
    };
    if let Some(f) = ctrl.world.take_fault(&ctrl.device) {
        let mut raw = BytesMut::new();
        match f {
            Fault::DropLink => return false,
            Fault::Delay { secs } | Fault::Silence { secs } => {
                tokio::time::sleep(Duration::from_secs_f64(secs.clamp(0.0, 600.0))).await
            }
            Fault::Garbage { bytes } => {
                return w.get_mut().write_all(&bytes).await.is_ok();
            }
            Fault::BadCrc => {
                let _ = encode_packet(&pkt, &mut raw);
                if let Some(last) = raw.last_mut() {
                    *last = 0x00;
                }
                return w.get_mut().write_all(&raw).await.is_ok();
            }
            Fault::Truncated => {
                let _ = encode_packet(&pkt, &mut raw);
                let _ = w.get_mut().write_all(&raw[..raw.len() / 2]).await;
                return false;
            }
            Fault::ErrorReply { code } => {
                pkt = Packet::reply(serial, code as i32, vec![]);
            }
        }
    }
    w.send(pkt).await.is_ok()
}

async fn connection(sock: TcpStream, ctrl: Arc<BcapController>) {
    let (r, w) = sock.into_split();
    let mut reader = FramedRead::new(r, BcapCodec);
    let mut writer = FramedWrite::new(w, BcapCodec);
    let mut s = Session {
        id: ctrl.conn_ids.fetch_add(1, Ordering::Relaxed),
        wdt: None,
        objs: HashMap::new(),
        next: 1,
    };
    while let Some(item) = reader.next().await {
        let Ok(req) = item else { break };
        let serial = req.serial;
        let res = if req.code == func::ROBOT_MOVE {
            match start_move(&ctrl, &s, &req.args) {
                Err(code) => Err(code),
                Ok(false) => Ok(vec![]),
                Ok(true) => match wait_move(&ctrl, &s, serial, &mut reader, &mut writer).await {
                    Some(r) => r,
                    None => break,
                },
            }
        } else {
            dispatch(&ctrl, &mut s, req.code, &req.args)
        };
        if !send_reply(&mut writer, &ctrl, serial, res).await {
            break;
        }
        if req.code == func::SERVICE_STOP {
            break;
        }
    }
    // A vanished client gives the arm back.
    ctrl.with(|c| {
        if c.taken_by == Some(s.id) {
            c.taken_by = None;
        }
    });
}

/// Wait for the motion, sending `S_EXECUTING` every WDT and `E_BUSY_PROC` to interlopers.
/// `None` = the link broke.
async fn wait_move(
    ctrl: &BcapController,
    s: &Session,
    serial: u16,
    reader: &mut FramedRead<tokio::net::tcp::OwnedReadHalf, BcapCodec>,
    writer: &mut Writer,
) -> Option<Res> {
    let world = ctrl.world.clone();
    let arm = ctrl.arm;
    let done = async move {
        if world.is_virtual() {
            world.arm_wait_arrival(arm).await;
        } else {
            while world.arm_is_moving(arm) {
                tokio::time::sleep(Duration::from_millis(4)).await;
            }
        }
    };
    tokio::pin!(done);
    let wdt = s.wdt;
    loop {
        tokio::select! {
            _ = &mut done => break,
            _ = tokio::time::sleep(wdt.unwrap_or(Duration::from_secs(3600))), if wdt.is_some() => {
                if writer.send(Packet::reply(serial, hresult::S_EXECUTING, vec![])).await.is_err() {
                    ctrl.world.arm_stop(ctrl.arm);
                    return None;
                }
            }
            next = reader.next() => match next {
                Some(Ok(p)) => {
                    if writer.send(Packet::reply(p.serial, hresult::E_BUSY_PROC, vec![])).await.is_err() {
                        ctrl.world.arm_stop(ctrl.arm);
                        return None;
                    }
                }
                _ => {
                    ctrl.world.arm_stop(ctrl.arm);
                    return None;
                }
            }
        }
    }
    if ctrl.pstop() {
        return Some(Err(hresult::E_SIM_PROTECTIVE_STOP));
    }
    Some(Ok(vec![]))
}

fn arg(args: &[Variant], i: usize) -> Result<&Variant, i32> {
    args.get(i).ok_or(hresult::E_INVALIDARG)
}

fn handle_of(s: &Session, args: &[Variant], want: fn(&Obj) -> bool) -> Result<i32, i32> {
    let h = arg(args, 0)?.as_handle().ok_or(hresult::E_HANDLE)?;
    match s.objs.get(&h) {
        Some(o) if want(o) => Ok(h),
        _ => Err(hresult::E_HANDLE),
    }
}

fn new_obj(s: &mut Session, o: Obj) -> Result<Vec<Variant>, i32> {
    if s.objs.len() >= 1000 {
        return Err(0x8000_0905_u32 as i32); // E_MAX_OBJECT
    }
    let h = s.next;
    s.next += 1;
    s.objs.insert(h, o);
    Ok(vec![Variant::I4(h)])
}

fn parse_option(opt: &str, key: &str) -> Option<f64> {
    opt.split(',').find_map(|kv| {
        let (k, v) = kv.split_once('=')?;
        if k.trim().eq_ignore_ascii_case(key) {
            v.trim().trim_start_matches(['F', 'f']).parse().ok()
        } else {
            None
        }
    })
}

/// Parse a joint pose: BSTR `[@E|@P|@0] J(j1, …)` (deg) or `[R8 array, "J", "@E"]`.
pub fn parse_joint_pose(v: &Variant) -> Result<Vec<f64>, i32> {
    let deg: Vec<f64> = match v {
        Variant::Bstr(s) => {
            let mut t = s.trim();
            for p in ["@E", "@P", "@0"] {
                if let Some(r) = t.strip_prefix(p) {
                    t = r.trim_start();
                }
            }
            let body = t
                .strip_prefix('J')
                .or_else(|| t.strip_prefix('j'))
                .map(str::trim_start)
                .and_then(|b| b.strip_prefix('('))
                .and_then(|b| b.trim_end().strip_suffix(')'))
                .ok_or(if t.starts_with('P') || t.starts_with('T') {
                    hresult::E_NOTIMPL
                } else {
                    hresult::E_INVALIDARG
                })?;
            body.split(',')
                .map(|x| x.trim().parse::<f64>())
                .collect::<Result<_, _>>()
                .map_err(|_| hresult::E_INVALIDARG)?
        }
        Variant::VariantArray(a) if a.len() >= 2 => {
            match a[1].as_str() {
                Some("J") | Some("j") => {}
                Some(_) => return Err(hresult::E_NOTIMPL),
                None => return Err(hresult::E_INVALIDARG),
            }
            a[0].as_f64_vec().ok_or(hresult::E_INVALIDARG)?
        }
        _ => return Err(hresult::E_INVALIDARG),
    };
    if deg.iter().any(|x| !x.is_finite()) {
        return Err(hresult::E_INVALIDARG);
    }
    Ok(deg)
}

/// Validate and start a move. `Ok(true)` = wait for it; `Ok(false)` = `NEXT` (asynchronous).
fn start_move(ctrl: &BcapController, s: &Session, args: &[Variant]) -> Result<bool, i32> {
    handle_of(s, args, |o| *o == Obj::Robot)?;
    let comp = arg(args, 1)?.as_i64().ok_or(hresult::E_INVALIDARG)?;
    if comp != 1 {
        return Err(hresult::E_NOTIMPL);
    }
    let deg = parse_joint_pose(arg(args, 2)?)?;
    let opt = args.get(3).and_then(Variant::as_str).unwrap_or("");
    let (taken, motor) = ctrl.with(|c| (c.taken_by == Some(s.id), c.motor_on));
    if !taken {
        return Err(hresult::E_ACCESSDENIED);
    }
    if ctrl.pstop() {
        return Err(hresult::E_SIM_PROTECTIVE_STOP);
    }
    if !motor {
        return Err(hresult::E_SIM_MOTOR_OFF);
    }
    let dof = ctrl.world.arm_dof(ctrl.arm);
    if deg.len() < dof {
        return Err(hresult::E_INVALIDARG);
    }
    let q: Vec<f64> = deg[..dof].iter().map(|d| d.to_radians()).collect();
    let pct = |k: &str| parse_option(opt, k).unwrap_or(100.0).clamp(0.1, 100.0) / 100.0;
    let speed = MoveSpeed {
        max_vel: pct("SPEED") * NOMINAL_MAX_VEL_DEG_S.to_radians(),
        max_acc: pct("ACCEL") * NOMINAL_MAX_ACC_DEG_S2.to_radians(),
    };
    match ctrl.world.arm_start_move(ctrl.arm, &q, speed) {
        Ok(_) => {}
        Err(WorldError::OutOfLimits { .. }) => return Err(hresult::E_SIM_OUT_OF_RANGE),
        Err(WorldError::ProtectiveStop) => return Err(hresult::E_SIM_PROTECTIVE_STOP),
        Err(_) => return Err(hresult::E_INVALIDARG),
    }
    let next = opt
        .split(',')
        .any(|t| t.trim().eq_ignore_ascii_case("NEXT"));
    Ok(!next)
}

fn dispatch(ctrl: &BcapController, s: &mut Session, f: i32, args: &[Variant]) -> Res {
    let is_ctrl = |o: &Obj| *o == Obj::Controller;
    let is_robot = |o: &Obj| *o == Obj::Robot;
    let is_var = |o: &Obj| matches!(o, Obj::Variable { .. });
    match f {
        func::SERVICE_START => {
            let opt = args.first().and_then(Variant::as_str).unwrap_or("");
            s.wdt = parse_option(opt, "WDT")
                .filter(|ms| *ms > 0.0)
                .map(|ms| Duration::from_secs_f64(ms.max(80.0) / 1000.0));
            Ok(vec![])
        }
        func::SERVICE_STOP => Ok(vec![]),
        func::CONTROLLER_CONNECT => {
            for i in 0..4 {
                if arg(args, i)?.as_str().is_none() {
                    return Err(hresult::E_INVALIDARG);
                }
            }
            new_obj(s, Obj::Controller)
        }
        func::CONTROLLER_DISCONNECT => {
            let h = handle_of(s, args, is_ctrl)?;
            s.objs.remove(&h);
            Ok(vec![])
        }
        func::CONTROLLER_GET_ROBOT => {
            handle_of(s, args, is_ctrl)?;
            let name = arg(args, 1)?.as_str().ok_or(hresult::E_INVALIDARG)?;
            if !(name.is_empty()
                || name.eq_ignore_ascii_case("Arm")
                || name.eq_ignore_ascii_case("Robot0"))
            {
                return Err(hresult::E_CAO_OBJECT_NOTFOUND);
            }
            new_obj(s, Obj::Robot)
        }
        func::CONTROLLER_GET_ROBOT_NAMES => {
            handle_of(s, args, is_ctrl)?;
            Ok(vec![Variant::BstrArray(vec!["Arm".into()])])
        }
        func::CONTROLLER_GET_VARIABLE | func::ROBOT_GET_VARIABLE => {
            let robot = f == func::ROBOT_GET_VARIABLE;
            handle_of(s, args, if robot { is_robot } else { is_ctrl })?;
            let name = arg(args, 1)?
                .as_str()
                .ok_or(hresult::E_INVALIDARG)?
                .to_string();
            let known: &[&str] = if robot {
                &["@CURRENT_ANGLE", "@CURRENT_POSITION", "@SERVO_ON"]
            } else {
                &["@ERROR_CODE", "@MODE", "@EMERGENCY_STOP", "@VERSION"]
            };
            if !known.iter().any(|k| k.eq_ignore_ascii_case(&name)) {
                return Err(hresult::E_CAO_OBJECT_NOTFOUND);
            }
            new_obj(
                s,
                Obj::Variable {
                    robot,
                    name: name.to_ascii_uppercase(),
                },
            )
        }
        func::CONTROLLER_EXECUTE => {
            handle_of(s, args, is_ctrl)?;
            let cmd = arg(args, 1)?.as_str().ok_or(hresult::E_INVALIDARG)?;
            let pstop = ctrl.pstop();
            match cmd.to_ascii_lowercase().as_str() {
                "clearerror" | "manualreset" => {
                    ctrl.world
                        .arm_recover(ctrl.arm)
                        .map_err(|_| hresult::E_FAIL)?;
                    Ok(vec![])
                }
                "getcurerrorcount" => Ok(vec![Variant::I4(pstop as i32)]),
                "getcurerrorinfo" => Ok(vec![Variant::VariantArray(if pstop {
                    vec![
                        Variant::I4(hresult::E_SIM_PROTECTIVE_STOP),
                        Variant::Bstr(hresult::name(hresult::E_SIM_PROTECTIVE_STOP).into()),
                    ]
                } else {
                    vec![Variant::I4(0), Variant::Bstr(String::new())]
                })]),
                "geterrordescription" => {
                    let code = args
                        .get(2)
                        .and_then(Variant::as_i64)
                        .ok_or(hresult::E_INVALIDARG)?;
                    Ok(vec![Variant::Bstr(hresult::name(code as i32).into())])
                }
                _ => Err(hresult::E_INVALID_CMD_NAME),
            }
        }
        func::ROBOT_EXECUTE => {
            handle_of(s, args, is_robot)?;
            let cmd = arg(args, 1)?.as_str().ok_or(hresult::E_INVALIDARG)?;
            let param = args.get(2).cloned().unwrap_or(Variant::Empty);
            robot_execute(ctrl, s, cmd, &param)
        }
        func::ROBOT_HALT => {
            handle_of(s, args, is_robot)?;
            ctrl.world.arm_stop(ctrl.arm);
            Ok(vec![])
        }
        func::ROBOT_RELEASE | func::VARIABLE_RELEASE => {
            let h = handle_of(
                s,
                args,
                if f == func::ROBOT_RELEASE {
                    is_robot
                } else {
                    is_var
                },
            )?;
            s.objs.remove(&h);
            Ok(vec![])
        }
        func::VARIABLE_GET_VALUE => {
            let h = handle_of(s, args, is_var)?;
            let Some(Obj::Variable { name, .. }) = s.objs.get(&h) else {
                return Err(hresult::E_HANDLE);
            };
            Ok(vec![match name.as_str() {
                "@CURRENT_ANGLE" => Variant::R8Array(ctrl.joints_deg()),
                "@CURRENT_POSITION" => Variant::R8Array(ctrl.position()),
                "@SERVO_ON" => Variant::Bool(ctrl.with(|c| c.motor_on)),
                "@ERROR_CODE" => Variant::I4(if ctrl.pstop() {
                    hresult::E_SIM_PROTECTIVE_STOP
                } else {
                    0
                }),
                "@MODE" => Variant::I4(3),
                "@EMERGENCY_STOP" => Variant::Bool(false),
                _ => Variant::Bstr("2.16.0 (robocal simulator)".into()),
            }])
        }
        func::VARIABLE_PUT_VALUE => {
            let h = handle_of(s, args, is_var)?;
            let v = arg(args, 1)?.clone();
            let Some(Obj::Variable { name, .. }) = s.objs.get(&h) else {
                return Err(hresult::E_HANDLE);
            };
            if name == "@SERVO_ON" {
                let on = v.as_bool().ok_or(hresult::E_INVALIDARG)?;
                if ctrl.with(|c| c.taken_by != Some(s.id)) {
                    return Err(hresult::E_ACCESSDENIED);
                }
                ctrl.with(|c| c.motor_on = on);
                Ok(vec![])
            } else {
                Err(0x8000_020A_u32 as i32) // E_CAO_NOT_WRITABLE
            }
        }
        _ => Err(hresult::E_NOTIMPL),
    }
}

fn robot_execute(ctrl: &BcapController, s: &Session, cmd: &str, param: &Variant) -> Res {
    let first = param
        .as_i64_vec()
        .and_then(|v| v.first().copied())
        .or_else(|| param.as_i64());
    match cmd.to_ascii_lowercase().as_str() {
        "takearm" => ctrl.with(|c| match c.taken_by {
            Some(o) if o != s.id => Err(hresult::E_ACCESSDENIED),
            _ => {
                c.taken_by = Some(s.id);
                Ok(vec![])
            }
        }),
        "givearm" => ctrl.with(|c| {
            if c.taken_by == Some(s.id) {
                c.taken_by = None;
            }
            Ok(vec![])
        }),
        "motor" => {
            let on = first.ok_or(hresult::E_INVALIDARG)? != 0;
            ctrl.with(|c| {
                if c.taken_by != Some(s.id) {
                    return Err(hresult::E_ACCESSDENIED);
                }
                c.motor_on = on;
                Ok(vec![])
            })
        }
        "extspeed" => Ok(vec![]),
        "curjnt" => Ok(vec![Variant::R8Array(ctrl.joints_deg())]),
        "highcurjntex" => {
            let mut v = vec![ctrl.world.now() * 1000.0];
            v.extend(ctrl.joints_deg());
            Ok(vec![Variant::R8Array(v)])
        }
        "curpos" => Ok(vec![Variant::R8Array(ctrl.position())]),
        _ => Err(hresult::E_INVALID_CMD_NAME),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_forms() {
        assert_eq!(
            parse_joint_pose(&Variant::Bstr("@E J(10, -20.5, 30,0,0,0)".into())).unwrap(),
            vec![10.0, -20.5, 30.0, 0.0, 0.0, 0.0]
        );
        assert_eq!(
            parse_joint_pose(&Variant::Bstr("J(1,2)".into())).unwrap(),
            vec![1.0, 2.0]
        );
        assert_eq!(
            parse_joint_pose(&Variant::VariantArray(vec![
                Variant::R8Array(vec![1.0, 2.0]),
                Variant::Bstr("J".into()),
                Variant::Bstr("@E".into())
            ]))
            .unwrap(),
            vec![1.0, 2.0]
        );
        assert_eq!(
            parse_joint_pose(&Variant::Bstr("@P P(1,2,3,0,0,0,-1)".into())),
            Err(hresult::E_NOTIMPL)
        );
        assert_eq!(
            parse_joint_pose(&Variant::Bstr("J(1,x)".into())),
            Err(hresult::E_INVALIDARG)
        );
        assert_eq!(
            parse_option(",WDT=400,InvokeTimeout=180000", "WDT"),
            Some(400.0)
        );
        assert_eq!(parse_option("SPEED=F2,NEXT", "SPEED"), Some(2.0));
    }
}
