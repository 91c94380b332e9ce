//! Laser datasets (plane and target poses with a measured range): the observations of any
//! dataset robocal reads, grouped by plane and target, and the closed-form single-plane
//! beam on each plane never panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use robocal::solve::laser;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(loaded) = robocal::dataset::io::parse_dataset(data, Path::new("fuzz.jsonl")) else {
        return;
    };
    let Ok(obs) = laser::observations(&loaded.dataset) else {
        return;
    };
    let _ = laser::by_target(&obs);
    for plane in laser::by_plane(&obs).values() {
        let _ = laser::fit::closed_form_single_plane(plane);
    }
});
