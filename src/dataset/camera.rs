//! The camera parts of the file contract (`docs/dataset-format.md`): the dataset header's
//! `camera` and `target` blocks and the calibration file's `camera` block. Both live in the
//! `extra` maps of [`Header`] / [`CalibrationFile`] (a header without them is still a valid
//! dataset); these typed views are what writers and readers use.
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::types::{CalibrationFile, Header};

/// Header `camera`: `{"kind": "mono", "width": W, "height": H}`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraHeader {
    /// Only `mono` so far.
    pub kind: String,
    /// Image size (px).
    pub width: u32,
    pub height: u32,
    /// Device name, when known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// `flange` (eye-in-hand, the default) or `base` (eye-to-hand).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mount: Option<String>,
}

/// Header `target`: the calibration board. `cols × rows` are INNER corners.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetHeader {
    /// `chessboard` or `charuco`.
    pub kind: String,
    pub cols: u32,
    pub rows: u32,
    /// Square edge (mm).
    pub square_mm: f64,
    /// ChArUco: marker edge (mm) and dictionary.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub marker_mm: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dictionary: Option<String>,
}

/// A pose with its uncertainty (file units).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseWithStd {
    pub xyz_mm: [f64; 3],
    /// `[w, x, y, z]`.
    pub quat: [f64; 4],
    /// 1σ of the translation (mm, along the parent frame's x, y, z) and of the rotation (deg,
    /// small rotations about the pose's own x, y, z axes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub std_mm: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub std_deg: Option<[f64; 3]>,
}

/// Calibration `camera.intrinsics`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IntrinsicsBlock {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// `[k1, k2, p1, p2, k3]` (OpenCV).
    pub dist: [f64; 5],
    pub width: u32,
    pub height: u32,
    /// Distortion model chosen (`none`, `k1`, `k1-k2`, `k1-k2-p1-p2`, `k1-k2-p1-p2-k3`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<String>,
    /// 1σ of `[fx, fy, cx, cy, k1, k2, p1, p2, k3]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub std: Option<[f64; 9]>,
}

/// Calibration `camera.hand_eye`: eye-in-hand (`mount` flange) the camera frame (OpenCV axes)
/// in the flange frame; eye-to-hand (`mount` base) the camera in the robot base.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HandEyeBlock {
    pub mount: String,
    pub xyz_mm: [f64; 3],
    pub quat: [f64; 4],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub std_mm: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub std_deg: Option<[f64; 3]>,
    /// Bootstrap 1σ (refits, mm, deg), when run.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bootstrap: Option<Value>,
}

/// Calibration `camera` block.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraCalBlock {
    pub intrinsics: IntrinsicsBlock,
    pub hand_eye: HandEyeBlock,
    /// Eye-in-hand: the board in the base. Eye-to-hand: `target_in_flange`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target_in_base: Option<PoseWithStd>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target_in_flange: Option<PoseWithStd>,
    /// The board as declared (inner corners, square), and the scale / bend the fit found when
    /// the diagnosis freed them (1, 0 otherwise).
    pub target: TargetHeader,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target_scale: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    /// Sag (mm) at the corner radius along x and y (see `solve::camera::problem`).
    pub target_bend_mm: Option<[f64; 2]>,
    /// The map of the flange positions the camera diagnosis found (`flange_map`): the hand-eye
    /// holds for flange poses read through it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flange_map: Option<FlangeMapBlock>,
}

/// `camera.flange_map`: a flange at reported position `p` (mm, base frame) is at
/// `p + matrix · (p − centre_mm)`, its orientation unchanged (`matrix` row-major, trace-free,
/// unitless: 0.001 is 1 mm per metre).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FlangeMapBlock {
    pub centre_mm: [f64; 3],
    pub matrix: [[f64; 3]; 3],
}

fn typed<T: for<'de> Deserialize<'de>>(
    m: &Map<String, Value>,
    key: &str,
) -> Result<Option<T>, String> {
    match m.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(v) => serde_json::from_value(v.clone())
            .map(Some)
            .map_err(|e| format!("field \"{key}\": {e}")),
    }
}

impl Header {
    /// The `camera` block, if any (error names the field).
    pub fn camera(&self) -> Result<Option<CameraHeader>, String> {
        typed(&self.extra, "camera")
    }
    /// The `target` block, if any.
    pub fn target(&self) -> Result<Option<TargetHeader>, String> {
        typed(&self.extra, "target")
    }
    /// Set the `camera` and `target` blocks.
    pub fn set_camera(&mut self, cam: &CameraHeader, target: Option<&TargetHeader>) {
        self.extra.insert(
            "camera".into(),
            serde_json::to_value(cam).expect("serialisable"),
        );
        if let Some(t) = target {
            self.extra.insert(
                "target".into(),
                serde_json::to_value(t).expect("serialisable"),
            );
        }
    }
}

impl CalibrationFile {
    /// The `camera` block, if any.
    pub fn camera(&self) -> Result<Option<CameraCalBlock>, String> {
        typed(&self.extra, "camera")
    }
    /// Set the `camera` block (and `kind: camera`).
    pub fn set_camera(&mut self, b: &CameraCalBlock) {
        self.set_kind("camera");
        self.extra.insert(
            "camera".into(),
            serde_json::to_value(b).expect("serialisable"),
        );
    }
}
