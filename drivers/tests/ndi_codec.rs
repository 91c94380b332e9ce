//! NDI codec: literal bytes (ndicapi constants and the protocol brief's examples), partial
//! frames, a test-local encoder for round trips, and >= 100,000 random and mutated inputs per
//! decoder (no panic, bounded output).

use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use robocal_drivers::ndi::codec::{self, Decoded};
use robocal_drivers::ndi::frame::{HandleState, Reply};

#[test]
fn crc_literals_from_ndicapi() {
    // CRCs embedded as literals in ndicapi.cxx (e.g. "INIT:E3A5\r", "RESETBE6F\r") and the
    // vectors in protocols.md §4.2.
    for (text, crc) in [
        ("INIT:", 0xE3A5),
        ("OKAY", 0xA896),
        ("RESET", 0xBE6F),
        ("VER:0", 0x65EE),
        ("GETINFO:Features.Firmware.Version", 0x0492),
        ("PHSR:01", 0xE03E),
        ("PHSR:02", 0xE17E),
        ("PHSR:03", 0x21BF),
        ("PHRQ:*********1****", 0xA4C1),
        ("PINIT:01", 0x31EA),
        ("PENA:01D", 0x6D3B),
        ("TSTART:", 0x5423),
        ("TSTOP:", 0x2C14),
        ("BX:0801", 0x00EC),
        ("TX:0801", 0xC19B),
        ("APIREV:", 0x443E),
        ("COMM:50000", 0x0048),
        ("ERROR01", 0x6BC2),
    ] {
        assert_eq!(codec::crc16(text.as_bytes()), crc, "{text}");
    }
}

#[test]
fn command_encoding() {
    assert_eq!(codec::encode_command("INIT:"), b"INIT:E3A5\r");
    assert_eq!(codec::encode_command("BX:0801"), b"BX:080100EC\r");
    // Older space form: no CRC (sawNDITracker).
    assert_eq!(codec::encode_command("VER 0"), b"VER 0\r");
    assert!(codec::is_binary_command("BX:0801"));
    assert!(!codec::is_binary_command("BEEP:1"));
    assert!(!codec::is_binary_command("TX:0801"));
}

#[test]
fn text_replies_and_partial_frames() {
    // "OKAYA896\r" (ndicapi), "ERROR016BC2\r" (protocols.md §4.3), "RESETBE6F\r".
    assert_eq!(
        codec::decode_reply(b"OKAYA896\r", false),
        Decoded::Reply {
            reply: Reply::Okay,
            consumed: 9
        }
    );
    assert_eq!(
        codec::decode_reply(b"ERROR016BC2\r", false),
        Decoded::Reply {
            reply: Reply::Error(1),
            consumed: 12
        }
    );
    assert_eq!(
        codec::decode_reply(b"RESETBE6F\r", false),
        Decoded::Reply {
            reply: Reply::Reset,
            consumed: 10
        }
    );
    // Partial: no CR yet.
    assert_eq!(codec::decode_reply(b"OKAYA89", false), Decoded::Incomplete);
    // Bad CRC.
    assert!(matches!(
        codec::decode_reply(b"OKAYA897\r", false),
        Decoded::Invalid { .. }
    ));
    // An ERROR reply to a binary command is text.
    assert_eq!(
        codec::decode_reply(b"ERROR016BC2\r", true),
        Decoded::Reply {
            reply: Reply::Error(1),
            consumed: 12
        }
    );
}

/// Test-local BX encoder, written from protocols.md §4.6 (not shared with the simulator).
fn bx_wire(body: &[u8]) -> Vec<u8> {
    let mut v = vec![0xC4, 0xA5];
    v.extend_from_slice(&(body.len() as u16).to_le_bytes());
    let h = codec::crc16(&v);
    v.extend_from_slice(&h.to_le_bytes());
    v.extend_from_slice(body);
    v.extend_from_slice(&codec::crc16(body).to_le_bytes());
    v
}

