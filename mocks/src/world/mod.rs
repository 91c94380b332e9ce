//! The simulated world: true robots with hidden effects, sensors, scene, clock, control.
//!
//! Units inside: mm, rad, s. Everything the protocol servers and the in-process `Sim*` devices
//! report comes from here. The world shares no code with the root crate's model: the true
//! kinematics is a URDF-style chain ([`chain`]) with its own forward kinematics.
//!
//! Determinism: every random draw comes from a per-device ChaCha8 stream seeded from the
//! scenario seed, and in virtual-clock mode every operation advances simulated time by its
//! simulated duration, so the same scenario and the same call sequence give byte-identical
//! measurements.

pub mod camera_board;
mod centring;
pub mod chain;
pub mod charuco;
pub mod clock;
pub mod control;
pub mod effects;
pub mod gear;
pub mod motion;
pub mod operator;
pub mod rcm_view;
pub mod sensors;

use crate::scenario::{
    CameraConfig, ClockMode, LaserConfig, Scenario, ScenarioError, SceneConfig, TrackerConfig,
    TrackerEffects, VolumeKind,
};
use chain::UrdfChain;
use clock::VirtualClock;
pub use control::{Control, Fault};
use effects::{ArmPhysics, JointContext, PointMass};
use motion::Move;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand::{Rng, RngCore};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
pub use robocal_drivers::{ArmMode, ArmState, SafetyState};
use robocal_drivers::{
    Clock, Image, JointState, MarkerToTracker, MoveSpeed, RangeReading, SystemClock,
    ToolObservation, ToolStatus, TrackerFrame,
};
use serde::Serialize;
use std::sync::{Arc, Mutex};

/// Errors of world operations.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum WorldError {
    /// No such device index.
    #[error("no {kind} with index {index}")]
    NoSuchDevice {
        /// Device kind.
        kind: &'static str,
        /// Index asked for.
        index: usize,
    },
    /// Wrong number of joints or a non-finite value.
    #[error("invalid target: {0}")]
    InvalidTarget(String),
    /// Target outside the joint limits.
    #[error("joint {joint} target {value_deg:.3}° outside [{lo_deg:.1}°, {hi_deg:.1}°]")]
    OutOfLimits {
        /// Joint (1-based).
        joint: usize,
        /// Target (deg).
        value_deg: f64,
        /// Lower limit (deg).
        lo_deg: f64,
        /// Upper limit (deg).
        hi_deg: f64,
    },
    /// The arm is in a protective stop.
    #[error("arm is in a protective stop")]
    ProtectiveStop,
}

/// Runtime state of one arm.
#[derive(Debug, Clone)]
pub(crate) struct ArmRuntime {
    pub(crate) name: String,
    pub(crate) serial: String,
    pub(crate) physics: ArmPhysics,
    pub(crate) motion: Move,
    pub(crate) max_vel: f64,
    pub(crate) max_acc: f64,
    pub(crate) settle_s: f64,
    pub(crate) approach: Vec<f64>,
    pub(crate) protective_stop: bool,
    pub(crate) rng: ChaCha8Rng,
    /// The arm follows the operator's hand: a DENSO whose teach pendant holds it (always), a
    /// UR only in `freedrive_mode()`.
    pub(crate) follows_hand: bool,
}

impl ArmRuntime {
    pub(crate) fn halt(&mut self, now: f64) {
        let q = self.motion.q_at(now);
        self.motion = Move::hold(q, now);
    }
    fn ctx(&self, t: f64) -> JointContext {
        JointContext {
            t_s: t,
            approach: self.approach.clone(),
        }
    }
}

/// Runtime state of one tracker.
#[derive(Debug, Clone)]
pub(crate) struct TrackerRuntime {
    pub(crate) cfg: TrackerConfig,
    pub(crate) arm: usize,
    pub(crate) tracker_in_base: Isometry3<f64>,
    pub(crate) marker_on_flange: Isometry3<f64>,
    pub(crate) volume: VolumeKind,
    pub(crate) frame_no: u64,
    pub(crate) occluded: bool,
    pub(crate) rng: ChaCha8Rng,
}

/// Runtime state of one laser.
#[derive(Debug, Clone)]
pub(crate) struct LaserRuntime {
    pub(crate) cfg: LaserConfig,
    pub(crate) arm: usize,
    pub(crate) force_oor: u32,
    pub(crate) rng: ChaCha8Rng,
    /// End time of the arm move whose spot the operator last centred ([`centring`]).
    pub(crate) centred_end: Option<f64>,
}

/// Runtime state of one camera.
#[derive(Debug, Clone)]
pub(crate) struct CameraRuntime {
    pub(crate) cfg: CameraConfig,
    pub(crate) arm: Option<usize>,
    pub(crate) rng: ChaCha8Rng,
}

