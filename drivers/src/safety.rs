//! Safety decorators that wrap ANY arm, whichever vendor is underneath.
//!
//! - [`JointLimiter`]: rejects targets outside the joint limits (or non-finite, wrong length).
//! - [`SpeedLimiter`]: clamps the requested speed / acceleration to the configured caps.
//! - [`EnvelopeGuard`]: checks the whole interpolated joint path (not only the end point)
//!   against a Cartesian envelope (box or cylinder) and a table plane, using points on the arm
//!   given by an [`ArmGeometry`] (built by the caller from its kinematic model).
//!
//! [`guard`] composes all three. A refused command fails with
//! [`ErrorKind::SafetyViolation`](crate::error::ErrorKind::SafetyViolation) and never reaches the
//! wrapped arm. The same pure check, [`check_move`], is used by the planner before anything moves.

use crate::error::{DriverError, DriverResult, ErrorKind};
use crate::traits::{
    ArmState, ArmStatus, FlangePose, FlangeToBase, JointReadout, JointState, MoveJoints, MoveSpeed,
};
use crate::Arm;
use async_trait::async_trait;
use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// A Cartesian envelope in the robot base frame (mm). Points on the arm must stay inside.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "shape", rename_all = "lowercase", deny_unknown_fields)]
pub enum Envelope {
    /// Axis-aligned box.
    Box {
        /// Lower corner (mm).
        min: [f64; 3],
        /// Upper corner (mm).
        max: [f64; 3],
    },
    /// Vertical cylinder about `center_xy`.
    Cylinder {
        /// Axis position (mm).
        center_xy: [f64; 2],
        /// Radius (mm).
        radius: f64,
        /// Lowest allowed z (mm).
        z_min: f64,
        /// Highest allowed z (mm).
        z_max: f64,
    },
}

impl Envelope {
    /// Whether `p` (mm, base frame) is inside.
    pub fn contains(&self, p: &Point3<f64>) -> bool {
        match self {
            Envelope::Box { min, max } => (0..3).all(|i| p[i] >= min[i] && p[i] <= max[i]),
            Envelope::Cylinder {
                center_xy,
                radius,
                z_min,
                z_max,
            } => {
                let dx = p.x - center_xy[0];
                let dy = p.y - center_xy[1];
                dx * dx + dy * dy <= radius * radius && p.z >= *z_min && p.z <= *z_max
            }
        }
    }
}

/// A table (or any forbidden half-space): points must stay on the `normal` side, at least
/// `clearance_mm` away from the plane.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TablePlane {
    /// A point on the plane (mm, base frame).
    pub point: [f64; 3],
    /// Normal pointing to the allowed side.
    pub normal: [f64; 3],
    /// Required distance above the plane (mm).
    #[serde(default)]
    pub clearance_mm: f64,
}

impl TablePlane {
    /// Signed height of `p` above the plane minus the clearance (≥ 0 is allowed).
    pub fn margin(&self, p: &Point3<f64>) -> f64 {
        let n = Vector3::from(self.normal);
        let norm = n.norm();
        if norm.is_nan() || norm <= 0.0 {
            return f64::NEG_INFINITY;
        }
        (p - Point3::from(self.point)).dot(&(n / norm)) - self.clearance_mm
    }
}

/// Every limit the safety decorators enforce.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SafetyLimits {
    /// Lower joint limits (rad).
    pub joint_lower: Vec<f64>,
    /// Upper joint limits (rad).
    pub joint_upper: Vec<f64>,
    /// Joint speed cap (rad/s).
    pub max_vel: f64,
    /// Joint acceleration cap (rad/s²).
    pub max_acc: f64,
    /// Cartesian envelope, if any.
    #[serde(default)]
    pub envelope: Option<Envelope>,
    /// Table plane, if any.
    #[serde(default)]
    pub table: Option<TablePlane>,
    /// Joint-space step for the path check (rad); default 1°.
    #[serde(default = "default_step")]
    pub path_step: f64,
}

fn default_step() -> f64 {
    1f64.to_radians()
}

/// Points on the arm (mm, base frame) that must satisfy the envelope and table, for joints `q` (rad).
/// Typically the wrist centre, the flange and the tool tip.
pub trait ArmGeometry: Send + Sync {
    /// The check points for `q`.
    fn check_points(&self, q: &[f64]) -> Vec<Point3<f64>>;
}

impl<F: Fn(&[f64]) -> Vec<Point3<f64>> + Send + Sync> ArmGeometry for F {
    fn check_points(&self, q: &[f64]) -> Vec<Point3<f64>> {
        self(q)
    }
}