fn one_valid_handle_body() -> Vec<u8> {
    let mut b = vec![1u8, 0x01, 0x01];
    for x in [1.0f32, 0.0, 0.0, 0.0, -12.5, 3.25, -1500.0, 0.125] {
        b.extend_from_slice(&x.to_le_bytes());
    }
    b.extend_from_slice(&0x31u32.to_le_bytes());
    b.extend_from_slice(&0xA1B2u32.to_le_bytes());
    b.extend_from_slice(&0u16.to_le_bytes());
    b
}

#[test]
fn bx_one_valid_handle_is_53_bytes_and_resyncs_after_garbage() {
    let body = one_valid_handle_body();
    assert_eq!(body.len(), 45, "protocols.md §4.6: 1 + (2 + 32 + 8) + 2");
    let wire = bx_wire(&body);
    assert_eq!(wire.len(), 53);
    // Every strict prefix is incomplete.
    for n in 0..wire.len() {
        assert_eq!(
            codec::decode_reply(&wire[..n], true),
            Decoded::Incomplete,
            "prefix {n}"
        );
    }
    let Decoded::Reply {
        reply: Reply::Binary(b),
        consumed: 53,
    } = codec::decode_reply(&wire, true)
    else {
        panic!("not decoded")
    };
    let r = codec::parse_bx(&b, 0x0801).unwrap();
    assert_eq!(r.handles.len(), 1);
    assert_eq!(r.handles[0].frame, 0xA1B2);
    assert_eq!(r.handles[0].port_status, 0x31);
    assert_eq!(
        r.handles[0].state,
        HandleState::Valid {
            q: [1.0, 0.0, 0.0, 0.0],
            t: [-12.5, 3.25, -1500.0],
            rms: 0.125
        }
    );
    // Garbage (including a false C4 with a bad header CRC) before the reply is skipped.
    let mut noisy = vec![0x00, 0xC4, 0xA5, 0x01, 0x00, 0x00, 0x00, 0x13];
    noisy.extend_from_slice(&wire);
    let mut buf = noisy.as_slice();
    let mut skipped = 0;
    loop {
        match codec::decode_reply(buf, true) {
            Decoded::Garbage { skip } => {
                skipped += skip;
                buf = &buf[skip..];
            }
            Decoded::Reply { consumed, .. } => {
                assert_eq!(consumed, 53);
                break;
            }
            other => panic!("{other:?}"),
        }
    }
    assert_eq!(skipped, 8);
    // Corrupt body CRC.
    let mut bad = wire.clone();
    bad[52] ^= 1;
    assert!(matches!(
        codec::decode_reply(&bad, true),
        Decoded::Invalid { consumed: 53, .. }
    ));
}

#[test]
fn bx_missing_and_disabled() {
    let mut b = vec![2u8, 0x0A, 0x02];
    b.extend_from_slice(&0x71u32.to_le_bytes());
    b.extend_from_slice(&9u32.to_le_bytes());
    b.extend_from_slice(&[0x0B, 0x04]);
    b.extend_from_slice(&0u16.to_le_bytes());
    let r = codec::parse_bx(&b, 0x0801).unwrap();
    assert_eq!(r.handles[0].state, HandleState::Missing);
    assert_eq!(r.handles[0].port_status, 0x71);
    assert_eq!(r.handles[1].state, HandleState::Disabled);
    assert!(codec::parse_bx(&b[..b.len() - 1], 0x0801).is_err());
    assert!(codec::parse_bx(&b, 0x0008).is_err(), "unsupported option");
}

#[test]
fn tx_literal_from_the_brief() {
    // protocols.md §4.5 example (one handle), then the system status line.
    let text = "0101+10000+00000+00000+00000-001234+000500-198700+00123000000310000A1B2\n0000";
    let r = codec::parse_tx(text, 0x0801).unwrap();
    assert_eq!(r.handles.len(), 1);
    let h = r.handles[0];
    assert_eq!((h.handle, h.port_status, h.frame), (1, 0x31, 0xA1B2));
    let HandleState::Valid { q, t, rms } = h.state else {
        panic!()
    };
    assert_eq!(q, [1.0, 0.0, 0.0, 0.0]);
    assert!(
        (t[0] + 12.34).abs() < 1e-9 && (t[1] - 5.0).abs() < 1e-9 && (t[2] + 1987.0).abs() < 1e-9
    );
    assert!((rms - 0.0123).abs() < 1e-12);
    // MISSING keeps status and frame; UNOCCUPIED is skipped (ndicapi).
    let text = "0302MISSING0000007100000009\n03UNOCCUPIED\n04DISABLED\n0000";
    let r = codec::parse_tx(text, 0x0001).unwrap();
    assert_eq!(r.handles.len(), 2);
    assert_eq!(r.handles[0].state, HandleState::Missing);
    assert_eq!(r.handles[1].state, HandleState::Disabled);
    assert!(codec::parse_tx("0101+10000", 0x0801).is_err());
}