/// The world state (behind the handle's mutex).
pub(crate) struct World {
    pub(crate) scenario: Scenario,
    pub(crate) arms: Vec<ArmRuntime>,
    pub(crate) trackers: Vec<TrackerRuntime>,
    pub(crate) lasers: Vec<LaserRuntime>,
    pub(crate) cameras: Vec<CameraRuntime>,
    pub(crate) scene: SceneConfig,
    pub(crate) control: control::ControlState,
    pub(crate) operator: Option<OperatorRuntime>,
    /// Endoscope renderers of fixed cameras in an RCM cell, by camera index (built on the
    /// first frame: [`rcm_view`]).
    pub(crate) rcm_renderers: std::collections::HashMap<usize, Arc<crate::rcm_render::RcmRenderer>>,
}

/// The simulated operator's script and when it started.
pub(crate) struct OperatorRuntime {
    cfg: operator::OperatorConfig,
    tracker: Option<usize>,
    t0: Option<f64>,
    /// Joint angles of each arm when the script started (where a first drag starts from).
    arm_start: Vec<Vec<f64>>,
}

/// Which device a name refers to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceRef {
    /// Arm index.
    Arm(usize),
    /// Tracker index.
    Tracker(usize),
    /// Laser index.
    Laser(usize),
    /// Camera index.
    Camera(usize),
}

/// The hidden truth of one arm.
#[derive(Debug, Clone, Serialize)]
pub struct ArmTruth {
    /// Device name.
    pub name: String,
    /// True chain, offsets, masses and effects.
    pub physics: ArmPhysics,
    /// Sign of the last motion per joint.
    pub approach: Vec<f64>,
}

/// The hidden truth of one tracker.
#[derive(Debug, Clone, Serialize)]
pub struct TrackerTruth {
    /// Device name.
    pub name: String,
    /// Index of the arm carrying the marker.
    pub arm: usize,
    /// Tracker pose in the robot base frame (before any bump).
    pub tracker_in_base: Isometry3<f64>,
    /// Marker pose in the flange frame.
    pub marker_on_flange: Isometry3<f64>,
    /// Effects.
    pub effects: TrackerEffects,
    /// Measurement volume in force.
    pub volume: VolumeKind,
}

/// The hidden truth of one laser.
#[derive(Debug, Clone, Serialize)]
pub struct LaserTruth {
    /// Device name.
    pub name: String,
    /// Index of the arm carrying it.
    pub arm: usize,
    /// Configuration (beam origin/direction in the flange frame, window, effects).
    pub config: LaserConfig,
}

/// Everything hidden in the world.
#[derive(Debug, Clone, Serialize)]
pub struct Truth {
    /// Arms.
    pub arms: Vec<ArmTruth>,
    /// Trackers.
    pub trackers: Vec<TrackerTruth>,
    /// Lasers.
    pub lasers: Vec<LaserTruth>,
    /// Cameras.
    pub cameras: Vec<CameraConfig>,
    /// Scene.
    pub scene: SceneConfig,
}

/// A cloneable handle to the shared world.
#[derive(Clone)]
pub struct WorldHandle {
    inner: Arc<Mutex<World>>,
    clock: Arc<dyn Clock>,
    vclock: Option<Arc<VirtualClock>>,
}

fn rng_for(seed: u64, kind: u64, index: usize) -> ChaCha8Rng {
    // SplitMix-style mixing so that streams of different devices are unrelated.
    let mut z = seed
        .wrapping_add(kind.wrapping_mul(0x9E37_79B9_7F4A_7C15))
        .wrapping_add((index as u64 + 1).wrapping_mul(0xBF58_476D_1CE4_E5B9));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ChaCha8Rng::seed_from_u64(z ^ (z >> 31))
}

fn normal<R: Rng>(rng: &mut R) -> f64 {
    rng.sample::<f64, _>(StandardNormal)
}

