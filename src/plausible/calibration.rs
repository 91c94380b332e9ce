//! Plausibility of a calibration file for the robot it is applied to: the same robot model,
//! and arm parameters within reach of the nominal geometry. A calibration whose `a3` is 1e308
//! (or 400 mm off the nominal) is not a calibration of this robot; a prediction from it would
//! be a confident wrong answer, and a fit started from it never converges.
use std::path::Path;

use crate::dataset::{CalibrationFile, CalibrationKind, DatasetError, Location, RobotBlock};
use crate::model::{KinematicModel, ParamGroup, Unit};

use super::dataset::{check_same_robot, MAX_COORD_MM};

/// Largest plausible correction of an arm length parameter from its nominal value (mm).
pub const MAX_ARM_CORRECTION_MM: f64 = 50.0;
/// Largest plausible correction of an arm angle parameter from its nominal value (deg).
pub const MAX_ARM_CORRECTION_DEG: f64 = 10.0;
/// Largest plausible tool (marker / tip in the flange) offset (mm).
pub const MAX_TOOL_MM: f64 = 2000.0;

fn err(file: &Path, field: String, msg: String) -> DatasetError {
    DatasetError::Field {
        at: Location {
            file: file.to_path_buf(),
            line: None,
        },
        field,
        msg,
    }
}

/// The calibration kinds robocal writes (the top-level `kind`; absent means kinematic).
pub const KNOWN_KINDS: [&str; 4] = ["kinematic", "laser", "rcm", "camera"];
/// Largest plausible magnitude of a number in an effect's parameters (a coefficient, a time
/// in seconds since `created`, ppm): 1e9.
pub const MAX_EFFECT_VALUE: f64 = 1.0e9;

/// The first number in `v` (recursively) that is not finite or above `max` in magnitude,
/// with its path below `at`.
fn bad_number(v: &serde_json::Value, at: String, max: f64) -> Option<(String, f64)> {
    match v {
        serde_json::Value::Number(n) => {
            let x = n.as_f64().unwrap_or(f64::INFINITY);
            (!x.is_finite() || x.abs() > max).then_some((at, x))
        }
        serde_json::Value::Array(a) => a
            .iter()
            .enumerate()
            .find_map(|(i, x)| bad_number(x, format!("{at}[{i}]"), max)),
        serde_json::Value::Object(o) => o
            .iter()
            .find_map(|(k, x)| bad_number(x, format!("{at}.{k}"), max)),
        _ => None,
    }
}