#[test]
fn phsr_and_phrq() {
    let v = codec::parse_phsr("020A0310B031").unwrap();
    assert_eq!(v.len(), 2);
    assert_eq!((v[0].handle, v[0].status), (0x0A, 0x031));
    assert_eq!(codec::parse_phsr("00").unwrap().len(), 0);
    assert!(codec::parse_phsr("020A031").is_err());
    assert_eq!(codec::parse_phrq("0a").unwrap(), 10);
    let cmds = codec::pvwr_commands(1, &[0xAB; 65]);
    assert_eq!(cmds.len(), 2);
    assert_eq!(cmds[1].len(), "PVWR:".len() + 2 + 4 + 128);
    assert!(cmds[1].starts_with("PVWR:010040AB00"));
}

fn encode_tx_field(v: f64, scale: f64, digits: usize) -> String {
    let n = (v / scale).round();
    format!(
        "{}{:0w$}",
        if n < 0.0 { '-' } else { '+' },
        n.abs() as u64,
        w = digits
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]
    #[test]
    fn bx_round_trip(handle in 1u8..=255, q in prop::array::uniform4(-1.0f32..1.0), t in prop::array::uniform3(-3000.0f32..3000.0),
                     rms in 0.0f32..2.0, status in any::<u32>(), frame in any::<u32>(), sys in any::<u16>()) {
        let mut b = vec![1u8, handle, 0x01];
        for x in q.iter().chain(t.iter()).chain(std::iter::once(&rms)) {
            b.extend_from_slice(&x.to_le_bytes());
        }
        b.extend_from_slice(&status.to_le_bytes());
        b.extend_from_slice(&frame.to_le_bytes());
        b.extend_from_slice(&sys.to_le_bytes());
        let wire = bx_wire(&b);
        let Decoded::Reply { reply: Reply::Binary(body), consumed } = codec::decode_reply(&wire, true) else {
            return Err(TestCaseError::fail("not decoded"));
        };
        prop_assert_eq!(consumed, wire.len());
        let r = codec::parse_bx(&body, 0x0801).unwrap();
        prop_assert_eq!(r.system_status, sys);
        let h = r.handles[0];
        prop_assert_eq!((h.handle, h.port_status, h.frame), (handle, status, frame));
        let HandleState::Valid { q: q2, t: t2, rms: r2 } = h.state else { return Err(TestCaseError::fail("state")) };
        for i in 0..4 { prop_assert_eq!(q2[i], f64::from(q[i])); }
        for i in 0..3 { prop_assert_eq!(t2[i], f64::from(t[i])); }
        prop_assert_eq!(r2, f64::from(rms));
    }

    #[test]
    fn tx_round_trip(handle in 1u8..=255, q in prop::array::uniform4(-1.0f64..1.0), t in prop::array::uniform3(-9999.0f64..9999.0),
                     rms in 0.0f64..9.0, status in any::<u32>(), frame in any::<u32>()) {
        let mut s = format!("01{handle:02X}");
        for x in q { s.push_str(&encode_tx_field(x, 1e-4, 5)); }
        for x in t { s.push_str(&encode_tx_field(x, 1e-2, 6)); }
        s.push_str(&encode_tx_field(rms, 1e-4, 5));
        s.push_str(&format!("{status:08X}{frame:08X}\n0000"));
        let r = codec::parse_tx(&s, 0x0801).unwrap();
        let h = r.handles[0];
        prop_assert_eq!((h.handle, h.port_status, h.frame), (handle, status, frame));
        let HandleState::Valid { q: q2, t: t2, rms: r2 } = h.state else { return Err(TestCaseError::fail("state")) };
        for i in 0..4 { prop_assert!((q2[i] - q[i]).abs() <= 0.5e-4 + 1e-12); }
        for i in 0..3 { prop_assert!((t2[i] - t[i]).abs() <= 0.5e-2 + 1e-9); }
        prop_assert!((r2 - rms).abs() <= 0.5e-4 + 1e-12);
    }

    #[test]
    fn text_reply_round_trip(text in "[ -~]{1,200}") {
        let mut wire = text.clone().into_bytes();
        wire.extend_from_slice(format!("{:04X}\r", codec::crc16(text.as_bytes())).as_bytes());
        match codec::decode_reply(&wire, false) {
            Decoded::Reply { consumed, reply } => {
                prop_assert_eq!(consumed, wire.len());
                match reply {
                    Reply::Text(t) => prop_assert_eq!(t, text),
                    Reply::Okay => prop_assert_eq!(text, "OKAY"),
                    Reply::Reset => prop_assert_eq!(text, "RESET"),
                    Reply::Error(c) => prop_assert_eq!(text, format!("ERROR{c:02X}")),
                    Reply::Binary(_) => return Err(TestCaseError::fail("binary")),
                }
            }
            Decoded::Invalid { .. } => prop_assert!(text.starts_with("ERROR")),
            other => return Err(TestCaseError::fail(format!("{other:?}"))),
        }
    }
}