impl WorldHandle {
    /// Build the world of a scenario (its seed draws the hidden errors).
    pub fn from_scenario(s: &Scenario) -> Result<Self, ScenarioError> {
        let mut arms = Vec::new();
        for (i, a) in s.arms.iter().enumerate() {
            let nominal = UrdfChain::preset(&a.model).ok_or_else(|| {
                ScenarioError::Invalid(format!(
                    "arm {}: unknown model {:?} (known: {:?})",
                    a.name,
                    a.model,
                    UrdfChain::PRESETS
                ))
            })?;
            let n = nominal.dof();
            let mut erng = match a.errors.seed {
                Some(sd) => ChaCha8Rng::seed_from_u64(sd),
                None => rng_for(s.seed, 1, i),
            };
            let chain = nominal.perturbed(&mut erng, a.errors.origin_mm, a.errors.origin_deg);
            let offsets_rad = (0..n)
                .map(|_| chain::signed_uniform(&mut erng, a.errors.offset_deg).to_radians())
                .collect();
            let mut masses = a.masses.clone();
            if let Some(p) = &a.payload {
                masses.push(PointMass {
                    link: n + 1,
                    xyz_mm: p.xyz_mm,
                    kg: p.kg,
                });
            }
            for m in &masses {
                if m.link == 0 || m.link > n + 1 {
                    return Err(ScenarioError::Invalid(format!(
                        "arm {}: mass on link {} (valid 1..={})",
                        a.name,
                        m.link,
                        n + 1
                    )));
                }
            }
            let physics = ArmPhysics {
                nominal,
                chain,
                offsets_rad,
                masses,
                effects: a.effects.clone(),
                gravity_dir: -Vector3::z(),
            };
            let home: Vec<f64> = match &a.home_deg {
                Some(h) if h.len() == n => h.iter().map(|d| d.to_radians()).collect(),
                Some(h) => {
                    return Err(ScenarioError::Invalid(format!(
                        "arm {}: home_deg has {} values, the arm has {n} joints",
                        a.name,
                        h.len()
                    )))
                }
                None => vec![0.0; n],
            };
            arms.push(ArmRuntime {
                name: a.name.clone(),
                serial: a.serial.clone(),
                physics,
                motion: Move::hold(home, 0.0),
                max_vel: a.motion.max_vel_deg_s.to_radians(),
                max_acc: a.motion.max_acc_deg_s2.to_radians(),
                settle_s: a.motion.settle_s,
                approach: vec![1.0; n],
                protective_stop: false,
                rng: rng_for(s.seed, 2, i),
                follows_hand: a.protocol != crate::scenario::Protocol::Ur,
            });
        }
        let arm_index = |name: &str, who: &str| {
            s.arms
                .iter()
                .position(|a| a.name == name)
                .ok_or_else(|| ScenarioError::Invalid(format!("{who}: no arm named {name:?}")))
        };
        let mut trackers = Vec::new();
        for (i, t) in s.trackers.iter().enumerate() {
            let default_volume = match t.kind {
                crate::scenario::TrackerKind::NdiOptotrakCertus => VolumeKind::Optotrak,
                _ => VolumeKind::PolarisPyramid,
            };
            trackers.push(TrackerRuntime {
                cfg: t.clone(),
                arm: arm_index(&t.arm, &t.name)?,
                tracker_in_base: t.tracker_in_base.isometry(),
                marker_on_flange: t.marker_on_flange.isometry(),
                volume: t.effects.volume.unwrap_or(default_volume),
                frame_no: 0,
                occluded: false,
                rng: rng_for(s.seed, 3, i),
            });
        }
        let mut lasers = Vec::new();
        for (i, l) in s.lasers.iter().enumerate() {
            let d = Vector3::from(l.beam_dir);
            if d.norm().is_nan() || d.norm() <= 0.0 {
                return Err(ScenarioError::Invalid(format!("{}: zero beam_dir", l.name)));
            }
            let mut cfg = l.clone();
            let dn = d.normalize();
            cfg.beam_dir = [dn.x, dn.y, dn.z];
            lasers.push(LaserRuntime {
                cfg,
                arm: arm_index(&l.arm, &l.name)?,
                force_oor: 0,
                rng: rng_for(s.seed, 4, i),
                centred_end: None,
            });
        }
        let mut cameras = Vec::new();
        for (i, c) in s.cameras.iter().enumerate() {
            let arm = match &c.arm {
                Some(a) => Some(arm_index(a, &c.name)?),
                None => None,
            };
            if c.width == 0 || c.height == 0 || c.width > 8192 || c.height > 8192 {
                return Err(ScenarioError::Invalid(format!(
                    "{}: bad image size",
                    c.name
                )));
            }
            cameras.push(CameraRuntime {
                cfg: c.clone(),
                arm,
                rng: rng_for(s.seed, 5, i),
            });
        }
        let mut names = std::collections::HashSet::new();
        for (n, _) in s.devices() {
            if !names.insert(n.clone()) {
                return Err(ScenarioError::Invalid(format!(
                    "duplicate device name {n:?}"
                )));
            }
        }
        let (clock, vclock): (Arc<dyn Clock>, Option<Arc<VirtualClock>>) = match s.clock {
            ClockMode::Virtual => {
                let v = Arc::new(VirtualClock::new());
                (v.clone(), Some(v))
            }
            ClockMode::Real => (Arc::new(SystemClock::default()), None),
        };
        Ok(Self {
            inner: Arc::new(Mutex::new(World {
                scenario: s.clone(),
                arms,
                trackers,
                lasers,
                cameras,
                scene: s.scene.clone(),
                control: Default::default(),
                rcm_renderers: Default::default(),
                operator: match &s.operator {
                    None => None,
                    Some(op) => Some(OperatorRuntime {
                        // No tracker: a script that only drags the arm.
                        tracker: match op.tracker.as_str() {
                            "" => None,
                            name => {
                                Some(s.trackers.iter().position(|t| t.name == name).ok_or_else(
                                    || {
                                        ScenarioError::Invalid(format!(
                                            "operator.tracker: no tracker named {name:?}"
                                        ))
                                    },
                                )?)
                            }
                        },
                        cfg: op.clone(),
                        t0: None,
                        arm_start: Vec::new(),
                    }),
                },
            })),
            clock,
            vclock,
        })
    }