/// Why a motion was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum Violation {
    /// The target has the wrong number of joints.
    #[error("target has {got} joints, the arm has {expected}")]
    DofMismatch {
        /// Expected count.
        expected: usize,
        /// Given count.
        got: usize,
    },
    /// A non-finite joint value.
    #[error("joint {joint} target is not finite")]
    NonFinite {
        /// 1-based joint.
        joint: usize,
    },
    /// A joint outside its limits.
    #[error("joint {joint} target {value_deg:.3}° is outside [{lower_deg:.3}°, {upper_deg:.3}°]")]
    JointLimit {
        /// 1-based joint.
        joint: usize,
        /// Target (deg).
        value_deg: f64,
        /// Lower limit (deg).
        lower_deg: f64,
        /// Upper limit (deg).
        upper_deg: f64,
    },
    /// A point on the arm leaves the envelope along the path.
    #[error(
        "path leaves the envelope at {fraction:.3} of the move: point ({x:.1}, {y:.1}, {z:.1}) mm"
    )]
    Envelope {
        /// Where along the move (0 = start, 1 = end).
        fraction: f64,
        /// Offending point (mm).
        x: f64,
        /// Offending point (mm).
        y: f64,
        /// Offending point (mm).
        z: f64,
    },
    /// A point on the arm comes too close to / below the table.
    #[error("path comes {margin_mm:.1} mm past the table clearance at {fraction:.3} of the move")]
    Table {
        /// Where along the move.
        fraction: f64,
        /// Negative margin (mm).
        margin_mm: f64,
    },
}

/// Check the joint-interpolated move `from → to` against `limits` (pure; no I/O).
pub fn check_move(
    limits: &SafetyLimits,
    geometry: Option<&dyn ArmGeometry>,
    from: Option<&[f64]>,
    to: &[f64],
) -> Result<(), Violation> {
    check_target(limits, to)?;
    let Some(geom) = geometry else {
        return Ok(());
    };
    if limits.envelope.is_none() && limits.table.is_none() {
        return Ok(());
    }
    let from = match from {
        Some(f) if f.len() == to.len() && f.iter().all(|x| x.is_finite()) => f,
        _ => to,
    };
    let max_delta = from
        .iter()
        .zip(to)
        .map(|(a, b)| (b - a).abs())
        .fold(0.0, f64::max);
    let step = if limits.path_step > 0.0 {
        limits.path_step
    } else {
        default_step()
    };
    let n = ((max_delta / step).ceil() as usize).clamp(1, 100_000);
    let mut q = vec![0.0; to.len()];
    for k in 0..=n {
        let s = k as f64 / n as f64;
        for (i, qi) in q.iter_mut().enumerate() {
            *qi = from[i] + s * (to[i] - from[i]);
        }
        for p in geom.check_points(&q) {
            if let Some(env) = &limits.envelope {
                if !env.contains(&p) {
                    return Err(Violation::Envelope {
                        fraction: s,
                        x: p.x,
                        y: p.y,
                        z: p.z,
                    });
                }
            }
            if let Some(table) = &limits.table {
                let m = table.margin(&p);
                if m < 0.0 {
                    return Err(Violation::Table {
                        fraction: s,
                        margin_mm: m,
                    });
                }
            }
        }
    }
    Ok(())
}

/// Check only the joint target (count, finiteness, limits).
pub fn check_target(limits: &SafetyLimits, to: &[f64]) -> Result<(), Violation> {
    let dof = limits.joint_lower.len().min(limits.joint_upper.len());
    if to.len() != dof {
        return Err(Violation::DofMismatch {
            expected: dof,
            got: to.len(),
        });
    }
    for (i, &v) in to.iter().enumerate() {
        if !v.is_finite() {
            return Err(Violation::NonFinite { joint: i + 1 });
        }
        let (lo, hi) = (limits.joint_lower[i], limits.joint_upper[i]);
        if v < lo || v > hi {
            return Err(Violation::JointLimit {
                joint: i + 1,
                value_deg: v.to_degrees(),
                lower_deg: lo.to_degrees(),
                upper_deg: hi.to_degrees(),
            });
        }
    }
    Ok(())
}

fn refused(v: Violation) -> DriverError {
    DriverError::new(ErrorKind::SafetyViolation, "safety", v.to_string())
}

macro_rules! delegate_reads {
    ($ty:ident) => {
        #[async_trait]
        impl<A: Arm + ?Sized> JointReadout for $ty<A> {
            async fn joints(&self) -> DriverResult<JointState> {
                self.inner.joints().await
            }
        }
        #[async_trait]
        impl<A: Arm + ?Sized> FlangePose for $ty<A> {
            async fn flange_pose(&self) -> DriverResult<FlangeToBase> {
                self.inner.flange_pose().await
            }
        }
        #[async_trait]
        impl<A: Arm + ?Sized> ArmStatus for $ty<A> {
            async fn state(&self) -> DriverResult<ArmState> {
                self.inner.state().await
            }
            async fn recover(&self) -> DriverResult<()> {
                self.inner.recover().await
            }
            fn link_recoveries(&self) -> u64 {
                self.inner.link_recoveries()
            }
        }
    };
}

