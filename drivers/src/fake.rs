//! In-process `Fake*` devices for fast orchestration tests (no wire, no physics).
//!
//! `FakeArm` moves instantly and records every command it receives, so tests can assert what
//! reached the arm. `FakeTracker` and `FakeRange` return what the test sets (or a function of
//! the fake arm's joints). For physically honest simulation use the `robocal-mocks` world.

use crate::error::{DriverError, DriverResult, ErrorKind};
use crate::traits::*;
use async_trait::async_trait;
use nalgebra::Isometry3;
use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

/// One command the fake arm received.
#[derive(Debug, Clone, PartialEq)]
pub struct MoveCommand {
    /// Target (rad).
    pub target: Vec<f64>,
    /// Speed as received.
    pub speed: MoveSpeed,
}

type FlangeFn = dyn Fn(&[f64]) -> Isometry3<f64> + Send + Sync;

#[derive(Debug)]
struct ArmInner {
    q: Vec<f64>,
    log: Vec<MoveCommand>,
    faults: VecDeque<ErrorKind>,
    state: ArmState,
}

/// A fake arm that arrives instantly.
#[derive(Clone)]
pub struct FakeArm {
    inner: Arc<Mutex<ArmInner>>,
    flange: Arc<FlangeFn>,
}

impl std::fmt::Debug for FakeArm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FakeArm")
            .field("inner", &self.inner)
            .finish()
    }
}

impl FakeArm {
    /// A fake arm at `q0` (rad); the flange pose is the identity unless set with [`Self::with_flange`].
    pub fn new(q0: Vec<f64>) -> Self {
        Self {
            inner: Arc::new(Mutex::new(ArmInner {
                q: q0,
                log: Vec::new(),
                faults: VecDeque::new(),
                state: ArmState {
                    mode: ArmMode::Ready,
                    safety: SafetyState::Normal,
                },
            })),
            flange: Arc::new(|_| Isometry3::identity()),
        }
    }
    /// Use `f(q)` as the controller's flange pose.
    pub fn with_flange(
        mut self,
        f: impl Fn(&[f64]) -> Isometry3<f64> + Send + Sync + 'static,
    ) -> Self {
        self.flange = Arc::new(f);
        self
    }
    /// Every move command received so far.
    pub fn commands(&self) -> Vec<MoveCommand> {
        self.lock().log.clone()
    }
    /// Make the next move fail with `kind` (queued; one per call).
    pub fn fail_next_move(&self, kind: ErrorKind) {
        self.lock().faults.push_back(kind);
    }
    /// Set the safety state (e.g. a protective stop).
    pub fn set_safety(&self, safety: SafetyState) {
        self.lock().state.safety = safety;
    }
    /// Current joints (rad).
    pub fn q(&self) -> Vec<f64> {
        self.lock().q.clone()
    }
    fn lock(&self) -> std::sync::MutexGuard<'_, ArmInner> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }
}

#[async_trait]
impl JointReadout for FakeArm {
    async fn joints(&self) -> DriverResult<JointState> {
        let g = self.lock();
        Ok(JointState {
            q: g.q.clone(),
            qd: Some(vec![0.0; g.q.len()]),
            t: 0.0,
        })
    }
}

#[async_trait]
impl FlangePose for FakeArm {
    async fn flange_pose(&self) -> DriverResult<FlangeToBase> {
        let q = self.q();
        Ok(FlangeToBase((self.flange)(&q)))
    }
}

#[async_trait]
impl MoveJoints for FakeArm {
    fn dof(&self) -> usize {
        self.lock().q.len()
    }
    async fn move_joints(&self, target: &[f64], speed: MoveSpeed) -> DriverResult<()> {
        let mut g = self.lock();
        g.log.push(MoveCommand {
            target: target.to_vec(),
            speed,
        });
        if let Some(kind) = g.faults.pop_front() {
            return Err(DriverError::new(kind, "fake-arm", "injected fault"));
        }
        if g.state.safety == SafetyState::ProtectiveStop {
            return Err(DriverError::new(
                ErrorKind::SafetyStop,
                "fake-arm",
                "protective stop",
            ));
        }
        if target.len() != g.q.len() {
            return Err(DriverError::new(
                ErrorKind::InvalidArgument,
                "fake-arm",
                "wrong joint count",
            ));
        }
        g.q = target.to_vec();
        Ok(())
    }
    async fn stop(&self) -> DriverResult<()> {
        Ok(())
    }
}

#[async_trait]
impl ArmStatus for FakeArm {
    async fn state(&self) -> DriverResult<ArmState> {
        Ok(self.lock().state)
    }
    async fn recover(&self) -> DriverResult<()> {
        self.lock().state.safety = SafetyState::Normal;
        Ok(())
    }
}

type FrameFn = dyn Fn(u64) -> DriverResult<TrackerFrame> + Send + Sync;

/// A fake tracker returning `f(frame_number)`.
#[derive(Clone)]
pub struct FakeTracker {
    f: Arc<FrameFn>,
    counter: Arc<Mutex<u64>>,
}

impl FakeTracker {
    /// A tracker whose frames are produced by `f(frame_number)`.
    pub fn new(f: impl Fn(u64) -> DriverResult<TrackerFrame> + Send + Sync + 'static) -> Self {
        Self {
            f: Arc::new(f),
            counter: Arc::new(Mutex::new(0)),
        }
    }
}

#[async_trait]
impl MarkerTracker for FakeTracker {
    async fn frame(&self) -> DriverResult<TrackerFrame> {
        let n = {
            let mut c = self.counter.lock().unwrap_or_else(|e| e.into_inner());
            *c += 1;
            *c
        };
        (self.f)(n)
    }
}

/// A fake range sensor returning queued readings, then `default`.
#[derive(Clone)]
pub struct FakeRange {
    queue: Arc<Mutex<VecDeque<DriverResult<RangeReading>>>>,
    default: RangeReading,
}

impl FakeRange {
    /// A sensor that reads `default` unless readings were queued.
    pub fn new(default: RangeReading) -> Self {
        Self {
            queue: Arc::new(Mutex::new(VecDeque::new())),
            default,
        }
    }
    /// Queue one reading (or error) to return next.
    pub fn push(&self, r: DriverResult<RangeReading>) {
        self.queue
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push_back(r);
    }
}

#[async_trait]
impl RangeSensor for FakeRange {
    async fn read_range(&self) -> DriverResult<RangeReading> {
        let next = self
            .queue
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .pop_front();
        next.unwrap_or(Ok(self.default))
    }
}