    pub(crate) fn with<R>(&self, f: impl FnOnce(&mut World) -> R) -> R {
        let mut g = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        if g.operator.as_ref().is_some_and(|o| o.t0.is_some()) {
            let now = self.now();
            g.apply_drag(now);
        }
        f(&mut g)
    }

    /// Start the operator's script now, unless it has started already.
    fn operator_start(&self) {
        let now = self.now();
        self.with(|w| {
            let qs: Vec<Vec<f64>> = w.arms.iter().map(|a| a.motion.q_at(now)).collect();
            if let Some(o) = w.operator.as_mut() {
                if o.t0.is_none() {
                    o.t0 = Some(now);
                    o.arm_start = qs;
                }
            }
        });
    }

    /// Put arm `arm` in (or out of) freedrive: in freedrive it follows the operator's hand.
    /// A DENSO held by its teach pendant follows the hand whatever this says.
    pub fn arm_set_freedrive(&self, arm: usize, on: bool) {
        let uses_freedrive = self.with(|w| {
            w.scenario
                .arms
                .get(arm)
                .is_some_and(|a| a.protocol == crate::scenario::Protocol::Ur)
        });
        if uses_freedrive {
            let now = self.now();
            self.with(|w| {
                if let Some(a) = w.arms.get_mut(arm) {
                    a.follows_hand = on;
                    if !on {
                        a.halt(now);
                    }
                }
            });
        }
    }

    /// Whether arm `arm` follows the operator's hand now (freedrive / teach pendant).
    pub fn arm_follows_hand(&self, arm: usize) -> bool {
        self.with(|w| w.arms.get(arm).is_some_and(|a| a.follows_hand))
    }

    /// The operator's TRUE probe marker pose in the base frame now (tests only), if the probe
    /// is in hand.
    pub fn operator_probe_truth(&self) -> Option<Isometry3<f64>> {
        let now = self.now();
        self.with(|w| match w.operator_act(now) {
            Some(operator::Act::Probe(m)) => Some(m),
            _ => None,
        })
    }

    /// The world clock (virtual or real time).
    pub fn clock(&self) -> Arc<dyn Clock> {
        self.clock.clone()
    }

    /// Whether time is virtual.
    pub fn is_virtual(&self) -> bool {
        self.vclock.is_some()
    }

    /// Current world time (s).
    pub fn now(&self) -> f64 {
        self.clock.now()
    }

    /// Advance virtual time by `secs` (no effect in real-time mode).
    pub fn advance(&self, secs: f64) {
        if let Some(v) = &self.vclock {
            v.advance(secs);
        }
    }

    /// The scenario this world was built from.
    pub fn scenario(&self) -> Scenario {
        self.with(|w| w.scenario.clone())
    }

    /// Look a device up by name.
    pub fn device(&self, name: &str) -> Option<DeviceRef> {
        self.with(|w| {
            if let Some(i) = w.arms.iter().position(|a| a.name == name) {
                return Some(DeviceRef::Arm(i));
            }
            if let Some(i) = w.trackers.iter().position(|a| a.cfg.name == name) {
                return Some(DeviceRef::Tracker(i));
            }
            if let Some(i) = w.lasers.iter().position(|a| a.cfg.name == name) {
                return Some(DeviceRef::Laser(i));
            }
            w.cameras
                .iter()
                .position(|a| a.cfg.name == name)
                .map(DeviceRef::Camera)
        })
    }

    // ------------------------------------------------------------------ arms

    /// Number of arms.
    pub fn arm_count(&self) -> usize {
        self.with(|w| w.arms.len())
    }

    /// Degrees of freedom of arm `arm` (0 when there is no such arm).
    pub fn arm_dof(&self, arm: usize) -> usize {
        self.with(|w| w.arms.get(arm).map_or(0, |a| a.physics.nominal.dof()))
    }

    /// Model name and serial of arm `arm`.
    pub fn arm_identity(&self, arm: usize) -> Option<(String, String)> {
        self.with(|w| {
            w.arms
                .get(arm)
                .map(|a| (a.physics.nominal.model.clone(), a.serial.clone()))
        })
    }

    /// The encoder reading (rad) and joint velocities (rad/s) now.
    ///
    /// # Panics
    /// Never; an unknown arm index yields an empty state.
    pub fn arm_joint_state(&self, arm: usize) -> JointState {
        self.operator_start();
        let t = self.now();
        self.with(|w| match w.arms.get(arm) {
            Some(a) => JointState {
                q: a.motion.q_at(t),
                qd: Some(a.motion.qd_at(t)),
                t,
            },
            None => JointState {
                q: Vec::new(),
                qd: None,
                t,
            },
        })
    }

