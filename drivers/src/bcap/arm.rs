//! [`DensoArm`]: the capability traits over b-CAP (RC8 "VRC" provider).
//!
//! **Never hand a `DensoArm` to the acquisition engine unwrapped**: wrap it with
//! [`crate::safety::guard`] so every motion is checked before it reaches the controller.
//!
//! Wire sequence: `Service_Start(option)`, `Controller_Connect("", provider, machine, "")`,
//! `Controller_GetRobot(h, "Arm", "")`; before the first move `Robot_Execute(TakeArm, [0, 0])`
//! and `Robot_Execute(Motor, [1, 0])`; moves are `Robot_Move(h, 1, "@E J(j1..j6)",
//! "SPEED=p,ACCEL=p,DECEL=p")` (deg, percent of the configured nominal joint speed /
//! acceleration; the call returns when the motion ended); joints are `Robot_Execute(CurJnt)`
//! (deg). On drop: `Motor [0,0]`, `GiveArm`, `Robot_Release`, `Controller_Disconnect`,
//! `Service_Stop` (spawned on the current tokio runtime; call [`DensoArm::close`] to await it).

use super::client::BcapClient;
use super::error::BcapError;
use super::frame::{hresult::E_ACCESSDENIED, Variant};
use crate::error::{DriverError, DriverResult};
use crate::traits::{
    ArmMode, ArmState, ArmStatus, FlangePose, FlangeToBase, JointReadout, JointState, MoveJoints,
    MoveSpeed, SafetyState,
};
use crate::ur::Backoff;
use async_trait::async_trait;
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::Mutex;

/// Where and how to reach a DENSO controller.
#[derive(Debug, Clone)]
pub struct DensoConfig {
    /// Device name used in errors.
    pub name: String,
    /// `host:port` (port 5007).
    pub addr: String,
    /// Reply deadline of ordinary calls.
    pub timeout: Duration,
    /// `Service_Start` option (`WDT=` asks for `S_EXECUTING` keepalives every N ms).
    pub service_option: String,
    /// CAO provider.
    pub provider: String,
    /// Machine passed to `Controller_Connect`.
    pub machine: String,
    /// Robot name for `Controller_GetRobot`.
    pub robot_name: String,
    /// Number of joints.
    pub dof: usize,
    /// Joint speed that `SPEED=100` means (rad/s).
    pub nominal_max_vel: f64,
    /// Joint acceleration that `ACCEL=100` means (rad/s²).
    pub nominal_max_acc: f64,
    /// Extra time allowed beyond the estimated move duration.
    pub move_margin: Duration,
    /// Reconnect policy.
    pub backoff: Backoff,
    /// How long `TakeArm` waits while another session holds the arm (E_ACCESSDENIED) — after a
    /// dropped link that is usually this host's own dead session, released once the controller
    /// notices the close.
    pub take_arm_wait: Duration,
}

impl DensoConfig {
    /// Defaults for `addr`.
    pub fn new(addr: impl Into<String>) -> Self {
        Self {
            name: "denso".into(),
            addr: addr.into(),
            timeout: Duration::from_secs(3),
            service_option: ",WDT=400,InvokeTimeout=180000".into(),
            provider: "CaoProv.DENSO.VRC".into(),
            machine: "localhost".into(),
            robot_name: "Arm".into(),
            dof: 6,
            nominal_max_vel: super::NOMINAL_MAX_VEL_DEG_S.to_radians(),
            nominal_max_acc: super::NOMINAL_MAX_ACC_DEG_S2.to_radians(),
            move_margin: Duration::from_secs(5),
            backoff: Backoff::default(),
            take_arm_wait: Duration::from_secs(15),
        }
    }
}

struct Session {
    client: Arc<BcapClient>,
    hctrl: i32,
    hrobot: i32,
    armed: bool,
    started: Instant,
    var_position: Option<i32>,
    var_servo: Option<i32>,
    var_error: Option<i32>,
}

/// A DENSO arm over b-CAP.
pub struct DensoArm {
    cfg: DensoConfig,
    reconnect: bool,
    recoveries: AtomicU64,
    session: Mutex<Option<Session>>,
}

impl std::fmt::Debug for DensoArm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DensoArm")
            .field("name", &self.cfg.name)
            .field("addr", &self.cfg.addr)
            .finish()
    }
}

/// `@E J(j1,…)` in degrees.
pub fn joint_pose_string(q_rad: &[f64]) -> String {
    let v: Vec<String> = q_rad
        .iter()
        .map(|x| format!("{:.6}", x.to_degrees()))
        .collect();
    format!("@E J({})", v.join(","))
}

