//! [`UrArm`]: the capability traits over RTDE + dashboard + script interface.
//!
//! **Never hand a `UrArm` to the acquisition engine unwrapped**: every motion must pass
//! through [`crate::safety::guard`], which checks joint limits, speeds and the Cartesian
//! envelope before anything reaches the controller.

use super::dashboard::DashboardClient;
use super::error::{Interface, UrError};
use super::rtde::frame::{runtime_state, RobotMode, SafetyMode};
use super::rtde::{RtdeClient, RtdeConfig, RtdeSample};
use super::script::{movej_program, stopj_program, ScriptClient};
use super::{ports, Backoff};
use crate::error::{DeviceError, DriverError, DriverResult, ErrorKind};
use crate::traits::{
    ArmMode, ArmState, ArmStatus, FlangePose, FlangeToBase, JointReadout, JointState, MoveJoints,
    MoveSpeed, SafetyState,
};
use async_trait::async_trait;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::Mutex;

/// Where and how to reach a UR controller.
#[derive(Debug, Clone)]
pub struct UrConfig {
    /// Device name used in errors (e.g. `ur5e`).
    pub name: String,
    /// Controller host (IP or name).
    pub host: String,
    /// RTDE port (30004).
    pub rtde_port: u16,
    /// Dashboard port (29999).
    pub dashboard_port: u16,
    /// Script port (30003).
    pub script_port: u16,
    /// RTDE session settings.
    pub rtde: RtdeConfig,
    /// Deadline of dashboard / script requests.
    pub request_timeout: Duration,
    /// A move is complete when every joint is within this of the target (rad).
    pub joint_tolerance_rad: f64,
    /// How long the program may take to start before the move counts as refused.
    pub start_timeout: Duration,
    /// Extra time allowed beyond the estimated move duration.
    pub move_margin: Duration,
    /// Reconnect policy.
    pub backoff: Backoff,
}

impl UrConfig {
    /// Defaults for `host` on the standard ports.
    pub fn new(host: impl Into<String>) -> Self {
        Self {
            name: "ur".into(),
            host: host.into(),
            rtde_port: ports::RTDE,
            dashboard_port: ports::DASHBOARD,
            script_port: ports::SCRIPT,
            rtde: RtdeConfig::default(),
            request_timeout: Duration::from_secs(2),
            joint_tolerance_rad: 1e-3,
            start_timeout: Duration::from_secs(2),
            move_margin: Duration::from_secs(5),
            backoff: Backoff::default(),
        }
    }
    fn addr(&self, port: u16) -> String {
        if self.host.contains(':') && !self.host.starts_with('[') {
            format!("[{}]:{port}", self.host)
        } else {
            format!("{}:{port}", self.host)
        }
    }
}

/// A UR arm. Reconnects RTDE / dashboard with backoff when built by [`UrArm::connect`].
pub struct UrArm {
    cfg: UrConfig,
    reconnect: bool,
    recoveries: AtomicU64,
    rtde: Mutex<Option<Arc<RtdeClient>>>,
    dashboard: Mutex<Option<Arc<DashboardClient>>>,
    script: ScriptClient,
}

impl std::fmt::Debug for UrArm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("UrArm")
            .field("name", &self.cfg.name)
            .field("host", &self.cfg.host)
            .finish()
    }
}

/// Duration (s) of a synchronised trapezoidal joint move of largest displacement `d`.
pub fn trapezoid_duration(d: f64, vel: f64, acc: f64) -> f64 {
    if d <= 0.0 || vel <= 0.0 || acc <= 0.0 {
        return 0.0;
    }
    if d < vel * vel / acc {
        2.0 * (d / acc).sqrt()
    } else {
        d / vel + vel / acc
    }
}

/// Rotation vector (axis·angle, rad) and translation (m) → isometry in mm.
pub fn ur_pose_to_isometry_mm(p: &[f64; 6]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(p[0] * 1000.0, p[1] * 1000.0, p[2] * 1000.0),
        UnitQuaternion::from_scaled_axis(Vector3::new(p[3], p[4], p[5])),
    )
}

impl UrArm {
    /// Connect RTDE, dashboard and script interface of `cfg.host`.
    pub async fn connect(cfg: UrConfig) -> Result<Self, UrError> {
        let (ra, da) = (cfg.addr(cfg.rtde_port), cfg.addr(cfg.dashboard_port));
        let rtde = cfg
            .backoff
            .retry(|| RtdeClient::connect(&ra, cfg.rtde.clone()))
            .await?;
        let dash = cfg
            .backoff
            .retry(|| DashboardClient::connect(&da, cfg.request_timeout))
            .await?;
        let script = ScriptClient::connect(&cfg.addr(cfg.script_port), cfg.request_timeout).await?;
        Ok(Self {
            reconnect: true,
            recoveries: AtomicU64::new(0),
            rtde: Mutex::new(Some(Arc::new(rtde))),
            dashboard: Mutex::new(Some(Arc::new(dash))),
            script,
            cfg,
        })
    }