    /// The controller's nominal forward kinematics of its encoders (flange in base, mm).
    pub fn arm_controller_flange(&self, arm: usize) -> Isometry3<f64> {
        let q = self.arm_joint_state(arm).q;
        self.with(|w| {
            w.arms
                .get(arm)
                .map_or(Isometry3::identity(), |a| a.physics.nominal_flange(&q))
        })
    }

    /// The TRUE flange pose now (tests only; includes every effect).
    pub fn arm_true_flange(&self, arm: usize) -> Isometry3<f64> {
        let t = self.now();
        self.with(|w| {
            w.arms.get(arm).map_or(Isometry3::identity(), |a| {
                a.physics.true_flange(&a.motion.q_at(t), &a.ctx(t))
            })
        })
    }

    /// Start a synchronised trapezoidal move to `target` (rad) under `speed` (capped by the
    /// controller's own limits). Returns the duration including settling (s).
    pub fn arm_start_move(
        &self,
        arm: usize,
        target: &[f64],
        speed: MoveSpeed,
    ) -> Result<f64, WorldError> {
        let now = self.now();
        self.with(|w| {
            let a = w.arms.get_mut(arm).ok_or(WorldError::NoSuchDevice {
                kind: "arm",
                index: arm,
            })?;
            if a.protective_stop {
                return Err(WorldError::ProtectiveStop);
            }
            let n = a.physics.nominal.dof();
            if target.len() != n || target.iter().any(|x| !x.is_finite()) {
                return Err(WorldError::InvalidTarget(format!(
                    "expected {n} finite joint values, got {:?}",
                    target
                )));
            }
            for (i, (x, j)) in target.iter().zip(&a.physics.nominal.joints).enumerate() {
                if *x < j.limits_rad.0 - 1e-9 || *x > j.limits_rad.1 + 1e-9 {
                    return Err(WorldError::OutOfLimits {
                        joint: i + 1,
                        value_deg: x.to_degrees(),
                        lo_deg: j.limits_rad.0.to_degrees(),
                        hi_deg: j.limits_rad.1.to_degrees(),
                    });
                }
            }
            let v = if speed.max_vel > 0.0 {
                speed.max_vel.min(a.max_vel)
            } else {
                a.max_vel
            };
            let acc = if speed.max_acc > 0.0 {
                speed.max_acc.min(a.max_acc)
            } else {
                a.max_acc
            };
            let from = a.motion.q_at(now);
            let sigma = a.physics.effects.servo_error_deg.to_radians();
            let to: Vec<f64> = target
                .iter()
                .map(|x| {
                    if sigma > 0.0 {
                        x + sigma * normal(&mut a.rng)
                    } else {
                        *x
                    }
                })
                .collect();
            for (k, (f, t)) in from.iter().zip(&to).enumerate() {
                if (t - f).abs() > 1e-12 {
                    a.approach[k] = (t - f).signum();
                }
            }
            a.motion = Move::plan(from, to, now, v, acc, a.settle_s);
            Ok(a.motion.end() - now)
        })
    }

    /// Whether arm `arm` is still moving or settling.
    pub fn arm_is_moving(&self, arm: usize) -> bool {
        let now = self.now();
        self.with(|w| w.arms.get(arm).is_some_and(|a| now < a.motion.end()))
    }

    /// Time (s) at which the current motion of `arm` ends (settled).
    pub fn arm_motion_end(&self, arm: usize) -> f64 {
        self.with(|w| w.arms.get(arm).map_or(0.0, |a| a.motion.end()))
    }

    /// Wait until the current motion ends (virtual time: jumps to the end).
    pub async fn arm_wait_arrival(&self, arm: usize) {
        loop {
            let end = self.arm_motion_end(arm);
            let now = self.now();
            if now >= end {
                return;
            }
            match &self.vclock {
                Some(v) => v.advance_to(end),
                None => self.clock.sleep(end - now).await,
            }
        }
    }

    /// Stop any motion now (the arm halts where it is).
    pub fn arm_stop(&self, arm: usize) {
        let now = self.now();
        self.with(|w| {
            if let Some(a) = w.arms.get_mut(arm) {
                a.halt(now);
            }
        });
    }

    /// Mode and safety state.
    pub fn arm_state(&self, arm: usize) -> ArmState {
        let moving = self.arm_is_moving(arm);
        self.with(|w| match w.arms.get(arm) {
            None => ArmState {
                mode: ArmMode::Unknown,
                safety: SafetyState::Fault,
            },
            Some(a) if a.protective_stop => ArmState {
                mode: ArmMode::Idle,
                safety: SafetyState::ProtectiveStop,
            },
            Some(_) => ArmState {
                mode: if moving {
                    ArmMode::Moving
                } else {
                    ArmMode::Ready
                },
                safety: SafetyState::Normal,
            },
        })
    }

    /// Clear a protective stop.
    pub fn arm_recover(&self, arm: usize) -> Result<(), WorldError> {
        self.with(|w| {
            let a = w.arms.get_mut(arm).ok_or(WorldError::NoSuchDevice {
                kind: "arm",
                index: arm,
            })?;
            a.protective_stop = false;
            Ok(())
        })
    }

