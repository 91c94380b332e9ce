//! KEYENCE DL-RS1A decoders: line splitting, reply lines, measured values. Never panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use robocal_drivers::keyence::codec;

fuzz_target!(|data: &[u8]| {
    let mut buf = data;
    while let Some((line, used)) = codec::take_line(buf) {
        assert!(used > 0 && used <= buf.len() && line.len() <= used);
        let _ = codec::is_reply_to(line, "M0");
        if let Ok(r) = codec::decode_line(line) {
            // A decoded reply never holds more fields than the line has bytes.
            assert!(format!("{r:?}").len() < 64 + 64 * line.len());
        }
        buf = &buf[used..];
    }
    let _ = codec::parse_value(&String::from_utf8_lossy(data));
});
