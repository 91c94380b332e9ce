//! The simulated operator: a scripted hand in the world that picks up a tracked probe, pivots
//! it in a divot, touches fiducials with a physiological tremor, and drags an arm (freedrive on
//! a UR, the teach pendant's hand-guiding on a DENSO). `robocal capture` is tested against it
//! over the real wire protocols; the truth (probe tip, divot, fiducials, taught joint poses) is
//! in the scenario's `[operator]` table and never goes over a wire.
//!
//! Time: the script starts at the first tracker frame or joint read after the world is built
//! (the operator starts when the tracker beeps), so a client that connects late does not miss
//! the first step. Steps run one after the other; after the last one the probe is put down (out
//! of view) and a dragged arm stays where it was left.
//!
//! Units: mm, degrees, seconds in the file; mm, rad, s inside.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use std::f64::consts::TAU;

/// `[operator]`: the person in the cell.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OperatorConfig {
    /// The tracker that sees the hand-held probe (empty: none, for a script that only drags
    /// the arm, e.g. a camera cell's hand-guided poses).
    #[serde(default)]
    pub tracker: String,
    /// Tool name the probe is reported under (its port handle order: after the tracker's
    /// arm marker).
    #[serde(default = "d_probe_tool")]
    pub probe_tool: String,
    /// TRUE tip of the probe in its marker frame (mm).
    pub probe_tip_mm: [f64; 3],
    /// Hand tremor while holding still, RMS per axis (mm); for a dragged arm, per joint (deg)
    /// is this divided by 1000.
    #[serde(default = "d_tremor")]
    pub tremor_mm: f64,
    /// The script, in order.
    #[serde(rename = "step")]
    pub steps: Vec<Step>,
}

fn d_probe_tool() -> String {
    "probe".into()
}
fn d_tremor() -> f64 {
    0.05
}

/// One thing the operator does.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum Step {
    /// Probe out of view (picking it up, walking over).
    Wait {
        /// Duration (s).
        seconds: f64,
    },
    /// Pivot the probe about its tip in a divot.
    Pivot {
        /// Divot in the robot base frame (mm).
        divot_mm: [f64; 3],
        /// Duration (s).
        seconds: f64,
        /// Largest tilt of the shaft from its mean axis (deg).
        cone_deg: f64,
        /// The divot slides (a divot that is not held still), mm/s in the base frame.
        #[serde(default)]
        drift_mm_s: [f64; 3],
    },
    /// Touch named points with the tip, holding still on each.
    Touch {
        /// The points, in order.
        points: Vec<NamedXyz>,
        /// Hold on each point (s).
        dwell_s: f64,
        /// Move between points (s), the tip lifted off the surface.
        move_s: f64,
    },
    /// Drag an arm through joint poses and hold each.
    Drag {
        /// The arm.
        arm: String,
        /// Joint poses (deg).
        poses_deg: Vec<Vec<f64>>,
        /// Move to each pose (s).
        move_s: f64,
        /// Hold at each pose (s).
        dwell_s: f64,
    },
}

/// A named point (mm, robot base frame).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NamedXyz {
    /// Name.
    pub name: String,
    /// Position (mm).
    pub xyz_mm: [f64; 3],
}

impl Step {
    /// Duration of the step (s).
    pub fn duration(&self) -> f64 {
        match self {
            Step::Wait { seconds } | Step::Pivot { seconds, .. } => *seconds,
            Step::Touch {
                points,
                dwell_s,
                move_s,
            } => points.len() as f64 * (dwell_s + move_s),
            Step::Drag {
                poses_deg,
                move_s,
                dwell_s,
                ..
            } => poses_deg.len() as f64 * (dwell_s + move_s),
        }
    }
}