    /// Build from already attached clients (no reconnection).
    pub fn attach(
        cfg: UrConfig,
        rtde: RtdeClient,
        dashboard: DashboardClient,
        script: ScriptClient,
    ) -> Self {
        Self {
            reconnect: false,
            recoveries: AtomicU64::new(0),
            rtde: Mutex::new(Some(Arc::new(rtde))),
            dashboard: Mutex::new(Some(Arc::new(dashboard))),
            script,
            cfg,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &UrConfig {
        &self.cfg
    }

    fn err(&self, e: UrError) -> DriverError {
        DriverError::from_device(self.cfg.name.clone(), e)
    }

    async fn rtde_client(&self) -> Result<Arc<RtdeClient>, UrError> {
        let mut g = self.rtde.lock().await;
        if let Some(c) = g.as_ref() {
            if !c.is_closed() || !self.reconnect {
                return Ok(c.clone());
            }
            self.recoveries.fetch_add(1, Ordering::Relaxed);
        }
        if !self.reconnect {
            return Err(UrError::Disconnected {
                interface: Interface::Rtde,
                detail: "no RTDE session".into(),
            });
        }
        *g = None;
        let addr = self.cfg.addr(self.cfg.rtde_port);
        tracing::warn!("{}: reconnecting RTDE to {addr}", self.cfg.name);
        let c = Arc::new(
            self.cfg
                .backoff
                .retry(|| RtdeClient::connect(&addr, self.cfg.rtde.clone()))
                .await?,
        );
        *g = Some(c.clone());
        Ok(c)
    }

    async fn drop_rtde(&self) {
        if self.rtde.lock().await.take().is_some() {
            self.recoveries.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// A fresh-enough RTDE sample; on a broken or silent stream, reconnect once and retry.
    pub async fn sample(&self, fresh: bool) -> Result<Arc<RtdeSample>, UrError> {
        let c = self.rtde_client().await?;
        let r = if fresh {
            c.next_sample().await
        } else {
            c.latest().await
        };
        match r {
            Err(e) if self.reconnect && e.kind().needs_reconnect() => {
                self.drop_rtde().await;
                let c = self.rtde_client().await?;
                c.next_sample().await
            }
            r => r,
        }
    }

    /// The dashboard session (reconnected when needed).
    pub async fn dashboard(&self) -> Result<Arc<DashboardClient>, UrError> {
        let mut g = self.dashboard.lock().await;
        if let Some(d) = g.as_ref() {
            return Ok(d.clone());
        }
        if !self.reconnect {
            return Err(UrError::Disconnected {
                interface: Interface::Dashboard,
                detail: "no dashboard session".into(),
            });
        }
        let addr = self.cfg.addr(self.cfg.dashboard_port);
        let d = Arc::new(
            self.cfg
                .backoff
                .retry(|| DashboardClient::connect(&addr, self.cfg.request_timeout))
                .await?,
        );
        *g = Some(d.clone());
        Ok(d)
    }

    async fn dashboard_cmd<T, F, Fut>(&self, f: F) -> Result<T, UrError>
    where
        F: Fn(Arc<DashboardClient>) -> Fut,
        Fut: std::future::Future<Output = Result<T, UrError>>,
    {
        let d = self.dashboard().await?;
        match f(d).await {
            Err(e) if self.reconnect && e.kind().needs_reconnect() => {
                *self.dashboard.lock().await = None;
                self.recoveries.fetch_add(1, Ordering::Relaxed);
                let d = self.dashboard().await?;
                f(d).await
            }
            r => r,
        }
    }

    /// Power on, release the brakes and wait (≤ 30 s) for robot_mode RUNNING.
    pub async fn power_up(&self) -> Result<(), UrError> {
        self.dashboard_cmd(|d| async move { d.power_on().await })
            .await?;
        self.dashboard_cmd(|d| async move { d.brake_release().await })
            .await?;
        let t0 = Instant::now();
        loop {
            let s = self.sample(true).await?;
            if s.int("robot_mode") == Some(RobotMode::Running.as_i32() as i64) {
                return Ok(());
            }
            if t0.elapsed() > Duration::from_secs(30) {
                return Err(UrError::Timeout {
                    interface: Interface::Rtde,
                    what: "waiting for robot_mode RUNNING".into(),
                    secs: 30.0,
                });
            }
        }
    }

    fn check_safety(s: &RtdeSample) -> Result<(), UrError> {
        let m = s.int("safety_mode").unwrap_or(1) as i32;
        match SafetyMode::from_i32(m) {
            Some(SafetyMode::Normal) | Some(SafetyMode::Reduced) => Ok(()),
            other => Err(UrError::SafetyStop {
                safety_mode: m,
                name: other.map_or("UNKNOWN", SafetyMode::name),
            }),
        }
    }

    fn q(s: &RtdeSample) -> Result<[f64; 6], UrError> {
        s.vec6("actual_q").ok_or_else(|| UrError::Protocol {
            interface: Interface::Rtde,
            detail: "recipe lacks actual_q".into(),
        })
    }

    async fn move_inner(&self, target: &[f64], speed: MoveSpeed) -> Result<(), UrError> {
        if target.len() != 6 || target.iter().any(|x| !x.is_finite()) {
            return Err(UrError::InvalidArgument(format!(
                "a UR move needs 6 finite joint targets, got {target:?}"
            )));
        }
        if !(speed.max_vel > 0.0 && speed.max_acc > 0.0) {
            return Err(UrError::InvalidArgument(format!("bad speed {speed:?}")));
        }
        let s = self.sample(false).await?;
        Self::check_safety(&s)?;
        let mode = s.int("robot_mode").unwrap_or(-1) as i32;
        if mode != RobotMode::Running.as_i32() {
            return Err(UrError::NotReady { robot_mode: mode });
        }
        let q0 = Self::q(&s)?;
        let d = q0
            .iter()
            .zip(target)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        let est = trapezoid_duration(d, speed.max_vel, speed.max_acc);
        self.script
            .send(&movej_program(target, speed.max_acc, speed.max_vel))
            .await?;
        let t0 = Instant::now();
        let deadline =
            Duration::from_secs_f64(est * 1.5) + self.cfg.start_timeout + self.cfg.move_margin;
        let tol = self.cfg.joint_tolerance_rad;
        let mut seen_playing = false;
        loop {
            let s = self.sample(true).await?;
            Self::check_safety(&s)?;
            let q = Self::q(&s)?;
            let err = q
                .iter()
                .zip(target)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            let rs = s.int("runtime_state").unwrap_or(-1);
            if rs == runtime_state::PLAYING as i64 {
                seen_playing = true;
            }
            if rs == runtime_state::STOPPED as i64 {
                if err <= tol {
                    return Ok(());
                }
                if seen_playing {
                    return Err(UrError::MoveAborted {
                        detail: format!("program stopped {:.4} rad from the target", err),
                    });
                }
                if t0.elapsed() > self.cfg.start_timeout {
                    return Err(UrError::MoveAborted {
                        detail: format!(
                            "the movej program did not start within {:.1} s",
                            self.cfg.start_timeout.as_secs_f64()
                        ),
                    });
                }
            }
            if t0.elapsed() > deadline {
                return Err(UrError::Timeout {
                    interface: Interface::Rtde,
                    what: format!("waiting for arrival ({err:.4} rad to go)"),
                    secs: deadline.as_secs_f64(),
                });
            }
        }
    }
}

#[async_trait]
impl JointReadout for UrArm {
    async fn joints(&self) -> DriverResult<JointState> {
        let s = self.sample(false).await.map_err(|e| self.err(e))?;
        let q = Self::q(&s).map_err(|e| self.err(e))?;
        Ok(JointState {
            q: q.to_vec(),
            qd: s.vec6("actual_qd").map(|v| v.to_vec()),
            t: s.double("timestamp").unwrap_or(0.0),
        })
    }
}

#[async_trait]
impl FlangePose for UrArm {
    async fn flange_pose(&self) -> DriverResult<FlangeToBase> {
        let s = self.sample(false).await.map_err(|e| self.err(e))?;
        let tcp = s.vec6("actual_TCP_pose").ok_or_else(|| {
            self.err(UrError::Protocol {
                interface: Interface::Rtde,
                detail: "recipe lacks actual_TCP_pose".into(),
            })
        })?;
        let tcp_in_base = ur_pose_to_isometry_mm(&tcp);
        // actual_TCP_pose includes the configured TCP offset; remove it to get the flange.
        let offset = s.vec6("tcp_offset").unwrap_or([0.0; 6]);
        let tcp_in_flange = ur_pose_to_isometry_mm(&offset);
        Ok(FlangeToBase(tcp_in_base * tcp_in_flange.inverse()))
    }
}

#[async_trait]
impl MoveJoints for UrArm {
    fn dof(&self) -> usize {
        6
    }
    async fn move_joints(&self, target: &[f64], speed: MoveSpeed) -> DriverResult<()> {
        self.move_inner(target, speed)
            .await
            .map_err(|e| self.err(e))
    }
    async fn stop(&self) -> DriverResult<()> {
        self.script
            .send(&stopj_program(2.0))
            .await
            .map_err(|e| self.err(e))
    }
}

/// Map RTDE robot_mode / safety_mode / runtime_state to the vendor-neutral state.
pub fn arm_state(robot_mode: i32, safety_mode: i32, runtime: u32) -> ArmState {
    let mode = match RobotMode::from_i32(robot_mode) {
        Some(RobotMode::Running) if runtime == runtime_state::PLAYING => ArmMode::Moving,
        Some(RobotMode::Running) => ArmMode::Ready,
        Some(RobotMode::Idle | RobotMode::PowerOn | RobotMode::Backdrive) => ArmMode::Idle,
        Some(RobotMode::PowerOff | RobotMode::Disconnected | RobotMode::NoController) => {
            ArmMode::PoweredOff
        }
        _ => ArmMode::Unknown,
    };
    let safety = match SafetyMode::from_i32(safety_mode) {
        Some(SafetyMode::Normal) => SafetyState::Normal,
        Some(SafetyMode::Reduced) => SafetyState::Reduced,
        Some(
            SafetyMode::ProtectiveStop
            | SafetyMode::SafeguardStop
            | SafetyMode::AutomaticModeSafeguardStop
            | SafetyMode::SystemThreePositionEnablingStop,
        ) => SafetyState::ProtectiveStop,
        Some(SafetyMode::SystemEmergencyStop | SafetyMode::RobotEmergencyStop) => {
            SafetyState::EmergencyStop
        }
        _ => SafetyState::Fault,
    };
    ArmState { mode, safety }
}

#[async_trait]
impl ArmStatus for UrArm {
    fn link_recoveries(&self) -> u64 {
        self.recoveries.load(Ordering::Relaxed)
    }
    async fn state(&self) -> DriverResult<ArmState> {
        let s = self.sample(false).await.map_err(|e| self.err(e))?;
        Ok(arm_state(
            s.int("robot_mode").unwrap_or(-1) as i32,
            s.int("safety_mode").unwrap_or(11) as i32,
            s.int("runtime_state").unwrap_or(1) as u32,
        ))
    }
    async fn recover(&self) -> DriverResult<()> {
        self.dashboard_cmd(|d| async move { d.unlock_protective_stop().await })
            .await
            .map_err(|e| self.err(e))?;
        // Wait (≤ 2 s) until RTDE shows the stop cleared.
        let t0 = Instant::now();
        loop {
            let s = self.sample(true).await.map_err(|e| self.err(e))?;
            if Self::check_safety(&s).is_ok() {
                return Ok(());
            }
            if t0.elapsed() > Duration::from_secs(2) {
                return Err(DriverError::new(
                    ErrorKind::SafetyStop,
                    self.cfg.name.clone(),
                    "protective stop still active after unlock",
                ));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn trapezoid_cases() {
        assert_eq!(trapezoid_duration(0.0, 1.0, 1.0), 0.0);
        // triangular: d < v²/a → 2 sqrt(d/a)
        assert_relative_eq!(trapezoid_duration(0.25, 1.0, 1.0), 1.0);
        // trapezoidal: d/v + v/a
        assert_relative_eq!(trapezoid_duration(2.0, 1.0, 2.0), 2.5);
    }

    #[test]
    fn pose_conversion_m_to_mm() {
        let iso = ur_pose_to_isometry_mm(&[0.1, -0.2, 0.3, 0.0, 0.0, std::f64::consts::FRAC_PI_2]);
        assert_relative_eq!(iso.translation.vector, Vector3::new(100.0, -200.0, 300.0));
        let x = iso.rotation * Vector3::x();
        assert_relative_eq!(x, Vector3::y(), epsilon = 1e-12);
    }

    #[test]
    fn state_mapping() {
        let s = arm_state(7, 3, 1);
        assert_eq!(s.mode, ArmMode::Ready);
        assert_eq!(s.safety, SafetyState::ProtectiveStop);
        assert_eq!(arm_state(7, 1, 2).mode, ArmMode::Moving);
        assert_eq!(arm_state(3, 7, 1).safety, SafetyState::EmergencyStop);
    }
}