/// DENSO P-type position `[x, y, z, rx, ry, rz, fig]` (mm, deg) → isometry (mm).
/// The posture is the rotation about the base x, then y, then z axes: R = Rz·Ry·Rx.
pub fn position_to_isometry(p: &[f64]) -> Option<Isometry3<f64>> {
    if p.len() < 6 || p[..6].iter().any(|x| !x.is_finite()) {
        return None;
    }
    Some(Isometry3::from_parts(
        Translation3::new(p[0], p[1], p[2]),
        UnitQuaternion::from_euler_angles(p[3].to_radians(), p[4].to_radians(), p[5].to_radians()),
    ))
}

async fn open(cfg: &DensoConfig) -> Result<Session, BcapError> {
    let client = Arc::new(BcapClient::connect(&cfg.addr, cfg.timeout).await?);
    client.service_start(&cfg.service_option).await?;
    let hctrl = client
        .controller_connect("", &cfg.provider, &cfg.machine, "")
        .await?;
    let hrobot = client.controller_get_robot(hctrl, &cfg.robot_name).await?;
    Ok(Session {
        client,
        hctrl,
        hrobot,
        armed: false,
        started: Instant::now(),
        var_position: None,
        var_servo: None,
        var_error: None,
    })
}

async fn shutdown(client: Arc<BcapClient>, hctrl: i32, hrobot: i32, armed: bool) {
    if armed {
        let _ = client
            .robot_execute(hrobot, "Motor", Variant::I4Array(vec![0, 0]))
            .await;
        let _ = client
            .robot_execute(hrobot, "GiveArm", Variant::Empty)
            .await;
    }
    let _ = client.robot_release(hrobot).await;
    let _ = client.controller_disconnect(hctrl).await;
    let _ = client.service_stop().await;
}

impl DensoArm {
    /// Connect and open the controller and robot objects (retried with backoff).
    pub async fn connect(cfg: DensoConfig) -> Result<Self, BcapError> {
        let s = cfg.backoff.retry(|| open(&cfg)).await?;
        Ok(Self {
            cfg,
            reconnect: true,
            recoveries: AtomicU64::new(0),
            session: Mutex::new(Some(s)),
        })
    }

    /// Run the opening sequence over an attached client (no reconnection).
    pub async fn attach(cfg: DensoConfig, client: BcapClient) -> Result<Self, BcapError> {
        let client = Arc::new(client);
        client.service_start(&cfg.service_option).await?;
        let hctrl = client
            .controller_connect("", &cfg.provider, &cfg.machine, "")
            .await?;
        let hrobot = client.controller_get_robot(hctrl, &cfg.robot_name).await?;
        Ok(Self {
            cfg,
            reconnect: false,
            recoveries: AtomicU64::new(0),
            session: Mutex::new(Some(Session {
                client,
                hctrl,
                hrobot,
                armed: false,
                started: Instant::now(),
                var_position: None,
                var_servo: None,
                var_error: None,
            })),
        })
    }

    /// Give the arm back and stop the service, awaiting the replies.
    pub async fn close(&self) {
        if let Some(s) = self.session.lock().await.take() {
            shutdown(s.client, s.hctrl, s.hrobot, s.armed).await;
        }
    }

    fn err(&self, e: BcapError) -> DriverError {
        DriverError::from_device(self.cfg.name.clone(), e)
    }

