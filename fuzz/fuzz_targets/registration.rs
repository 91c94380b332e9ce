//! Registration file (`robocal-registration/1`) and points CSV readers: never panic; an
//! accepted registration gives a transform and covariance or a clear error.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(r) = robocal::register::RegistrationFile::parse(text, "fuzz.json") {
        let _ = r.transform();
        let _ = r.covariance();
    }
    let _ = robocal::register::points::parse_points_csv(text, "fuzz.csv");
});
