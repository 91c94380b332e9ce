//! RCM (endoscope) dataset reader: a dataset robocal accepts either gives RCM data or a
//! clear error, and the closed-form RCM calibration on it never panics (issue 26 §3: one
//! pixel coordinate of 1e308 used to panic inside the SVD).
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let file = Path::new("fuzz.jsonl");
    let Ok(loaded) = robocal::dataset::io::parse_dataset(data, file) else {
        return;
    };
    if let Ok(d) = robocal::solve::rcm::RcmData::from_dataset(&loaded.dataset, file) {
        let _ = robocal::solve::rcm::calibrate(
            &d,
            &robocal::solve::rcm::RcmOptions {
                bootstrap: 0,
                seed: 1,
            },
        );
    }
});
