//! Calibration reader (`robocal-calibration/1`): never panics; an accepted file re-encodes to
//! one that reads back equal; its values check and apply to its robot's model without panic.
#![no_main]

#[path = "common/mod.rs"]
mod common;

use common::same_json;
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