    /// Run `f` on a healthy session; a broken link is rebuilt with backoff first, and a call
    /// that fails with `Disconnected` / `Timeout` is retried once on a new session (not for
    /// moves: `retry = false`).
    async fn with_session<T, F>(&self, retry: bool, f: F) -> Result<T, BcapError>
    where
        F: for<'a> Fn(
            &'a mut Session,
        ) -> std::pin::Pin<
            Box<dyn std::future::Future<Output = Result<T, BcapError>> + Send + 'a>,
        >,
    {
        use crate::error::DeviceError as _;
        let mut g = self.session.lock().await;
        for attempt in 0..2 {
            let healthy = match g.as_ref() {
                Some(s) => !s.client.is_broken().await,
                None => false,
            };
            if !healthy {
                if !self.reconnect {
                    return Err(BcapError::Disconnected {
                        detail: "b-CAP session closed".into(),
                    });
                }
                *g = None;
                tracing::warn!(
                    "{}: reopening b-CAP session to {}",
                    self.cfg.name,
                    self.cfg.addr
                );
                *g = Some(self.cfg.backoff.retry(|| open(&self.cfg)).await?);
                self.recoveries.fetch_add(1, Ordering::Relaxed);
            }
            let s = g.as_mut().expect("set above");
            match f(s).await {
                Err(e) if retry && attempt == 0 && self.reconnect && e.kind().needs_reconnect() => {
                    *g = None;
                }
                r => return r,
            }
        }
        unreachable!("second attempt returns")
    }

    async fn prepare(s: &mut Session, take_arm_wait: Duration) -> Result<(), BcapError> {
        if !s.armed {
            // After a dropped link the controller still holds the arm for the dead session
            // until it notices the close (or its watchdog fires): `TakeArm` is refused with
            // E_ACCESSDENIED meanwhile. Wait for the release instead of failing the move.
            let deadline = Instant::now() + take_arm_wait;
            let mut pause = Duration::from_millis(50);
            loop {
                match s
                    .client
                    .robot_execute(s.hrobot, "TakeArm", Variant::I4Array(vec![0, 0]))
                    .await
                {
                    Err(BcapError::Hresult { code, .. })
                        if code == E_ACCESSDENIED && Instant::now() + pause < deadline =>
                    {
                        tokio::time::sleep(pause).await;
                        pause = (pause * 2).min(Duration::from_secs(1));
                    }
                    r => {
                        r?;
                        break;
                    }
                }
            }
            s.client
                .robot_execute(s.hrobot, "Motor", Variant::I4Array(vec![1, 0]))
                .await?;
            s.armed = true;
        }
        Ok(())
    }

    async fn cur_jnt(s: &mut Session, dof: usize) -> Result<Vec<f64>, BcapError> {
        let v = s
            .client
            .robot_execute(s.hrobot, "CurJnt", Variant::Empty)
            .await?;
        let deg = v.as_f64_vec().ok_or_else(|| BcapError::Protocol {
            detail: format!("CurJnt returned {v:?}"),
        })?;
        if deg.len() < dof || deg[..dof].iter().any(|x| !x.is_finite()) {
            return Err(BcapError::Protocol {
                detail: format!("CurJnt returned {} values for {dof} joints", deg.len()),
            });
        }
        Ok(deg[..dof].iter().map(|d| d.to_radians()).collect())
    }

    async fn move_inner(&self, target: &[f64], speed: MoveSpeed) -> Result<(), BcapError> {
        let dof = self.cfg.dof;
        if target.len() != dof || target.iter().any(|x| !x.is_finite()) {
            return Err(BcapError::InvalidArgument(format!(
                "expected {dof} finite joint targets, got {target:?}"
            )));
        }
        if !(speed.max_vel > 0.0 && speed.max_acc > 0.0) {
            return Err(BcapError::InvalidArgument(format!("bad speed {speed:?}")));
        }
        let pv = (100.0 * speed.max_vel / self.cfg.nominal_max_vel).clamp(0.1, 100.0);
        let pa = (100.0 * speed.max_acc / self.cfg.nominal_max_acc).clamp(0.1, 100.0);
        let option = format!("SPEED={pv:.2},ACCEL={pa:.2},DECEL={pa:.2}");
        let pose = joint_pose_string(target);
        let margin = self.cfg.move_margin;
        let wait = self.cfg.take_arm_wait;
        let cfg_dof = dof;
        let target = target.to_vec();
        self.with_session(false, move |s| {
            let option = option.clone();
            let pose = pose.clone();
            let target = target.clone();
            Box::pin(async move {
                Self::prepare(s, wait).await?;
                let q0 = Self::cur_jnt(s, cfg_dof).await?;
                let d = q0
                    .iter()
                    .zip(&target)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max);
                let est = crate::ur::arm::trapezoid_duration(
                    d,
                    speed.max_vel.max(1e-6),
                    speed.max_acc.max(1e-6),
                );
                let total = Duration::from_secs_f64(est * 1.5) + margin;
                s.client
                    .robot_move(s.hrobot, 1, Variant::Bstr(pose), &option, total)
                    .await
            })
        })
        .await
    }
}

impl Drop for DensoArm {
    fn drop(&mut self) {
        if let Some(s) = self.session.get_mut().take() {
            if let Ok(rt) = tokio::runtime::Handle::try_current() {
                rt.spawn(shutdown(s.client, s.hctrl, s.hrobot, s.armed));
            }
        }
    }
}