    // --------------------------------------------------------------- trackers

    /// Number of trackers.
    pub fn tracker_count(&self) -> usize {
        self.with(|w| w.trackers.len())
    }

    /// Tool name and frame rate of tracker `tracker`.
    pub fn tracker_info(&self, tracker: usize) -> Option<(String, f64)> {
        self.with(|w| {
            w.trackers
                .get(tracker)
                .map(|t| (t.cfg.tool.clone(), t.cfg.rate_hz))
        })
    }

    /// The next frame of the first tracker (see [`Self::tracker_frame_of`]).
    pub fn tracker_frame(&self) -> TrackerFrame {
        self.tracker_frame_of(0)
    }

    /// The next frame of tracker `tracker`: in virtual time, advances the clock by 1/rate first.
    pub fn tracker_frame_of(&self, tracker: usize) -> TrackerFrame {
        let rate = self.with(|w| w.trackers.get(tracker).map_or(60.0, |t| t.cfg.rate_hz));
        if rate > 0.0 {
            self.advance(1.0 / rate);
        }
        if self.with(|w| {
            w.operator
                .as_ref()
                .is_some_and(|o| o.tracker == Some(tracker))
        }) {
            self.operator_start();
        }
        let t = self.now();
        self.with(|w| {
            let probe = match (
                &w.operator,
                w.operator_act(
                    t - w
                        .trackers
                        .get(tracker)
                        .map_or(0.0, |tr| tr.cfg.effects.latency_s),
                ),
            ) {
                (Some(o), Some(operator::Act::Probe(m))) if o.tracker == Some(tracker) => {
                    Some((o.cfg.probe_tool.clone(), m))
                }
                _ => None,
            };
            let Some(tr) = w.trackers.get(tracker) else {
                return TrackerFrame {
                    frame_number: 0,
                    t,
                    tools: Vec::new(),
                };
            };
            let eff = tr.cfg.effects.clone();
            let arm = &w.arms[tr.arm];
            let ts = t - eff.latency_s;
            let flange = arm.physics.true_flange(&arm.motion.q_at(ts), &arm.ctx(ts));
            let tib = tracker_in_base_at(tr.tracker_in_base, &eff, t);
            let marker_base = flange * tr.marker_on_flange;
            let tr = &mut w.trackers[tracker];
            tr.frame_no += 1;
            let mut tools = vec![ToolObservation {
                tool: tr.cfg.tool.clone(),
                status: observe(tr, &eff, &tib, &marker_base, true),
            }];
            if let Some((name, m)) = probe {
                tools.push(ToolObservation {
                    tool: name,
                    status: observe(tr, &eff, &tib, &m, false),
                });
            }
            TrackerFrame {
                frame_number: tr.frame_no,
                t,
                tools,
            }
        })
    }

    /// The noise-free TRUE marker pose in the (current, possibly bumped) tracker frame now,
    /// without scale error or latency (tests and truth files).
    pub fn marker_truth(&self, tracker: usize) -> Option<Isometry3<f64>> {
        let t = self.now();
        self.with(|w| {
            let tr = w.trackers.get(tracker)?;
            let arm = &w.arms[tr.arm];
            let flange = arm.physics.true_flange(&arm.motion.q_at(t), &arm.ctx(t));
            let tib = tracker_in_base_at(tr.tracker_in_base, &tr.cfg.effects, t);
            Some(tib.inverse() * flange * tr.marker_on_flange)
        })
    }

    // ----------------------------------------------------------------- lasers

    /// Number of lasers.
    pub fn laser_count(&self) -> usize {
        self.with(|w| w.lasers.len())
    }

    /// One sample of the first laser (see [`Self::laser_reading_of`]).
    pub fn laser_reading(&self) -> RangeReading {
        self.laser_reading_of(0)
    }

    /// One sample of laser `laser`: in virtual time, advances the clock by the sampling period.
    pub fn laser_reading_of(&self, laser: usize) -> RangeReading {
        let rate = self.with(|w| w.lasers.get(laser).map_or(1000.0, |l| l.cfg.rate_hz));
        if rate > 0.0 {
            self.advance(1.0 / rate);
        }
        let t = self.now();
        self.with(|w| {
            let World {
                lasers,
                arms,
                scene,
                ..
            } = w;
            let Some(l) = lasers.get_mut(laser) else {
                return RangeReading::OutOfRange;
            };
            if l.force_oor > 0 {
                l.force_oor -= 1;
                return RangeReading::OutOfRange;
            }
            if let Some(pl) = &scene.plate {
                if let Some(c) = &pl.centring {
                    centring::centre(&mut arms[l.arm], l, scene, pl, c, t);
                }
            }
            let arm = &arms[l.arm];
            let flange = arm.physics.true_flange(&arm.motion.q_at(t), &arm.ctx(t));
            let (o, u) = laser_ray(&flange, &l.cfg);
            let Some(hit) = sensors::cast_ray(scene, &o, &u) else {
                return RangeReading::OutOfRange;
            };
            let cos_g = (-u).dot(&hit.normal).clamp(-1.0, 1.0);
            if cos_g.acos() > l.cfg.max_incidence_deg.to_radians() {
                return RangeReading::OutOfRange;
            }
            let e = &l.cfg.effects;
            let u = (hit.distance_mm - 0.5 * (l.cfg.min_mm + l.cfg.max_mm))
                / (0.5 * (l.cfg.max_mm - l.cfg.min_mm)).max(1e-9);
            let m = hit.distance_mm * (1.0 + e.scale_ppm * 1e-6)
                + e.offset_mm
                + e.incidence_mm * (1.0 - cos_g)
                + e.nonlinearity_mm * u * u
                + e.noise_mm * normal(&mut l.rng);
            if m < l.cfg.min_mm || m > l.cfg.max_mm {
                RangeReading::OutOfRange
            } else {
                RangeReading::Distance(m)
            }
        })
    }