impl OperatorConfig {
    /// Value checks: finite, positive durations, non-empty lists.
    pub fn validate(&self, arm_dof: impl Fn(&str) -> Option<usize>) -> Result<(), String> {
        if !(self.tremor_mm >= 0.0 && self.tremor_mm < 10.0) {
            return Err(format!(
                "operator.tremor_mm = {} (0 ≤ tremor < 10 mm)",
                self.tremor_mm
            ));
        }
        let tip = Vector3::from(self.probe_tip_mm);
        if !(tip.norm() > 10.0 && tip.norm() < 1000.0) {
            return Err("operator.probe_tip_mm: tip 10 – 1000 mm from the marker".into());
        }
        for (i, s) in self.steps.iter().enumerate() {
            let d = s.duration();
            if !(d > 0.0 && d < 86_400.0) {
                return Err(format!(
                    "operator.step[{i}]: duration {d} s (0 < d < 1 day)"
                ));
            }
            match s {
                Step::Pivot { cone_deg, .. } if !(*cone_deg > 0.0 && *cone_deg < 80.0) => {
                    return Err(format!(
                        "operator.step[{i}].cone_deg = {cone_deg} (0 – 80°)"
                    ));
                }
                Step::Touch {
                    dwell_s, move_s, ..
                }
                | Step::Drag {
                    dwell_s, move_s, ..
                } if !(*dwell_s > 0.0 && *move_s > 0.0) => {
                    return Err(format!(
                        "operator.step[{i}]: dwell_s and move_s must be positive"
                    ));
                }
                Step::Drag { arm, poses_deg, .. } => {
                    let Some(n) = arm_dof(arm) else {
                        return Err(format!("operator.step[{i}]: no arm named {arm:?}"));
                    };
                    if let Some(p) = poses_deg.iter().find(|p| p.len() != n) {
                        return Err(format!(
                            "operator.step[{i}]: pose {p:?} has {} values, arm {arm} has {n} joints",
                            p.len()
                        ));
                    }
                }
                _ => {}
            }
        }
        Ok(())
    }
}

/// What the operator does at one instant.
#[derive(Debug, Clone, PartialEq)]
pub enum Act {
    /// Nothing the sensors see.
    Idle,
    /// The probe's marker is at this pose in the base frame.
    Probe(Isometry3<f64>),
    /// Arm `arm` (index into the scenario's arms) is held at these joint angles (rad).
    Arm(usize, Vec<f64>),
}

/// Band-limited tremor: three sinusoids per axis at 4–11 Hz with fixed phases, unit RMS.
fn tremor(t: f64, axis: usize) -> f64 {
    const F: [[f64; 3]; 3] = [[4.3, 7.9, 10.7], [5.1, 8.3, 9.7], [4.7, 6.9, 11.3]];
    const P: [[f64; 3]; 3] = [[0.3, 2.1, 4.0], [1.7, 5.2, 0.9], [3.3, 0.4, 2.8]];
    let s: f64 = (0..3)
        .map(|k| (TAU * F[axis][k] * t + P[axis][k]).sin())
        .sum();
    // Three unit sinusoids have RMS sqrt(3/2).
    s / 1.5_f64.sqrt()
}

fn smooth(s: f64) -> f64 {
    let s = s.clamp(0.0, 1.0);
    0.5 - 0.5 * (std::f64::consts::PI * s).cos()
}

/// The marker orientation whose +z looks from `at` to the tracker, with the shaft (tip → marker)
/// along that direction.
fn facing(
    at: &Point3<f64>,
    tracker_origin: &Point3<f64>,
    tip: &Vector3<f64>,
) -> UnitQuaternion<f64> {
    let to_tracker = (tracker_origin - at).normalize();
    // The shaft in the marker frame points from the tip to the marker origin: −tip.
    let shaft_m = (-tip).normalize();
    UnitQuaternion::rotation_between(&shaft_m, &to_tracker).unwrap_or_else(|| {
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
    })
}

