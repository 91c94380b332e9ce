//! Typed blocks of the RCM / endoscope hand-eye contract (`docs/dataset-format.md`):
//! the header's `camera` (`kind: "endoscope"`) and `instrument` blocks, a pose record's
//! `shaft_lines`, and the calibration file's `camera` block (`hand_eye`, its uncertainty and
//! the RCM point). They live in the flattened `extra` maps of [`super::Header`],
//! [`super::PoseRecord`] and [`super::CalibrationFile`], so old readers keep them verbatim.
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

/// Header `camera` block of an endoscope dataset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EndoscopeCamera {
    /// Always `"endoscope"`.
    pub kind: String,
    /// Image size (pixels).
    pub width: u32,
    /// Image size (pixels).
    pub height: u32,
    /// Focal lengths (pixels).
    pub fx: f64,
    /// Focal lengths (pixels).
    pub fy: f64,
    /// Principal point (pixels).
    pub cx: f64,
    /// Principal point (pixels).
    pub cy: f64,
    /// OpenCV distortion `[k1, k2, p1, p2, k3]` (the `shaft_lines` are already undistorted).
    #[serde(default)]
    pub dist: [f64; 5],
}

/// Header `instrument` block.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InstrumentBlock {
    /// Shaft radius (mm).
    pub shaft_radius_mm: f64,
}

/// `camera.hand_eye` of a calibration file: the camera frame (OpenCV axes: x right, y down,
/// z forward) in the frame named by `mount` (`"base"`: the robot base, eye-to-hand;
/// `"flange"`: eye-in-hand).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HandEye {
    /// `"base"` or `"flange"`.
    pub mount: String,
    /// Origin of the camera frame (mm).
    pub xyz_mm: [f64; 3],
    /// Orientation `[w, x, y, z]`.
    pub quat: [f64; 4],
    /// 1-σ of `xyz_mm` (mm).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub xyz_std_mm: Option<[f64; 3]>,
    /// 1-σ of the orientation as a small rotation about the mount frame's x, y, z (deg).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rot_std_deg: Option<[f64; 3]>,
    /// Unknown fields, kept.
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// The remote centre of motion found by an RCM calibration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RcmPoint {
    /// In the robot base (mm).
    pub base_mm: [f64; 3],
    /// In the camera frame (mm).
    pub camera_mm: [f64; 3],
    /// RMS distance of the instrument axes (robot side) from it (mm).
    pub axes_rms_mm: f64,
}

/// The calibration file's `camera` block written by `robocal calibrate rcm`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraCal {
    /// Intrinsics the calibration used (copied from the dataset header).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub intrinsics: Option<EndoscopeCamera>,
    /// The hand-eye transform.
    pub hand_eye: HandEye,
    /// The RCM point.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rcm: Option<RcmPoint>,
    /// Unknown fields, kept.
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// Reads a typed block from a flattened `extra` map; `Ok(None)` when absent.
pub fn block<T: serde::de::DeserializeOwned>(
    extra: &Map<String, Value>,
    key: &str,
) -> Result<Option<T>, String> {
    match extra.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(v) => serde_json::from_value(v.clone())
            .map(Some)
            .map_err(|e| format!("field \"{key}\": {e}")),
    }
}

/// The `shaft_lines` of a pose record: two segments `[u1, v1, u2, v2]` of finite numbers.
pub fn shaft_lines(extra: &Map<String, Value>) -> Result<Option<[[f64; 4]; 2]>, String> {
    let Some(v) = extra.get("shaft_lines") else {
        return Ok(None);
    };
    if v.is_null() {
        return Ok(None);
    }
    let bad = || {
        format!(
            "field \"shaft_lines\": expected [[u1, v1, u2, v2], [u3, v3, u4, v4]] (two segments of finite pixel coordinates), got {}",
            short(v)
        )
    };
    let arr = v.as_array().ok_or_else(bad)?;
    if arr.len() != 2 {
        return Err(bad());
    }
    let mut out = [[0.0; 4]; 2];
    for (k, seg) in arr.iter().enumerate() {
        let s = seg.as_array().ok_or_else(bad)?;
        if s.len() != 4 {
            return Err(bad());
        }
        for (j, x) in s.iter().enumerate() {
            out[k][j] = x.as_f64().filter(|x| x.is_finite()).ok_or_else(bad)?;
        }
    }
    Ok(Some(out))
}

/// A short rendering of a JSON value for error messages (at most ~80 characters).
fn short(v: &Value) -> String {
    let s = v.to_string();
    if s.chars().count() > 80 {
        format!("{}…", s.chars().take(80).collect::<String>())
    } else {
        s
    }
}