fn mutate(rng: &mut impl Rng, seed: &[u8]) -> Vec<u8> {
    let mut v = seed.to_vec();
    for _ in 0..rng.random_range(1..6) {
        match rng.random_range(0..4) {
            0 if !v.is_empty() => {
                let i = rng.random_range(0..v.len());
                v[i] = rng.random();
            }
            1 if !v.is_empty() => {
                let i = rng.random_range(0..v.len());
                v.remove(i);
            }
            2 => {
                let i = rng.random_range(0..=v.len());
                v.insert(i, rng.random());
            }
            _ => {
                let n = rng.random_range(0..=v.len());
                v.truncate(n);
            }
        }
    }
    v
}

/// >= 100,000 random and mutated inputs through every decoder: no panic, bounded output.
#[test]
fn decoders_survive_100k_random_and_mutated_inputs() {
    let mut rng = rand::rngs::StdRng::seed_from_u64(0x4E44_4931);
    let bx = bx_wire(&one_valid_handle_body());
    let tx = "0201+10000+00000+00000+00000-001234+000500-198700+00123000000310000A1B2\n02MISSING0000007100000009\n0000";
    let seeds: Vec<Vec<u8>> = vec![
        bx.clone(),
        one_valid_handle_body(),
        tx.as_bytes().to_vec(),
        b"OKAYA896\r".to_vec(),
        b"ERROR016BC2\r".to_vec(),
        b"020A0310B031".to_vec(),
    ];
    let mut n = 0usize;
    for i in 0..120_000 {
        let input: Vec<u8> = if i % 3 == 0 {
            let len = rng.random_range(0..300);
            (0..len).map(|_| rng.random()).collect()
        } else {
            mutate(&mut rng, &seeds[i % seeds.len()])
        };
        for binary in [false, true] {
            match codec::decode_reply(&input, binary) {
                Decoded::Reply { consumed, reply } => {
                    assert!(consumed <= input.len() && consumed > 0);
                    if let Reply::Binary(b) = reply {
                        assert!(b.len() <= input.len());
                    }
                }
                Decoded::Garbage { skip } => assert!(skip > 0 && skip <= input.len()),
                Decoded::Invalid { consumed, .. } => {
                    assert!(consumed > 0 && consumed <= input.len())
                }
                Decoded::Incomplete => {}
            }
        }
        if let Ok(r) = codec::parse_bx(&input, 0x0801) {
            // Each handle uses at least 2 bytes: bounded by the input.
            assert!(r.handles.len() * 2 <= input.len());
        }
        let text = String::from_utf8_lossy(&input);
        if let Ok(r) = codec::parse_tx(&text, 0x0801) {
            assert!(r.handles.len() <= input.len());
        }
        let _ = codec::parse_phsr(&text);
        let _ = codec::parse_phrq(&text);
        n += 1;
    }
    assert!(n >= 100_000);
}