/// Rejects joint targets outside the limits.
pub struct JointLimiter<A: ?Sized> {
    limits: Arc<SafetyLimits>,
    inner: Arc<A>,
}

impl<A: Arm + ?Sized> JointLimiter<A> {
    /// Wrap `inner`.
    pub fn new(inner: Arc<A>, limits: Arc<SafetyLimits>) -> Self {
        Self { limits, inner }
    }
}

delegate_reads!(JointLimiter);

#[async_trait]
impl<A: Arm + ?Sized> MoveJoints for JointLimiter<A> {
    fn dof(&self) -> usize {
        self.inner.dof()
    }
    async fn move_joints(&self, target: &[f64], speed: MoveSpeed) -> DriverResult<()> {
        check_target(&self.limits, target).map_err(refused)?;
        self.inner.move_joints(target, speed).await
    }
    async fn stop(&self) -> DriverResult<()> {
        self.inner.stop().await
    }
}

/// Clamps speed and acceleration to the caps (never forwards a faster command).
pub struct SpeedLimiter<A: ?Sized> {
    limits: Arc<SafetyLimits>,
    inner: Arc<A>,
}

impl<A: Arm + ?Sized> SpeedLimiter<A> {
    /// Wrap `inner`.
    pub fn new(inner: Arc<A>, limits: Arc<SafetyLimits>) -> Self {
        Self { limits, inner }
    }
}

delegate_reads!(SpeedLimiter);

#[async_trait]
impl<A: Arm + ?Sized> MoveJoints for SpeedLimiter<A> {
    fn dof(&self) -> usize {
        self.inner.dof()
    }
    async fn move_joints(&self, target: &[f64], speed: MoveSpeed) -> DriverResult<()> {
        let clamp = |v: f64, cap: f64| {
            if v.is_finite() && v > 0.0 {
                v.min(cap)
            } else {
                cap
            }
        };
        let speed = MoveSpeed {
            max_vel: clamp(speed.max_vel, self.limits.max_vel),
            max_acc: clamp(speed.max_acc, self.limits.max_acc),
        };
        self.inner.move_joints(target, speed).await
    }
    async fn stop(&self) -> DriverResult<()> {
        self.inner.stop().await
    }
}

/// Checks the interpolated joint path against the envelope and the table.
pub struct EnvelopeGuard<A: ?Sized> {
    limits: Arc<SafetyLimits>,
    geometry: Arc<dyn ArmGeometry>,
    inner: Arc<A>,
}

impl<A: Arm + ?Sized> EnvelopeGuard<A> {
    /// Wrap `inner`; `geometry` gives the points on the arm to check.
    pub fn new(inner: Arc<A>, limits: Arc<SafetyLimits>, geometry: Arc<dyn ArmGeometry>) -> Self {
        Self {
            limits,
            geometry,
            inner,
        }
    }
}

delegate_reads!(EnvelopeGuard);

#[async_trait]
impl<A: Arm + ?Sized> MoveJoints for EnvelopeGuard<A> {
    fn dof(&self) -> usize {
        self.inner.dof()
    }
    async fn move_joints(&self, target: &[f64], speed: MoveSpeed) -> DriverResult<()> {
        // The path starts where the arm really is: read it, never assume.
        let from = self.inner.joints().await?;
        check_move(
            &self.limits,
            Some(self.geometry.as_ref()),
            Some(&from.q),
            target,
        )
        .map_err(refused)?;
        self.inner.move_joints(target, speed).await
    }
    async fn stop(&self) -> DriverResult<()> {
        self.inner.stop().await
    }
}

/// Wrap `arm` in all three decorators: joint limits, then speed cap, then the path envelope.
pub fn guard(
    arm: Arc<dyn Arm>,
    limits: SafetyLimits,
    geometry: Option<Arc<dyn ArmGeometry>>,
) -> Arc<dyn Arm> {
    let limits = Arc::new(limits);
    let inner: Arc<dyn Arm> = match geometry {
        Some(g) => Arc::new(EnvelopeGuard::new(arm, limits.clone(), g)),
        None => arm,
    };
    let inner: Arc<dyn Arm> = Arc::new(SpeedLimiter::new(inner, limits.clone()));
    Arc::new(JointLimiter::new(inner, limits))
}
