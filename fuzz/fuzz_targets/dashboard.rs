//! Dashboard line decoder and reply parsers: never panic, lines never exceed the cap.
#![no_main]

use libfuzzer_sys::fuzz_target;
use robocal_drivers::ur::dashboard::{parse_robot_mode, parse_safety, LineCodec, MAX_LINE};

fuzz_target!(|data: &[u8]| {
    if let Ok(lines) = LineCodec::decode_all(data) {
        for l in lines {
            assert!(l.len() <= MAX_LINE);
            let _ = parse_robot_mode(&l);
            let _ = parse_safety(&l);
        }
    }
});
