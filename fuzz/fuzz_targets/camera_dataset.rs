//! Camera dataset header blocks (`camera`, `target`) and the camera calibration block of a
//! calibration file: never panic on any dataset or calibration robocal's readers accept.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(loaded) = robocal::dataset::io::parse_dataset(data, Path::new("fuzz.jsonl")) {
        let _ = loaded.dataset.header.camera();
        let _ = loaded.dataset.header.target();
    }
    if let Ok(text) = std::str::from_utf8(data) {
        if let Ok(cal) = robocal::dataset::CalibrationFile::parse(text, Path::new("fuzz.json")) {
            let _ = cal.camera();
        }
    }
});
