//! Server-side byte format of the NDI Combined API: command parsing, reply encoding.

/// CRC-16/ARC (bitwise, MSB-first formulation of the reflected 0x8005 polynomial).
pub fn crc16(data: &[u8]) -> u16 {
    let mut crc: u16 = 0;
    for &b in data {
        let mut x = u16::from(b);
        for _ in 0..8 {
            let mix = (crc ^ x) & 1;
            crc >>= 1;
            if mix != 0 {
                crc ^= 0xA001;
            }
            x >>= 1;
        }
    }
    crc
}

/// A command line received from the host.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Command {
    /// Command word, e.g. `PHSR`.
    pub word: String,
    /// Parameters (without CRC), as sent.
    pub params: String,
}

/// Why a command line was refused (mapped to `ERRORxx`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CommandError {
    /// `ERROR01` invalid command.
    Invalid,
    /// `ERROR04` bad command CRC.
    BadCrc,
}

/// Parse one command line (without the trailing `\r`). Both forms are accepted:
/// `WORD:params<CRC4>` (CRC verified, hex in either case) and `WORD params` / `WORD`.
pub fn parse_command(line: &[u8]) -> Result<Command, CommandError> {
    let text = std::str::from_utf8(line).map_err(|_| CommandError::Invalid)?;
    let word_len = text
        .bytes()
        .take_while(|b| b.is_ascii_uppercase() || b.is_ascii_digit())
        .count();
    if word_len == 0 {
        return Err(CommandError::Invalid);
    }
    let word = text[..word_len].to_string();
    let rest = &text[word_len..];
    if let Some(after) = rest.strip_prefix(':') {
        if after.len() < 4 {
            return Err(CommandError::BadCrc);
        }
        let (params, crc_hex) = text.split_at(text.len() - 4);
        let sent = u16::from_str_radix(crc_hex, 16).map_err(|_| CommandError::BadCrc)?;
        if !crc_hex.bytes().all(|b| b.is_ascii_hexdigit()) || sent != crc16(params.as_bytes()) {
            return Err(CommandError::BadCrc);
        }
        Ok(Command {
            word,
            params: params[word_len + 1..].to_string(),
        })
    } else if let Some(after) = rest.strip_prefix(' ') {
        Ok(Command {
            word,
            params: after.to_string(),
        })
    } else if rest.is_empty() {
        Ok(Command {
            word,
            params: String::new(),
        })
    } else {
        Err(CommandError::Invalid)
    }
}

/// `<text><CRC 4 hex>\r`.
pub fn text_reply(text: &str) -> Vec<u8> {
    let mut v = text.as_bytes().to_vec();
    v.extend_from_slice(format!("{:04X}\r", crc16(text.as_bytes())).as_bytes());
    v
}

/// `ERRORxx<CRC>\r`.
pub fn error_reply(code: u8) -> Vec<u8> {
    text_reply(&format!("ERROR{code:02X}"))
}

/// `C4 A5`, length, header CRC, body, body CRC.
pub fn binary_reply(body: &[u8]) -> Vec<u8> {
    let len = u16::try_from(body.len()).unwrap_or(u16::MAX);
    let mut v = vec![0xC4, 0xA5];
    v.extend_from_slice(&len.to_le_bytes());
    let hcrc = crc16(&v);
    v.extend_from_slice(&hcrc.to_le_bytes());
    v.extend_from_slice(&body[..usize::from(len)]);
    v.extend_from_slice(&crc16(&body[..usize::from(len)]).to_le_bytes());
    v
}

/// One handle's content for a tracking reply.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Record {
    /// Transform: `[q0,qx,qy,qz]`, translation (mm), RMS (mm).
    Transform {
        /// Quaternion.
        q: [f64; 4],
        /// Translation (mm).
        t: [f64; 3],
        /// RMS.
        rms: f64,
    },
    /// `MISSING`.
    Missing,
    /// `DISABLED`.
    Disabled,
}

/// One handle in a tracking reply.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandleOut {
    /// Handle.
    pub handle: u8,
    /// Content.
    pub record: Record,
    /// Port status bits.
    pub port_status: u32,
    /// Frame number.
    pub frame: u32,
}

/// `BX` body for option 0x0001 (0x0800 changes nothing in the layout).
pub fn bx_body(handles: &[HandleOut], system_status: u16) -> Vec<u8> {
    let mut v = vec![handles.len() as u8];
    for h in handles {
        v.push(h.handle);
        match h.record {
            Record::Transform { q, t, rms } => {
                v.push(0x01);
                for x in q.iter().chain(t.iter()).chain(std::iter::once(&rms)) {
                    v.extend_from_slice(&(*x as f32).to_le_bytes());
                }
            }
            Record::Missing => v.push(0x02),
            Record::Disabled => {
                v.push(0x04);
                continue;
            }
        }
        v.extend_from_slice(&h.port_status.to_le_bytes());
        v.extend_from_slice(&h.frame.to_le_bytes());
    }
    v.extend_from_slice(&system_status.to_le_bytes());
    v
}

