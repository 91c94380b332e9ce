//! Serde types of the dataset header, records and the calibration file.
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

/// One joint of the URDF-style nominal chain in a dataset header (mm, degrees).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ChainJoint {
    pub name: String,
    /// Fixed translation from the previous joint frame (mm).
    pub origin_xyz: [f64; 3],
    /// Fixed URDF roll-pitch-yaw (deg, fixed axes X then Y then Z).
    pub origin_rpy: [f64; 3],
    /// Joint axis in the joint frame (unit vector).
    pub axis: [f64; 3],
    /// Joint limits (deg), when known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub limits: Option<[f64; 2]>,
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// Fixed transform from the last joint frame to the flange (mm, degrees).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct FixedOrigin {
    pub origin_xyz: [f64; 3],
    pub origin_rpy: [f64; 3],
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// The header's `robot` block.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RobotBlock {
    /// A preset name (`denso-vs060`, `ur5e`, `ur10e`) or free text when `chain` is given.
    pub model: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub serial: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub chain: Option<Vec<ChainJoint>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flange: Option<FixedOrigin>,
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// Line 1 of a dataset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// Always `robocal-dataset/1`.
    pub format: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub created: Option<String>,
    pub robot: RobotBlock,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tool: Option<Value>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tracker: Option<Value>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub range_sensor: Option<Value>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plan: Option<Value>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub notes: Option<String>,
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// A pose in a file: position (mm) and unit quaternion `[w, x, y, z]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FilePose {
    pub p: [f64; 3],
    pub quat: [f64; 4],
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// A tracked marker as recorded (tracker frame).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MarkerObs {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub p: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub quat: Option<[f64; 4]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rms: Option<f64>,
    #[serde(default = "default_true")]
    pub visible: bool,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames: Option<u32>,
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

fn default_true() -> bool {
    true
}

/// A `pose` record.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PoseRecord {
    pub id: u64,
    pub t: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub point: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub branch: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub group: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub q_cmd: Option<Vec<f64>>,
    /// Measured joints (deg). Absent only for records that carry a `flange` pose instead.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub q: Option<Vec<f64>>,
    /// Joints (deg) the move into this pose started from (its approach direction per joint
    /// is `sign(q − q_prev)`; backlash needs it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub q_prev: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flange: Option<FilePose>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub marker: Option<MarkerObs>,
    /// A reference body fixed in the cell, re-measured by the same tracker at this pose
    /// (tracker frame, same shape as `marker`). When a dataset's poses carry it, the
    /// kinematic observation builders re-express `marker` in this body's frame, which
    /// removes tracker drift (the tracker moving in the cell during the session).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference: Option<MarkerObs>,
    /// Laser range (mm); `Some(None)` = recorded as `null` (out of range).
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        with = "serde_with_null"
    )]
    pub range: Option<Option<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub temp_c: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plane: Option<String>,
    #[serde(rename = "move", default, skip_serializing_if = "Option::is_none")]
    pub move_kind: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub image: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub corners: Option<Vec<[f64; 2]>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tip: Option<Value>,
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// A `pivot` record.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PivotRecord {
    pub t: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tool: Option<String>,
    pub marker: MarkerObs,
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// An `event` record (`what` is one of skip, retry, fault, resume, pause, note).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EventRecord {
    pub t: f64,
    pub what: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub id: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// Any record line after the header.
// Pose records dominate every dataset; boxing them would only add an allocation each.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Record {
    Pose(PoseRecord),
    Pivot(PivotRecord),
    Event(EventRecord),
}

/// A whole dataset in memory.
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset {
    pub header: Header,
    pub records: Vec<Record>,
}

impl Dataset {
    /// All `pose` records in file order.
    pub fn poses(&self) -> impl Iterator<Item = &PoseRecord> {
        self.records.iter().filter_map(|r| match r {
            Record::Pose(p) => Some(p),
            _ => None,
        })
    }
    /// `pose` records whose `group` equals `group`.
    pub fn poses_in<'a>(&'a self, group: &'a str) -> impl Iterator<Item = &'a PoseRecord> + 'a {
        self.poses()
            .filter(move |p| p.group.as_deref() == Some(group))
    }
}

/// One parameter in a calibration file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalParam {
    pub name: String,
    pub value: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub std: Option<f64>,
    pub unit: String,
    pub free: bool,
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// One modelled physical effect in a calibration file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalEffect {
    pub kind: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub joint: Option<usize>,
    #[serde(default)]
    pub params: Map<String, Value>,
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// Per-joint range (degrees) of the training poses of a calibration's effects.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalJointRange {
    pub min_deg: Vec<f64>,
    pub max_deg: Vec<f64>,
}

/// `robocal-calibration/1`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationFile {
    /// Always `robocal-calibration/1`.
    pub format: String,
    pub robot: RobotBlock,
    pub params: Vec<CalParam>,
    #[serde(default)]
    pub effects: Vec<CalEffect>,
    /// The training poses' joint ranges the effects were fitted on (absent in older files):
    /// prediction holds the effects at the edge of these ranges.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub effects_joint_range: Option<CalJointRange>,
    #[serde(default)]
    pub metrics: Map<String, Value>,
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// `range: null` must stay distinguishable from an absent `range`.
mod serde_with_null {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};
    pub fn serialize<S: Serializer>(v: &Option<Option<f64>>, s: S) -> Result<S::Ok, S::Error> {
        match v {
            Some(inner) => inner.serialize(s),
            None => s.serialize_none(),
        }
    }
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<Option<f64>>, D::Error> {
        Ok(Some(Option::<f64>::deserialize(d)?))
    }
}