/// The operator at world time `t` (since the script started, `tau`).
pub fn act(
    cfg: &OperatorConfig,
    tau: f64,
    tracker_origin: &Point3<f64>,
    arm_index: impl Fn(&str) -> Option<usize>,
    arm_start: impl Fn(usize) -> Vec<f64>,
) -> Act {
    let tip = Vector3::from(cfg.probe_tip_mm);
    let mut t0 = 0.0;
    let mut last_drag: Option<(usize, Vec<f64>)> = None;
    for step in &cfg.steps {
        let d = step.duration();
        let local = tau - t0;
        if local < d {
            return step_act(
                cfg,
                step,
                local,
                tracker_origin,
                &tip,
                &arm_index,
                last_drag,
                &arm_start,
            );
        }
        if let Step::Drag { arm, poses_deg, .. } = step {
            if let (Some(a), Some(p)) = (arm_index(arm), poses_deg.last()) {
                last_drag = Some((a, p.iter().map(|d| d.to_radians()).collect()));
            }
        }
        t0 += d;
    }
    match last_drag {
        Some((a, q)) => Act::Arm(a, q),
        None => Act::Idle,
    }
}

#[allow(clippy::too_many_arguments)]
fn step_act(
    cfg: &OperatorConfig,
    step: &Step,
    local: f64,
    tracker_origin: &Point3<f64>,
    tip: &Vector3<f64>,
    arm_index: &impl Fn(&str) -> Option<usize>,
    last_drag: Option<(usize, Vec<f64>)>,
    arm_start: &impl Fn(usize) -> Vec<f64>,
) -> Act {
    match step {
        Step::Wait { .. } => Act::Idle,
        Step::Pivot {
            divot_mm,
            cone_deg,
            drift_mm_s,
            ..
        } => {
            let divot = Point3::from(*divot_mm) + Vector3::from(*drift_mm_s) * local;
            let r0 = facing(&divot, tracker_origin, tip);
            // Tilt sweeps the cone (azimuth every 2.9 s, tilt breathing every 7.3 s), with a
            // slow roll of the probe about its shaft.
            let tilt = cone_deg.to_radians() * (0.55 + 0.45 * (TAU * local / 7.3).sin());
            let az = TAU * local / 2.9;
            let shaft = r0 * (-tip).normalize();
            let e1 = shaft
                .cross(&Vector3::z())
                .try_normalize(1e-9)
                .unwrap_or_else(|| shaft.cross(&Vector3::x()).normalize());
            let e2 = shaft.cross(&e1);
            let axis = e1 * az.cos() + e2 * az.sin();
            let roll = 0.3 * (TAU * local / 5.1).sin();
            let r = UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(axis), tilt)
                * UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(shaft), roll)
                * r0;
            Act::Probe(marker_with_tip_at(&divot, r, tip))
        }
        Step::Touch {
            points,
            dwell_s,
            move_s,
        } => {
            let period = dwell_s + move_s;
            let k = ((local / period) as usize).min(points.len() - 1);
            let s = local - k as f64 * period;
            let here = Point3::from(points[k].xyz_mm);
            let (tip_at, target) = if s < *move_s {
                // Approach from the previous point (or from above), the tip lifted 30 mm.
                let from = if k == 0 {
                    here + Vector3::new(0.0, 0.0, 80.0)
                } else {
                    Point3::from(points[k - 1].xyz_mm)
                };
                let u = smooth(s / move_s);
                let lift = 30.0 * (std::f64::consts::PI * u).sin();
                (
                    from + (here - from) * u + Vector3::new(0.0, 0.0, lift),
                    here,
                )
            } else {
                let a = cfg.tremor_mm;
                let w = Vector3::new(tremor(s, 0), tremor(s, 1), tremor(s, 2)) * a;
                (here + w, here)
            };
            let r = facing(&target, tracker_origin, tip);
            Act::Probe(marker_with_tip_at(&tip_at, r, tip))
        }
        Step::Drag {
            arm,
            poses_deg,
            move_s,
            dwell_s,
        } => {
            let Some(a) = arm_index(arm) else {
                return Act::Idle;
            };
            let period = dwell_s + move_s;
            let k = ((local / period) as usize).min(poses_deg.len() - 1);
            let s = local - k as f64 * period;
            let to: Vec<f64> = poses_deg[k].iter().map(|d| d.to_radians()).collect();
            let from: Vec<f64> = if k == 0 {
                match last_drag {
                    Some((la, q)) if la == a => q,
                    _ => arm_start(a),
                }
            } else {
                poses_deg[k - 1].iter().map(|d| d.to_radians()).collect()
            };
            let q = if s < *move_s {
                let u = smooth(s / move_s);
                from.iter().zip(&to).map(|(f, t)| f + (t - f) * u).collect()
            } else {
                // The hand on a braked-free arm trembles a little.
                let a_rad = (cfg.tremor_mm / 1000.0).to_radians();
                to.iter()
                    .enumerate()
                    .map(|(j, x)| x + a_rad * tremor(s + j as f64 * 0.37, j % 3))
                    .collect()
            };
            Act::Arm(a, q)
        }
    }
}