fn signed(value: f64, scale: f64, digits: usize) -> String {
    let max = 10f64.powi(digits as i32) - 1.0;
    let n = (value / scale).round().clamp(-max, max);
    let sign = if n < 0.0 { '-' } else { '+' };
    format!("{sign}{:0width$}", n.abs() as u64, width = digits)
}

/// `TX` reply text for option 0x0001 (before CRC).
pub fn tx_text(handles: &[HandleOut], system_status: u16) -> String {
    let mut s = format!("{:02X}", handles.len());
    for h in handles {
        s.push_str(&format!("{:02X}", h.handle));
        match h.record {
            Record::Transform { q, t, rms } => {
                for x in q {
                    s.push_str(&signed(x, 1e-4, 5));
                }
                for x in t {
                    s.push_str(&signed(x, 1e-2, 6));
                }
                s.push_str(&signed(rms, 1e-4, 5));
            }
            Record::Missing => s.push_str("MISSING"),
            Record::Disabled => {
                s.push_str("DISABLED\n");
                continue;
            }
        }
        s.push_str(&format!("{:08X}{:08X}\n", h.port_status, h.frame));
    }
    s.push_str(&format!("{system_status:04X}"));
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_matches_literals_from_ndicapi() {
        // Literals embedded in ndicapi.cxx / quoted in docs/protocols.md §4.2.
        assert_eq!(crc16(b"INIT:"), 0xE3A5);
        assert_eq!(crc16(b"OKAY"), 0xA896);
        assert_eq!(crc16(b"RESET"), 0xBE6F);
        assert_eq!(crc16(b"VER:0"), 0x65EE);
        assert_eq!(crc16(b"PHRQ:*********1****"), 0xA4C1);
        assert_eq!(crc16(b"BX:0801"), 0x00EC);
        assert_eq!(crc16(b"ERROR01"), 0x6BC2);
    }

    #[test]
    fn parses_both_command_forms() {
        assert_eq!(
            parse_command(b"PINIT:0a31EA").map(|c| c.params),
            Err(CommandError::BadCrc),
            "CRC covers the lower-case text"
        );
        let crc = crc16(b"PINIT:0a");
        let line = format!("PINIT:0a{crc:04x}");
        let c = parse_command(line.as_bytes()).unwrap();
        assert_eq!((c.word.as_str(), c.params.as_str()), ("PINIT", "0a"));
        let c = parse_command(b"VER 0").unwrap();
        assert_eq!((c.word.as_str(), c.params.as_str()), ("VER", "0"));
        assert_eq!(parse_command(b"INIT:E3A5").unwrap().params, "");
        assert_eq!(parse_command(b"INIT:E3A6"), Err(CommandError::BadCrc));
        assert_eq!(parse_command(b"init:"), Err(CommandError::Invalid));
    }

    #[test]
    fn okay_and_error_literals() {
        assert_eq!(text_reply("OKAY"), b"OKAYA896\r");
        assert_eq!(error_reply(1), b"ERROR016BC2\r");
    }

    #[test]
    fn bx_one_valid_handle_is_53_bytes() {
        let h = HandleOut {
            handle: 1,
            record: Record::Transform {
                q: [1.0, 0.0, 0.0, 0.0],
                t: [1.0, 2.0, 3.0],
                rms: 0.1,
            },
            port_status: 0x31,
            frame: 7,
        };
        let wire = binary_reply(&bx_body(&[h], 0));
        assert_eq!(wire.len(), 53);
        assert_eq!(&wire[..4], &[0xC4, 0xA5, 45, 0]);
        // CRC-16/ARC of a header followed by its own LE CRC is zero (ndicapi relies on it).
        assert_eq!(crc16(&wire[..6]), 0);
    }

    #[test]
    fn tx_matches_the_documented_example() {
        // docs/protocols.md §4.5 example line.
        let h = HandleOut {
            handle: 1,
            record: Record::Transform {
                q: [1.0, 0.0, 0.0, 0.0],
                t: [-12.34, 5.0, -1987.0],
                rms: 0.0123,
            },
            port_status: 0x31,
            frame: 0xA1B2,
        };
        assert_eq!(
            tx_text(&[h], 0),
            "0101+10000+00000+00000+00000-001234+000500-198700+00123000000310000A1B2\n0000"
        );
    }
}