    /// The noise-free TRUE laser hit now: (distance mm, spot in base frame, surface label).
    pub fn laser_truth(&self, laser: usize) -> Option<(f64, Point3<f64>, String)> {
        let t = self.now();
        self.with(|w| {
            let l = w.lasers.get(laser)?;
            let arm = &w.arms[l.arm];
            let flange = arm.physics.true_flange(&arm.motion.q_at(t), &arm.ctx(t));
            let (o, u) = laser_ray(&flange, &l.cfg);
            let hit = sensors::cast_ray(&w.scene, &o, &u)?;
            Some((hit.distance_mm, o + u * hit.distance_mm, hit.surface))
        })
    }

    // ---------------------------------------------------------------- cameras

    /// Number of cameras.
    pub fn camera_count(&self) -> usize {
        self.with(|w| w.cameras.len())
    }

    /// Render the first camera (see [`Self::render_camera_of`]).
    pub fn render_camera(&self) -> Image {
        self.render_camera_of(0)
    }

    /// The true camera pose in the base frame now.
    pub fn camera_in_base(&self, camera: usize) -> Option<Isometry3<f64>> {
        let t = self.now();
        self.with(|w| {
            let c = w.cameras.get(camera)?;
            Some(match c.arm {
                Some(a) => {
                    let arm = &w.arms[a];
                    arm.physics.true_flange(&arm.motion.q_at(t), &arm.ctx(t))
                        * c.cfg.placement.isometry()
                }
                None => c.cfg.placement.isometry(),
            })
        })
    }

    /// Render an 8-bit image of the chessboard from camera `camera`. The world is locked only
    /// to read the pose and draw the image's noise seed; the rendering itself runs unlocked, so
    /// a camera stream never stalls the other devices.
    pub fn render_camera_of(&self, camera: usize) -> Image {
        if let Some(img) = self.render_rcm_view(camera) {
            return img;
        }
        let t = self.now();
        let pose = self.camera_in_base(camera);
        let job = self.with(|w| {
            let World { cameras, scene, .. } = w;
            cameras.get_mut(camera).map(|c| {
                (
                    c.cfg.clone(),
                    scene.chessboard.clone(),
                    ChaCha8Rng::seed_from_u64(c.rng.next_u64()),
                )
            })
        });
        match (job, pose) {
            (Some((cfg, board, mut rng)), Some(pose)) => Image {
                width: cfg.width,
                height: cfg.height,
                data: sensors::render(&cfg, &pose, board.as_ref(), &mut rng),
                t,
            },
            _ => Image {
                width: 0,
                height: 0,
                data: Vec::new(),
                t,
            },
        }
    }

    // ---------------------------------------------------------------- control

    /// Out-of-band control (tests only; never through the wire).
    pub fn control(&self) -> Control {
        Control {
            world: self.clone(),
        }
    }

    /// The next queued wire fault for `device` (shortcut for `control().take_fault`).
    pub fn take_fault(&self, device: &str) -> Option<Fault> {
        self.control().take_fault(device)
    }

    /// The hidden truth.
    pub fn truth(&self) -> Truth {
        self.with(|w| Truth {
            arms: w
                .arms
                .iter()
                .map(|a| ArmTruth {
                    name: a.name.clone(),
                    physics: a.physics.clone(),
                    approach: a.approach.clone(),
                })
                .collect(),
            trackers: w
                .trackers
                .iter()
                .map(|t| TrackerTruth {
                    name: t.cfg.name.clone(),
                    arm: t.arm,
                    tracker_in_base: t.tracker_in_base,
                    marker_on_flange: t.marker_on_flange,
                    effects: t.cfg.effects.clone(),
                    volume: t.volume,
                })
                .collect(),
            lasers: w
                .lasers
                .iter()
                .map(|l| LaserTruth {
                    name: l.cfg.name.clone(),
                    arm: l.arm,
                    config: l.cfg.clone(),
                })
                .collect(),
            cameras: w.cameras.iter().map(|c| c.cfg.clone()).collect(),
            scene: w.scene.clone(),
        })
    }
}