/// Checks what a calibration file claims before any number of it is used: a kind robocal
/// knows, at least one parameter (a kinematic or laser calibration without parameters is
/// not a calibration: applying it gives the nominal model, metres off), every effect of a
/// kinematic calibration one robocal can apply (an unknown effect silently ignored would be
/// a confident wrong prediction) and every effect number finite and plausible.
fn check_kind_and_effects(cal: &CalibrationFile, file: &Path) -> Result<(), DatasetError> {
    let kind = cal.kind();
    if let CalibrationKind::Other(k) = &kind {
        if !KNOWN_KINDS.contains(&k.as_str()) {
            return Err(err(
                file,
                "kind".into(),
                format!(
                    "unknown calibration kind \"{k}\": robocal writes {} (a file of another \
                     program, or a typo)",
                    KNOWN_KINDS.join(", ")
                ),
            ));
        }
    }
    if matches!(kind, CalibrationKind::Kinematic | CalibrationKind::Laser) && cal.params.is_empty()
    {
        return Err(err(
            file,
            "params".into(),
            "empty: a calibration without parameters would predict with the nominal model (no \
             base, no tool: metres off); an unfinished or hand-edited file"
                .into(),
        ));
    }
    for (i, e) in cal.effects.iter().enumerate() {
        if let Some((at, x)) = bad_number(
            &serde_json::Value::Object(e.params.clone()),
            format!("effects[{i}].params"),
            MAX_EFFECT_VALUE,
        ) {
            return Err(err(
                file,
                at,
                format!(
                    "effect \"{}\": {x:e} is not a plausible coefficient (finite, at most \
                     {MAX_EFFECT_VALUE:e} in magnitude): a corrupted or mistyped file",
                    e.kind
                ),
            ));
        }
        if kind == CalibrationKind::Kinematic {
            if let Err(why) = crate::diagnose::effects::Effect::from_cal(e) {
                return Err(err(
                    file,
                    format!("effects[{i}]"),
                    format!(
                        "{why}: robocal cannot apply this effect, and ignoring it would give \
                         predictions that silently lack it"
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// Checks the values of a calibration file on their own: its kind and effects
/// ([`check_kind_and_effects`]), every `value` and `std` finite, `std ≥ 0`, and for a
/// kinematic calibration every arm parameter within [`MAX_ARM_CORRECTION_MM`] /
/// [`MAX_ARM_CORRECTION_DEG`] of the nominal chain of the file's own robot block, the tool
/// within [`MAX_TOOL_MM`] and the base within 100 m.
pub fn check_values(cal: &CalibrationFile, file: &Path) -> Result<(), DatasetError> {
    check_kind_and_effects(cal, file)?;
    for (i, p) in cal.params.iter().enumerate() {
        if !p.value.is_finite() || p.value.abs() > MAX_COORD_MM {
            return Err(err(
                file,
                format!("params[{i}].value"),
                format!(
                    "parameter \"{}\" = {:e} {} is not a plausible calibration value: a corrupted \
                     or mistyped file",
                    p.name, p.value, p.unit
                ),
            ));
        }
        if let Some(s) = p.std {
            if !s.is_finite() || s < 0.0 {
                return Err(err(
                    file,
                    format!("params[{i}].std"),
                    format!(
                        "parameter \"{}\": a standard deviation is ≥ 0, got {s}",
                        p.name
                    ),
                ));
            }
        }
    }
    if cal.kind() == CalibrationKind::Other("camera".into()) {
        check_camera_block(cal, file)?;
    }
    if cal.kind() != CalibrationKind::Kinematic {
        return Ok(());
    }
    let Ok(nominal) = KinematicModel::from_robot_block(&cal.robot) else {
        return Ok(()); // reported by the caller when it builds the model
    };
    let mut m = nominal.clone();
    if m.apply_cal_params(&cal.params).is_err() {
        return Ok(()); // unknown names / units: reported by the caller with its context
    }
    for (p, n) in m.params().iter().zip(nominal.params()) {
        let idx = cal
            .params
            .iter()
            .position(|c| c.name == p.name)
            .map(|i| format!("params[{i}].value"))
            .unwrap_or_else(|| format!("params \"{}\"", p.name));
        let d = p.value - n.value;
        match (p.group, p.unit) {
            (ParamGroup::Joint(_) | ParamGroup::Flange, Unit::Mm)
                if d.abs() > MAX_ARM_CORRECTION_MM =>
            {
                return Err(err(
                    file,
                    idx,
                    format!(
                        "arm parameter \"{}\" = {:.3} mm is {:.1} mm from the nominal {:.3} mm of \
                         robot \"{}\" (a calibration corrects by at most {MAX_ARM_CORRECTION_MM} \
                         mm): a calibration of another robot, or a corrupted value",
                        p.name, p.value, d, n.value, cal.robot.model
                    ),
                ));
            }
            (ParamGroup::Joint(_) | ParamGroup::Flange, Unit::Rad)
                if d.to_degrees().abs() > MAX_ARM_CORRECTION_DEG =>
            {
                return Err(err(
                    file,
                    idx,
                    format!(
                        "arm parameter \"{}\" = {:.4}° is {:.2}° from the nominal {:.4}° of robot \
                         \"{}\" (a calibration corrects by at most {MAX_ARM_CORRECTION_DEG}°): a \
                         calibration of another robot, or a corrupted value",
                        p.name,
                        p.value.to_degrees(),
                        d.to_degrees(),
                        n.value.to_degrees(),
                        cal.robot.model
                    ),
                ));
            }
            (ParamGroup::Tool, Unit::Mm) if p.value.abs() > MAX_TOOL_MM => {
                return Err(err(
                    file,
                    idx,
                    format!(
                        "tool parameter \"{}\" = {:.1} mm: a marker or tip more than \
                         {MAX_TOOL_MM} mm from the flange is not plausible",
                        p.name, p.value
                    ),
                ));
            }
            _ => {}
        }
    }
    Ok(())
}

/// Reads a calibration file, checks its values ([`check_values`]) and that it was made for
/// the robot of `robot` (the dataset `data_file` it is applied to).
pub fn load_for(
    path: &Path,
    robot: &RobotBlock,
    data_file: &Path,
) -> Result<CalibrationFile, DatasetError> {
    let cal = CalibrationFile::load(path)?;
    check_same_robot(robot, data_file, &cal.robot, path, "calibration")?;
    check_values(&cal, path)?;
    Ok(cal)
}

/// Largest plausible board bend (`camera.target_bend_mm`) as a fraction of the board's corner
/// radius: a printed board sags by a fraction of a millimetre, never by a tenth of its size.
pub const MAX_BEND_FRACTION: f64 = 0.1;

/// The camera block's numbers that `predict` applies: intrinsics finite with positive focal
/// lengths, the declared board positive, the board scale the diagnosis found within 0.5–2
/// (a scale off by 1000 is a unit mistake) and its bend finite and at most
/// [`MAX_BEND_FRACTION`] of the board's corner radius.
fn check_camera_block(cal: &CalibrationFile, file: &Path) -> Result<(), DatasetError> {
    let b = match cal.camera() {
        Ok(Some(b)) => b,
        Ok(None) => {
            return Err(err(
                file,
                "camera".into(),
                "a calibration of kind camera without its \"camera\" block: an unfinished or \
                 hand-edited file"
                    .into(),
            ))
        }
        Err(e) => return Err(err(file, "camera".into(), e)),
    };
    let i = &b.intrinsics;
    let intr = [i.fx, i.fy, i.cx, i.cy];
    // A focal length beyond 1e6 px or a distortion coefficient beyond 1e4 is no lens.
    if intr.iter().any(|v| !v.is_finite() || v.abs() > 1e6)
        || i.dist.iter().any(|v| !v.is_finite() || v.abs() > 1e4)
        || i.fx <= 0.0
        || i.fy <= 0.0
    {
        return Err(err(
            file,
            "camera.intrinsics".into(),
            format!(
                "fx {} fy {} cx {} cy {} dist {:?}: the intrinsics must be finite with fx, fy > 0, \
                 |fx|, |fy|, |cx|, |cy| ≤ 1e6 px and |dist| ≤ 1e4 (a corrupted value)",
                i.fx, i.fy, i.cx, i.cy, i.dist
            ),
        ));
    }
    let t = &b.target;
    if !(t.square_mm.is_finite() && t.square_mm > 0.0) || t.cols == 0 || t.rows == 0 {
        return Err(err(
            file,
            "camera.target".into(),
            format!(
                "board {}x{} inner corners of {} mm squares: not a board (a corrupted value)",
                t.cols, t.rows, t.square_mm
            ),
        ));
    }
    if let Some(s) = b.target_scale {
        if !(s.is_finite() && (0.5..=2.0).contains(&s)) {
            return Err(err(
                file,
                "camera.target_scale".into(),
                format!(
                    "{s}: a printed board is within a few per cent of its declared size (0.5–2 \
                     accepted); a scale off by 1000 is metres for millimetres, else a corrupted \
                     value"
                ),
            ));
        }
    }
    if let Some(bend) = b.target_bend_mm {
        let (w, h) = (
            f64::from(t.cols + 1) * t.square_mm,
            f64::from(t.rows + 1) * t.square_mm,
        );
        let max = MAX_BEND_FRACTION * (w * w + h * h).sqrt() / 2.0;
        if bend.iter().any(|v| !v.is_finite() || v.abs() > max) {
            return Err(err(
                file,
                "camera.target_bend_mm".into(),
                format!(
                    "{bend:?} mm: a board's bend is at most {max:.1} mm (a tenth of its corner \
                     radius); a corrupted value or a bend in the wrong unit"
                ),
            ));
        }
    }
    if let Some(m) = &b.flange_map {
        let entries = m.matrix.iter().flatten();
        let trace = m.matrix[0][0] + m.matrix[1][1] + m.matrix[2][2];
        if m.centre_mm.iter().any(|v| !v.is_finite() || v.abs() > 1e5)
            || entries
                .clone()
                .any(|v| !v.is_finite() || v.abs() > MAX_FLANGE_MAP)
            || trace.abs() > 1e-9
        {
            return Err(err(
                file,
                "camera.flange_map".into(),
                format!(
                    "centre {:?} mm, matrix {:?}: the map of an arm's flange positions is \
                     trace-free with entries within ±{MAX_FLANGE_MAP} ({} mm per metre) and a \
                     finite centre within 100 m; a corrupted or hand-edited value",
                    m.centre_mm,
                    m.matrix,
                    1e3 * MAX_FLANGE_MAP
                ),
            ));
        }
    }
    Ok(())
}

/// Largest plausible entry of `camera.flange_map.matrix`: an arm whose reported positions are
/// off by more than 5 cm per metre is not calibrated by a camera, it is broken or mis-declared.
pub const MAX_FLANGE_MAP: f64 = 0.05;
