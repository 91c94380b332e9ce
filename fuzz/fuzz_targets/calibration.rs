//! Calibration reader (`robocal-calibration/1`): never panics; an accepted file re-encodes to
//! one that reads back equal; its values check and apply to its robot's model without panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use robocal::dataset::CalibrationFile;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let file = Path::new("fuzz.json");
    if let Ok(cal) = CalibrationFile::parse(text, file) {
        let _ = robocal::plausible::calibration::check_values(&cal, file);
        if let Ok(mut m) = robocal::model::KinematicModel::from_robot_block(&cal.robot) {
            let _ = m.apply_cal_params(&cal.params);
        }
        let again = CalibrationFile::parse(&cal.to_json_pretty(), file)
            .expect("a calibration robocal accepted re-encodes to a file robocal reads");
        let (a, b) = (
            serde_json::to_value(&again).expect("serialise"),
            serde_json::to_value(&cal).expect("serialise"),
        );
        assert!(same_json(&a, &b), "re-read calibration differs");
    }
});

/// Equal JSON values, floats within a relative 1e-12 (serde_json is built without its
/// `float_roundtrip` feature: its fast float parser may land an ulp off on re-read).
fn same_json(a: &serde_json::Value, b: &serde_json::Value) -> bool {
    use serde_json::Value;
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => match (x.as_f64(), y.as_f64()) {
            (Some(x), Some(y)) => {
                x == y
                    || (x - y).abs() <= 1e-12 * x.abs().max(y.abs())
                    || x.abs().max(y.abs()) < 1e-300
            }
            _ => x == y,
        },
        (Value::Array(x), Value::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(p, q)| same_json(p, q))
        }
        (Value::Object(x), Value::Object(y)) => {
            x.len() == y.len()
                && x.iter()
                    .all(|(k, v)| y.get(k).is_some_and(|w| same_json(v, w)))
        }
        _ => a == b,
    }
}