/// One tool's status in a frame: missing when occluded / not facing the tracker (the
/// tracker's occlusion switch applies to the arm marker only), out of volume, else the pose with
/// the tracker's scale error and noise.
fn observe(
    tr: &mut TrackerRuntime,
    eff: &TrackerEffects,
    tib: &Isometry3<f64>,
    marker_base: &Isometry3<f64>,
    arm_marker: bool,
) -> ToolStatus {
    let pose = tib.inverse() * marker_base;
    let p = Point3::from(pose.translation.vector);
    let tracker_origin = Point3::from(tib.translation.vector);
    let marker_origin = Point3::from(marker_base.translation.vector);
    let facing = eff.max_view_angle_deg.is_none_or(|max| {
        let zm = pose.rotation * Vector3::z();
        let to_tracker = -p.coords.normalize();
        zm.dot(&to_tracker).clamp(-1.0, 1.0).acos() <= max.to_radians()
    });
    let blocked = eff.occluders.iter().any(|o| {
        sensors::segment_distance(&tracker_origin, &marker_origin, &Point3::from(o.center_mm))
            < o.radius_mm
    });
    if (arm_marker && tr.occluded) || blocked || !facing {
        return ToolStatus::Missing;
    }
    if !sensors::in_volume(tr.volume, &p) {
        return ToolStatus::OutOfVolume;
    }
    let mut scaled = p.coords * (1.0 + eff.scale_ppm * 1e-6);
    scaled.z += p.z * eff.depth_scale_ppm * 1e-6;
    let los = scaled.normalize();
    let e1 = los
        .cross(&Vector3::x())
        .try_normalize(1e-9)
        .unwrap_or_else(|| los.cross(&Vector3::y()).normalize());
    let e2 = los.cross(&e1);
    let rng = &mut tr.rng;
    let noise = los * (eff.noise_depth_mm * normal(rng))
        + e1 * (eff.noise_lateral_mm * normal(rng))
        + e2 * (eff.noise_lateral_mm * normal(rng));
    let rot_sigma = eff.noise_rot_deg.to_radians();
    let drot = Vector3::new(normal(rng), normal(rng), normal(rng)) * rot_sigma;
    let rms = tr.cfg.fit_rms_mm * (1.0 + 0.2 * normal(rng).abs());
    let measured = Isometry3::from_parts(
        Translation3::from(scaled + noise),
        UnitQuaternion::from_scaled_axis(drot) * pose.rotation,
    );
    ToolStatus::Visible {
        pose: MarkerToTracker(measured),
        rms_mm: rms,
    }
}

impl World {
    /// What the operator does at world time `now` (`None` without an operator or before the
    /// script started).
    fn operator_act(&self, now: f64) -> Option<operator::Act> {
        let o = self.operator.as_ref()?;
        let t0 = o.t0?;
        // The probe faces the tracker; a script without a tracker only drags the arm.
        let origin = match o.tracker.and_then(|i| self.trackers.get(i)) {
            Some(tr) => Point3::from(
                tracker_in_base_at(tr.tracker_in_base, &tr.cfg.effects, now)
                    .translation
                    .vector,
            ),
            None => Point3::origin(),
        };
        Some(operator::act(
            &o.cfg,
            now - t0,
            &origin,
            |name| self.arms.iter().position(|a| a.name == name),
            |a| o.arm_start.get(a).cloned().unwrap_or_default(),
        ))
    }

    /// A dragged arm that follows the hand is where the hand holds it.
    fn apply_drag(&mut self, now: f64) {
        if let Some(operator::Act::Arm(a, q)) = self.operator_act(now) {
            if let Some(arm) = self.arms.get_mut(a) {
                if arm.follows_hand && !arm.protective_stop && q.len() == arm.motion.q_at(now).len()
                {
                    arm.motion = Move::hold(q, now);
                }
            }
        }
    }
}

/// Tracker placement at time `t` (after a base bump when one is configured).
pub fn tracker_in_base_at(
    tracker_in_base: Isometry3<f64>,
    eff: &TrackerEffects,
    t: f64,
) -> Isometry3<f64> {
    match &eff.base_bump {
        Some(b) if t >= b.t_s => {
            Isometry3::from_parts(
                Translation3::from(Vector3::from(b.shift_mm)),
                UnitQuaternion::identity(),
            ) * tracker_in_base
                * chain::fixed_transform_deg([0.0; 3], b.rot_deg)
        }
        _ => tracker_in_base,
    }
}

/// Beam origin and unit direction in the base frame for a flange pose.
pub fn laser_ray(flange: &Isometry3<f64>, cfg: &LaserConfig) -> (Point3<f64>, Vector3<f64>) {
    let o = flange * Point3::from(cfg.beam_origin_mm);
    let u = (flange.rotation * Vector3::from(cfg.beam_dir)).normalize();
    (o, u)
}
