//! Device file reader (`DEVICES.toml` of a real cell): never panics; an accepted file
//! re-encodes to TOML that reads back equal.
#![no_main]

use libfuzzer_sys::fuzz_target;
use robocal::acquire::devices::DevicesFile;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(f) = DevicesFile::parse(text, "fuzz.toml") {
        if let Ok(again) = toml::to_string(&f) {
            let back = DevicesFile::parse(&again, "fuzz.toml")
                .expect("a device file robocal accepted re-encodes to a file robocal reads");
            assert_eq!(back, f);
        }
    }
});
