//! `PLAN.json` (`robocal-plan/1`): what the acquisition engine consumes. Units mm / deg.
//!
//! ```json
//! {"format": "robocal-plan/1", "name": "seed001-annulus",
//!  "robot": {"model": "denso-vs060"},
//!  "tool": {"p": [0, 0, 100], "quat": [1, 0, 0, 0]},
//!  "spec": { ... the TOML spec as JSON ... },
//!  "poses": [{"id": 0, "point": 17, "branch": 3, "label": "A018",
//!             "branch_label": "shoulder-right/elbow-down/wrist-flip",
//!             "q_deg": [..], "flange": {"p": [..], "quat": [w, x, y, z]},
//!             "group": "train", "plane": "P1", "move": "translate", "block": 4}],
//!  "summary": { ... }}
//! ```
//! Poses are listed in acquisition order (`id` = 0, 1, 2, …).
use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

use super::observe::Observability;
use super::PlanError;
use crate::dataset::RobotBlock;
use crate::model::KinematicModel;

/// Plan file format tag.
pub use crate::schema::PLAN_FORMAT;

/// A pose in a file: position (mm) and unit quaternion `[w, x, y, z]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlanFilePose {
    pub p: [f64; 3],
    pub quat: [f64; 4],
}

impl PlanFilePose {
    /// From an isometry (mm).
    pub fn from_iso(iso: &Isometry3<f64>) -> Self {
        let t = iso.translation.vector;
        let q = iso.rotation.quaternion();
        PlanFilePose {
            p: [t.x, t.y, t.z],
            quat: [q.w, q.i, q.j, q.k],
        }
    }
    /// To an isometry; `None` when not finite or not (nearly) unit.
    pub fn to_iso(&self) -> Option<Isometry3<f64>> {
        crate::plausible::quat::pose(&self.p, &self.quat).ok()
    }
}

/// One planned pose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlanPose {
    /// Acquisition order, 0-based.
    pub id: u64,
    /// Target number (several IK branches may share it).
    pub point: u64,
    /// IK branch number (`4·shoulder + 2·elbow + wrist`).
    pub branch: u8,
    /// Human label of the target (`A017`, `P1-b03-T2`, …).
    pub label: String,
    /// Branch name (`shoulder-right/elbow-up/wrist-noflip`).
    #[serde(default)]
    pub branch_label: String,
    /// Joint targets (deg).
    pub q_deg: Vec<f64>,
    /// Nominal flange pose in the robot base.
    pub flange: PlanFilePose,
    pub group: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plane: Option<String>,
    #[serde(rename = "move", default, skip_serializing_if = "Option::is_none")]
    pub move_kind: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub block: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target: Option<String>,
}

/// A rejected target or IK branch, and why.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RejectedPose {
    pub point: u64,
    pub label: String,
    /// Absent when the whole target was rejected (unreachable, tracker, laser, …).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub branch: Option<u8>,
    /// Reason key (as counted in the summary).
    pub reason: String,
    /// Human-readable detail.
    pub detail: String,
}

/// Session-time figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimingSummary {
    /// Generated (unordered) sequence: seconds and poses per hour.
    pub generated_s: f64,
    pub generated_poses_per_hour: f64,
    /// Optimised order (the order of `poses`).
    pub optimised_s: f64,
    pub optimised_poses_per_hour: f64,
}

/// Result of `--select N`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SelectSummary {
    pub requested: usize,
    pub all: Observability,
    pub selected: Observability,
    /// Smallest greedy prefix whose O1 reaches the full set's O1 (if any).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub poses_to_reach_full_o1: Option<usize>,
}

/// Plan summary (also printed by `robocal plan --json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlanSummary {
    pub name: String,
    /// Targets generated.
    pub targets: usize,
    /// Target × branch combinations examined (unreachable targets count once).
    pub examined: usize,
    /// Feasible poses kept.
    pub feasible: usize,
    /// Feasible poses per IK branch label.
    pub per_branch: BTreeMap<String, usize>,
    /// Rejections counted by reason key.
    pub rejects: BTreeMap<String, usize>,
    /// Consecutive moves of the final order that the safety path check refuses.
    #[serde(default)]
    pub path_violations: usize,
    pub timing: TimingSummary,
    pub observability: Observability,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub select: Option<SelectSummary>,
    #[serde(default)]
    pub warnings: Vec<String>,
}

/// The whole plan file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlanFile {
    pub format: String,
    pub name: String,
    pub robot: RobotBlock,
    /// The tool (sensor / marker) in the flange frame.
    pub tool: PlanFilePose,
    /// The spec the plan was generated from.
    pub spec: serde_json::Value,
    pub poses: Vec<PlanPose>,
    /// Every rejection, in generation order.
    #[serde(default)]
    pub rejected: Vec<RejectedPose>,
    pub summary: PlanSummary,
}

impl PlanFile {
    /// Parse and validate a plan (see [`PlanFile::validate`]).
    pub fn from_json_str(s: &str) -> Result<Self, PlanError> {
        let f: PlanFile = serde_json::from_str(s).map_err(|e| PlanError::PlanFile {
            message: crate::schema::kind::with_other_kind(&e, s, crate::schema::PLAN_FORMAT),
        })?;
        f.validate()?;
        Ok(f)
    }