fn marker_with_tip_at(
    tip_at: &Point3<f64>,
    r: UnitQuaternion<f64>,
    tip: &Vector3<f64>,
) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::from(tip_at.coords - r * tip), r)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(steps: Vec<Step>) -> OperatorConfig {
        OperatorConfig {
            tracker: "t".into(),
            probe_tool: "probe".into(),
            probe_tip_mm: [1.0, -2.0, -160.0],
            tremor_mm: 0.05,
            steps,
        }
    }

    #[test]
    fn pivot_keeps_the_tip_in_the_divot_and_tilts() {
        let c = cfg(vec![Step::Pivot {
            divot_mm: [500.0, 0.0, 200.0],
            seconds: 10.0,
            cone_deg: 30.0,
            drift_mm_s: [0.0; 3],
        }]);
        let tracker = Point3::new(1700.0, 80.0, 650.0);
        let mut axes = Vec::new();
        for i in 0..100 {
            let Act::Probe(m) = act(&c, i as f64 * 0.1, &tracker, |_| None, |_| vec![]) else {
                panic!("no probe");
            };
            let tip_at = m * Point3::from(c.probe_tip_mm);
            assert!((tip_at - Point3::new(500.0, 0.0, 200.0)).norm() < 1e-9);
            axes.push(m.rotation * Vector3::z());
        }
        let max = axes
            .iter()
            .map(|a| a.angle(&axes[0]).to_degrees())
            .fold(0.0, f64::max);
        assert!(max > 20.0 && max < 65.0, "tilt range {max}");
        assert_eq!(act(&c, 11.0, &tracker, |_| None, |_| vec![]), Act::Idle);
    }

    #[test]
    fn touch_holds_each_point_within_tremor() {
        let c = cfg(vec![Step::Touch {
            points: vec![
                NamedXyz {
                    name: "F1".into(),
                    xyz_mm: [500.0, 0.0, 100.0],
                },
                NamedXyz {
                    name: "F2".into(),
                    xyz_mm: [520.0, 40.0, 110.0],
                },
            ],
            dwell_s: 2.0,
            move_s: 1.0,
        }]);
        let tracker = Point3::new(1700.0, 80.0, 650.0);
        let mut sum = Vector3::zeros();
        let n = 600;
        for i in 0..n {
            let t = 4.0 + 2.0 * i as f64 / n as f64;
            let Act::Probe(m) = act(&c, t, &tracker, |_| None, |_| vec![]) else {
                panic!()
            };
            let d = m * Point3::from(c.probe_tip_mm) - Point3::new(520.0, 40.0, 110.0);
            assert!(d.norm() < 0.3, "{d}");
            sum += d;
        }
        assert!((sum / n as f64).norm() < 0.01);
    }
}