#[async_trait]
impl JointReadout for DensoArm {
    async fn joints(&self) -> DriverResult<JointState> {
        let dof = self.cfg.dof;
        let (q, t) = self
            .with_session(true, move |s| {
                Box::pin(async move {
                    let q = Self::cur_jnt(s, dof).await?;
                    Ok((q, s.started.elapsed().as_secs_f64()))
                })
            })
            .await
            .map_err(|e| self.err(e))?;
        Ok(JointState { q, qd: None, t })
    }
}

#[async_trait]
impl FlangePose for DensoArm {
    async fn flange_pose(&self) -> DriverResult<FlangeToBase> {
        let v = self
            .with_session(true, |s| {
                Box::pin(async move {
                    let h = match s.var_position {
                        Some(h) => h,
                        None => {
                            let h = s
                                .client
                                .robot_get_variable(s.hrobot, "@CURRENT_POSITION")
                                .await?;
                            s.var_position = Some(h);
                            h
                        }
                    };
                    s.client.variable_get_value(h).await
                })
            })
            .await
            .map_err(|e| self.err(e))?;
        let p = v
            .as_f64_vec()
            .and_then(|p| position_to_isometry(&p))
            .ok_or_else(|| {
                self.err(BcapError::Protocol {
                    detail: format!("@CURRENT_POSITION returned {v:?}"),
                })
            })?;
        Ok(FlangeToBase(p))
    }
}

#[async_trait]
impl MoveJoints for DensoArm {
    fn dof(&self) -> usize {
        self.cfg.dof
    }
    async fn move_joints(&self, target: &[f64], speed: MoveSpeed) -> DriverResult<()> {
        self.move_inner(target, speed)
            .await
            .map_err(|e| self.err(e))
    }
    async fn stop(&self) -> DriverResult<()> {
        self.with_session(true, |s| {
            Box::pin(async move { s.client.robot_halt(s.hrobot).await })
        })
        .await
        .map_err(|e| self.err(e))
    }
}

#[async_trait]
impl ArmStatus for DensoArm {
    fn link_recoveries(&self) -> u64 {
        self.recoveries.load(Ordering::Relaxed)
    }
    async fn state(&self) -> DriverResult<ArmState> {
        let (servo, err) = self
            .with_session(true, |s| {
                Box::pin(async move {
                    let hs = match s.var_servo {
                        Some(h) => h,
                        None => {
                            let h = s.client.robot_get_variable(s.hrobot, "@SERVO_ON").await?;
                            s.var_servo = Some(h);
                            h
                        }
                    };
                    let he = match s.var_error {
                        Some(h) => h,
                        None => {
                            let h = s
                                .client
                                .controller_get_variable(s.hctrl, "@ERROR_CODE")
                                .await?;
                            s.var_error = Some(h);
                            h
                        }
                    };
                    let servo = s.client.variable_get_value(hs).await?;
                    let err = s.client.variable_get_value(he).await?;
                    Ok((servo, err))
                })
            })
            .await
            .map_err(|e| self.err(e))?;
        let servo_on = servo.as_bool().unwrap_or(false);
        let code = err.as_i64().unwrap_or(0);
        Ok(ArmState {
            mode: if servo_on {
                ArmMode::Ready
            } else {
                ArmMode::Idle
            },
            safety: if code == 0 {
                SafetyState::Normal
            } else {
                SafetyState::ProtectiveStop
            },
        })
    }
    async fn recover(&self) -> DriverResult<()> {
        let wait = self.cfg.take_arm_wait;
        self.with_session(true, move |s| {
            Box::pin(async move {
                s.client
                    .controller_execute(s.hctrl, "ClearError", Variant::Empty)
                    .await?;
                s.armed = false;
                Self::prepare(s, wait).await
            })
        })
        .await
        .map_err(|e| self.err(e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn pose_strings_and_positions() {
        assert_eq!(
            joint_pose_string(&[0.0, std::f64::consts::FRAC_PI_2, -std::f64::consts::PI]),
            "@E J(0.000000,90.000000,-180.000000)"
        );
        let iso = position_to_isometry(&[100.0, 0.0, 50.0, 0.0, 0.0, 90.0, -1.0]).unwrap();
        assert_relative_eq!(iso.translation.x, 100.0);
        let x = iso.rotation * nalgebra::Vector3::x();
        assert_relative_eq!(x, nalgebra::Vector3::y(), epsilon = 1e-12);
        assert!(position_to_isometry(&[1.0, 2.0]).is_none());
    }
}
