//! Robot-world inputs: the `robocal-robot-world/1` file reader and the AX = YB observations
//! of a dataset with the closed forms on them never panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use robocal::register::robot_world as rw;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        if let Ok(f) = serde_json::from_str::<rw::RobotWorldFile>(text) {
            let _ = f.y();
        }
    }
    let Ok(loaded) = robocal::dataset::io::parse_dataset(data, Path::new("fuzz.jsonl")) else {
        return;
    };
    if let Ok((obs, _)) = rw::observations_from_dataset(&loaded.dataset) {
        let _ = rw::shah(&obs);
        let _ = rw::li(&obs);
        let _ = rw::tsai_route(&obs);
    }
});
