//! NDI Combined API decoders: reply framing (text and binary, with resync), BX / TX / PHSR /
//! PHRQ parsers. Never panic; consumed byte counts stay within the input.
#![no_main]

use libfuzzer_sys::fuzz_target;
use robocal_drivers::ndi::codec::{self, Decoded};
use robocal_drivers::ndi::frame::Reply;

fuzz_target!(|data: &[u8]| {
    for binary in [false, true] {
        // Drive the decoder like the client does: drop garbage, stop at the first reply.
        let mut buf = data;
        loop {
            match codec::decode_reply(buf, binary) {
                Decoded::Garbage { skip } => {
                    assert!(skip > 0 && skip <= buf.len());
                    buf = &buf[skip..];
                }
                Decoded::Reply { reply, consumed } => {
                    assert!(consumed > 0 && consumed <= buf.len());
                    match reply {
                        Reply::Binary(body) => {
                            let _ = codec::parse_bx(&body, 0x0801);
                        }
                        Reply::Text(t) => {
                            let _ = codec::parse_tx(&t, 0x0801);
                            let _ = codec::parse_phsr(&t);
                            let _ = codec::parse_phrq(&t);
                        }
                        _ => {}
                    }
                    break;
                }
                Decoded::Invalid { consumed, .. } => {
                    assert!(consumed > 0 && consumed <= buf.len());
                    break;
                }
                Decoded::Incomplete => break,
            }
        }
    }
    let _ = codec::parse_bx(data, 0x0801);
    let text = String::from_utf8_lossy(data);
    let _ = codec::parse_tx(&text, 0x0801);
});