    /// Read and validate a plan file.
    pub fn read(path: &std::path::Path) -> Result<Self, PlanError> {
        let s = crate::fsio::read_to_string(path).map_err(|e| PlanError::Io {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
        Self::from_json_str(&s)
    }

    /// Format tag, ids 0..n in order, finite joints of the robot's dof within its limits,
    /// unit quaternions, and a flange pose that matches the robot's nominal forward
    /// kinematics of `q_deg` (0.01 mm / 0.001°).
    pub fn validate(&self) -> Result<(), PlanError> {
        let err = |m: String| Err(PlanError::PlanFile { message: m });
        if self.format != PLAN_FORMAT {
            return err(format!("format `{}` is not `{PLAN_FORMAT}`", self.format));
        }
        if self.tool.to_iso().is_none() {
            return err("tool pose is not finite / not a unit quaternion".into());
        }
        let model =
            KinematicModel::from_robot_block(&self.robot).map_err(|e| PlanError::PlanFile {
                message: format!("robot: {e}"),
            })?;
        let limits = model.joint_limits();
        for (k, p) in self.poses.iter().enumerate() {
            if p.id != k as u64 {
                return err(format!("pose {k}: id {} out of sequence", p.id));
            }
            if p.q_deg.len() != model.dof() {
                return err(format!(
                    "pose {k}: {} joints, robot has {}",
                    p.q_deg.len(),
                    model.dof()
                ));
            }
            if !p.q_deg.iter().all(|x| x.is_finite()) {
                return err(format!("pose {k}: q_deg is not finite"));
            }
            let q: Vec<f64> = p.q_deg.iter().map(|x| x.to_radians()).collect();
            for (i, (&x, &(lo, hi))) in q.iter().zip(&limits).enumerate() {
                if x < lo - 1e-9 || x > hi + 1e-9 {
                    return err(format!(
                        "pose {k}: joint {} = {:.3}° outside its limits",
                        i + 1,
                        p.q_deg[i]
                    ));
                }
            }
            let Some(fl) = p.flange.to_iso() else {
                return err(format!(
                    "pose {k}: flange pose is not finite / not a unit quaternion"
                ));
            };
            let fk = model.flange_pose(&q);
            let (dp, dr) = crate::model::pose_distance(&fk, &fl);
            if dp > 0.01 || dr > 0.001f64.to_radians() {
                return err(format!(
                    "pose {k}: flange differs from the forward kinematics of q_deg by {dp:.3} mm / {:.4}°",
                    dr.to_degrees()
                ));
            }
        }
        Ok(())
    }
}

/// Serde for an `f64` that may be non-finite (a condition number of an unobservable set is
/// infinite): finite values are JSON numbers, `+∞`/`−∞`/NaN the strings `"inf"`, `"-inf"`,
/// `"nan"` (JSON has no such numbers and `serde_json` would write `null`). Reading also
/// accepts `null` as `+∞`, which is what plan files written before this fix hold.
pub mod nonfinite_f64 {
    use serde::{de, Deserializer, Serializer};

    /// Writes `v`.
    pub fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        if v.is_finite() {
            s.serialize_f64(*v)
        } else if v.is_nan() {
            s.serialize_str("nan")
        } else if *v > 0.0 {
            s.serialize_str("inf")
        } else {
            s.serialize_str("-inf")
        }
    }

    struct V;

    impl de::Visitor<'_> for V {
        type Value = f64;
        fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str(r#"a number, "inf", "-inf" or "nan""#)
        }
        fn visit_f64<E: de::Error>(self, v: f64) -> Result<f64, E> {
            Ok(v)
        }
        fn visit_i64<E: de::Error>(self, v: i64) -> Result<f64, E> {
            Ok(v as f64)
        }
        fn visit_u64<E: de::Error>(self, v: u64) -> Result<f64, E> {
            Ok(v as f64)
        }
        fn visit_unit<E: de::Error>(self) -> Result<f64, E> {
            Ok(f64::INFINITY)
        }
        fn visit_none<E: de::Error>(self) -> Result<f64, E> {
            Ok(f64::INFINITY)
        }
        fn visit_str<E: de::Error>(self, v: &str) -> Result<f64, E> {
            match v.trim().to_ascii_lowercase().as_str() {
                "inf" | "+inf" | "infinity" => Ok(f64::INFINITY),
                "-inf" | "-infinity" => Ok(f64::NEG_INFINITY),
                "nan" => Ok(f64::NAN),
                _ => Err(E::invalid_value(de::Unexpected::Str(v), &self)),
            }
        }
    }

    /// Reads a number, `"inf"`, `"-inf"`, `"nan"` or `null` (= `+∞`).
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        d.deserialize_any(V)
    }
}

#[cfg(test)]
mod nonfinite_tests {
    use super::super::observe::Observability;

    fn obs(condition: f64) -> Observability {
        Observability {
            poses: 2,
            params: 3,
            o1: 0.0,
            condition,
            sigma_max: 1.0,
            sigma_min: 0.0,
            unidentifiable: vec![],
        }
    }

    /// An infinite condition number (too few poses) round-trips through JSON; `null` (what
    /// older plan files hold) reads as infinite.
    #[test]
    fn infinite_condition_round_trips() {
        let o = obs(f64::INFINITY);
        let text = serde_json::to_string(&o).unwrap();
        assert!(text.contains(r#""condition":"inf""#), "{text}");
        let back: Observability = serde_json::from_str(&text).unwrap();
        assert_eq!(back, o);
        let old = text.replace(r#""inf""#, "null");
        let back: Observability = serde_json::from_str(&old).unwrap();
        assert!(back.condition.is_infinite());
        let fin = obs(12.5);
        let back: Observability =
            serde_json::from_str(&serde_json::to_string(&fin).unwrap()).unwrap();
        assert_eq!(back, fin);
        assert!(serde_json::from_str::<Observability>(&text.replace("inf", "big")).is_err());
    }
}
