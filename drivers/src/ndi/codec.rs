//! Byte-level encoding and decoding of the NDI Combined API (no I/O).
//!
//! * Commands: `<CMD>:<params><CRC16 4 hex>\r` when a `:` follows the command word, else
//!   `<CMD> <params>\r` without CRC (the older form).
//! * Text replies: `<text><CRC16 4 hex>\r` (multi-line replies separate lines with `\n`).
//! * Binary replies (`BX`): `C4 A5`, u16 LE body length, u16 LE header CRC (of the 4 bytes
//!   before it), body, u16 LE body CRC.
//! * CRC: CRC-16/ARC (poly 0x8005 reflected, init 0, no final XOR) over every byte before it.

use super::frame::{HandleRecord, HandleState, PortHandleStatus, Reply, TrackingReply};

/// Longest text reply accepted before the decoder gives up (bytes, excluding `\r`).
pub const MAX_TEXT_REPLY: usize = 16 * 1024;

/// CRC-16/ARC of `data`.
pub fn crc16(data: &[u8]) -> u16 {
    crc16_update(0, data)
}

/// Continue a CRC-16/ARC over more bytes.
pub fn crc16_update(mut crc: u16, data: &[u8]) -> u16 {
    for &b in data {
        crc ^= u16::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xA001
            } else {
                crc >> 1
            };
        }
    }
    crc
}

/// The command word: the leading run of `A-Z0-9`.
pub fn command_word(command: &str) -> &str {
    let end = command
        .bytes()
        .position(|b| !(b.is_ascii_uppercase() || b.is_ascii_digit()))
        .unwrap_or(command.len());
    &command[..end]
}

/// Whether the device answers `command` with a binary reply.
pub fn is_binary_command(command: &str) -> bool {
    matches!(command_word(command), "BX" | "BX2" | "GETLOG" | "VGET")
}

/// Encode a command for the wire: appends the CRC when a `:` follows the command word,
/// then `\r`.
pub fn encode_command(command: &str) -> Vec<u8> {
    let word = command_word(command);
    let mut out = command.as_bytes().to_vec();
    if command.as_bytes().get(word.len()) == Some(&b':') {
        out.extend_from_slice(format!("{:04X}", crc16(command.as_bytes())).as_bytes());
    }
    out.push(b'\r');
    out
}

/// Why a reply could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum DecodeError {
    /// CRC mismatch.
    #[error("bad CRC: sent {sent:04X}, computed {computed:04X}")]
    BadCrc {
        /// CRC on the wire.
        sent: u16,
        /// CRC of the received bytes.
        computed: u16,
    },
    /// Structurally wrong bytes.
    #[error("{0}")]
    Malformed(String),
}

/// Outcome of one decoding attempt over a receive buffer.
#[derive(Debug, Clone, PartialEq)]
pub enum Decoded {
    /// Not enough bytes yet.
    Incomplete,
    /// Bytes before a recognisable reply start that were skipped (binary mode resync);
    /// drop `skip` bytes and decode again.
    Garbage {
        /// Bytes to drop.
        skip: usize,
    },
    /// A reply that used `consumed` bytes.
    Reply {
        /// The reply.
        reply: Reply,
        /// Bytes used.
        consumed: usize,
    },
    /// A complete but invalid reply that used `consumed` bytes.
    Invalid {
        /// Why.
        error: DecodeError,
        /// Bytes used.
        consumed: usize,
    },
}

/// Decode one reply from the front of `buf`. `binary` says whether the pending command has
/// a binary reply (then an `ERROR`/text reply is still recognised).
pub fn decode_reply(buf: &[u8], binary: bool) -> Decoded {
    if buf.is_empty() {
        return Decoded::Incomplete;
    }
    if binary {
        if buf[0] == 0xC4 {
            if buf.len() < 2 {
                return Decoded::Incomplete;
            }
            if buf[1] == 0xA5 {
                return decode_binary(buf);
            }
        }
        if !buf[0].is_ascii_uppercase() {
            // Resynchronise: skip to the next possible start (C4 A5 or an upper-case letter).
            let skip = buf
                .iter()
                .skip(1)
                .position(|&b| b == 0xC4 || b.is_ascii_uppercase())
                .map_or(buf.len(), |p| p + 1);
            return Decoded::Garbage { skip };
        }
    }
    decode_text(buf)
}

fn decode_binary(buf: &[u8]) -> Decoded {
    if buf.len() < 6 {
        return Decoded::Incomplete;
    }
    let header_crc = u16::from_le_bytes([buf[4], buf[5]]);
    let computed = crc16(&buf[..4]);
    if header_crc != computed {
        // Not a real header (or corrupted): skip the start byte and look further.
        return Decoded::Garbage { skip: 1 };
    }
    let len = usize::from(u16::from_le_bytes([buf[2], buf[3]]));
    let total = 6 + len + 2;
    if buf.len() < total {
        return Decoded::Incomplete;
    }
    let body = &buf[6..6 + len];
    let sent = u16::from_le_bytes([buf[6 + len], buf[7 + len]]);
    let computed = crc16(body);
    if sent != computed {
        return Decoded::Invalid {
            error: DecodeError::BadCrc { sent, computed },
            consumed: total,
        };
    }
    Decoded::Reply {
        reply: Reply::Binary(body.to_vec()),
        consumed: total,
    }
}

fn decode_text(buf: &[u8]) -> Decoded {
    let Some(end) = buf.iter().position(|&b| b == b'\r') else {
        if buf.len() > MAX_TEXT_REPLY {
            return Decoded::Invalid {
                error: DecodeError::Malformed(format!("no CR within {MAX_TEXT_REPLY} bytes")),
                consumed: buf.len(),
            };
        }
        return Decoded::Incomplete;
    };
    let consumed = end + 1;
    let line = &buf[..end];
    let invalid = |msg: String| Decoded::Invalid {
        error: DecodeError::Malformed(msg),
        consumed,
    };
    if line.len() < 4 {
        return invalid(format!("reply too short ({} bytes)", line.len()));
    }
    if !line
        .iter()
        .all(|&b| b == b'\n' || (0x20..0x7F).contains(&b))
    {
        return invalid("non-ASCII bytes in a text reply".into());
    }
    let (text, crc_hex) = line.split_at(line.len() - 4);
    let Some(sent) = parse_hex_u32(crc_hex).map(|v| v as u16) else {
        return invalid("reply CRC is not 4 hex digits".into());
    };
    let computed = crc16(text);
    if sent != computed {
        return Decoded::Invalid {
            error: DecodeError::BadCrc { sent, computed },
            consumed,
        };
    }
    // ASCII was checked above.
    let text = String::from_utf8_lossy(text).into_owned();
    let reply = if text == "OKAY" {
        Reply::Okay
    } else if text == "RESET" {
        Reply::Reset
    } else if let Some(code) = text.strip_prefix("ERROR") {
        match (code.len(), parse_hex_u32(code.as_bytes())) {
            (2, Some(c)) => Reply::Error(c as u8),
            _ => return invalid(format!("bad ERROR reply `{text}`")),
        }
    } else {
        Reply::Text(text)
    };
    Decoded::Reply { reply, consumed }
}

/// Parse ASCII hex digits (either case) of at most 8 digits.
pub fn parse_hex_u32(digits: &[u8]) -> Option<u32> {
    if digits.is_empty() || digits.len() > 8 {
        return None;
    }
    let mut v: u32 = 0;
    for &d in digits {
        v = (v << 4) | (d as char).to_digit(16)?;
    }
    Some(v)
}

/// Reply option bits this decoder understands for `BX` / `TX`.
pub const SUPPORTED_OPTIONS: u16 = 0x0001 | 0x0800;

fn check_options(options: u16) -> Result<(), DecodeError> {
    if options & !SUPPORTED_OPTIONS != 0 || options & 0x0001 == 0 {
        return Err(DecodeError::Malformed(format!(
            "reply option {options:04X} not supported (only 0001 with optional 0800)"
        )));
    }
    Ok(())
}

struct Cursor<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], DecodeError> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.buf.len());
        let end = end.ok_or_else(|| {
            DecodeError::Malformed(format!(
                "body ends at {} while reading {n} bytes at {}",
                self.buf.len(),
                self.pos
            ))
        })?;
        let s = &self.buf[self.pos..end];
        self.pos = end;
        Ok(s)
    }
    fn u8(&mut self) -> Result<u8, DecodeError> {
        Ok(self.take(1)?[0])
    }
    fn u16(&mut self) -> Result<u16, DecodeError> {
        let b = self.take(2)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }
    fn u32(&mut self) -> Result<u32, DecodeError> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn f32(&mut self) -> Result<f64, DecodeError> {
        Ok(f64::from(f32::from_bits(self.u32()?)))
    }
}

/// Decode a `BX` body (the bytes between header and body CRC) sent for reply `options`.
pub fn parse_bx(body: &[u8], options: u16) -> Result<TrackingReply, DecodeError> {
    check_options(options)?;
    let mut c = Cursor { buf: body, pos: 0 };
    let count = c.u8()?;
    let mut handles = Vec::with_capacity(usize::from(count));
    for _ in 0..count {
        let handle = c.u8()?;
        let status = c.u8()?;
        let state = match status {
            0x01 => {
                let mut v = [0.0; 8];
                for x in &mut v {
                    *x = c.f32()?;
                }
                HandleState::Valid {
                    q: [v[0], v[1], v[2], v[3]],
                    t: [v[4], v[5], v[6]],
                    rms: v[7],
                }
            }
            0x02 => HandleState::Missing,
            0x04 => HandleState::Disabled,
            other => {
                return Err(DecodeError::Malformed(format!(
                    "handle {handle:02X}: unknown handle status {other:02X}"
                )))
            }
        };
        let (port_status, frame) = if state == HandleState::Disabled {
            (0, 0)
        } else {
            (c.u32()?, c.u32()?)
        };
        handles.push(HandleRecord {
            handle,
            state,
            port_status,
            frame,
        });
    }
    let system_status = c.u16()?;
    if c.pos != body.len() {
        return Err(DecodeError::Malformed(format!(
            "{} trailing bytes after the system status",
            body.len() - c.pos
        )));
    }
    Ok(TrackingReply {
        handles,
        system_status,
    })
}

fn hex_field(s: &[u8], what: &str) -> Result<u32, DecodeError> {
    parse_hex_u32(s).ok_or_else(|| {
        DecodeError::Malformed(format!(
            "{what}: `{}` is not hex",
            String::from_utf8_lossy(s)
        ))
    })
}

/// Parse a signed fixed-point field such as `+10000` (5 digits) with `scale` units per digit.
fn signed_field(s: &[u8], scale: f64, what: &str) -> Result<f64, DecodeError> {
    let bad = || {
        DecodeError::Malformed(format!(
            "{what}: `{}` is not a signed decimal",
            String::from_utf8_lossy(s)
        ))
    };
    let (sign, digits) = match s.split_first() {
        Some((b'+', d)) => (1.0, d),
        Some((b'-', d)) => (-1.0, d),
        _ => return Err(bad()),
    };
    if digits.is_empty() || !digits.iter().all(u8::is_ascii_digit) {
        return Err(bad());
    }
    let v: u64 = std::str::from_utf8(digits)
        .ok()
        .and_then(|d| d.parse().ok())
        .ok_or_else(bad)?;
    Ok(sign * v as f64 * scale)
}

/// Decode a `TX` reply text (CRC already stripped) sent for reply `options`.
pub fn parse_tx(text: &str, options: u16) -> Result<TrackingReply, DecodeError> {
    check_options(options)?;
    let b = text.as_bytes();
    if b.len() < 2 {
        return Err(DecodeError::Malformed(
            "TX reply shorter than its count".into(),
        ));
    }
    let count = hex_field(&b[..2], "handle count")?;
    let mut lines = b[2..].split(|&c| c == b'\n');
    let mut handles = Vec::new();
    for _ in 0..count {
        let line = lines.next().ok_or_else(|| {
            DecodeError::Malformed("TX reply has fewer lines than handles".into())
        })?;
        if line.len() < 2 {
            return Err(DecodeError::Malformed("TX handle line too short".into()));
        }
        let handle = hex_field(&line[..2], "handle")? as u8;
        let rest = &line[2..];
        let (state, rest) = if rest.starts_with(b"UNOCCUPIED") {
            continue;
        } else if let Some(r) = rest.strip_prefix(b"MISSING") {
            (HandleState::Missing, r)
        } else if let Some(r) = rest.strip_prefix(b"DISABLED") {
            (HandleState::Disabled, r)
        } else {
            if rest.len() < 51 {
                return Err(DecodeError::Malformed(format!(
                    "handle {handle:02X}: transform shorter than 51 characters"
                )));
            }
            let f = |a: usize, n: usize, scale: f64, what: &str| {
                signed_field(&rest[a..a + n], scale, what)
            };
            let q = [
                f(0, 6, 1e-4, "q0")?,
                f(6, 6, 1e-4, "qx")?,
                f(12, 6, 1e-4, "qy")?,
                f(18, 6, 1e-4, "qz")?,
            ];
            let t = [
                f(24, 7, 1e-2, "tx")?,
                f(31, 7, 1e-2, "ty")?,
                f(38, 7, 1e-2, "tz")?,
            ];
            let rms = f(45, 6, 1e-4, "rms")?;
            (HandleState::Valid { q, t, rms }, &rest[51..])
        };
        let (port_status, frame) = if rest.len() >= 16 {
            (
                hex_field(&rest[..8], "port status")?,
                hex_field(&rest[8..16], "frame number")?,
            )
        } else if rest.is_empty() && state == HandleState::Disabled {
            (0, 0)
        } else {
            return Err(DecodeError::Malformed(format!(
                "handle {handle:02X}: port status / frame number missing"
            )));
        };
        handles.push(HandleRecord {
            handle,
            state,
            port_status,
            frame,
        });
    }
    let status_line = lines
        .next()
        .ok_or_else(|| DecodeError::Malformed("TX reply lacks the system status".into()))?;
    if status_line.len() != 4 {
        return Err(DecodeError::Malformed(format!(
            "system status `{}` is not 4 hex digits",
            String::from_utf8_lossy(status_line)
        )));
    }
    let system_status = hex_field(status_line, "system status")? as u16;
    if lines.next().is_some() {
        return Err(DecodeError::Malformed(
            "text after the system status".into(),
        ));
    }
    Ok(TrackingReply {
        handles,
        system_status,
    })
}

/// Decode a `PHSR` reply: `NN` then `HHSSS` per handle.
pub fn parse_phsr(text: &str) -> Result<Vec<PortHandleStatus>, DecodeError> {
    let b = text.as_bytes();
    if b.len() < 2 {
        return Err(DecodeError::Malformed("PHSR reply too short".into()));
    }
    let n = hex_field(&b[..2], "PHSR count")? as usize;
    if b.len() != 2 + 5 * n {
        return Err(DecodeError::Malformed(format!(
            "PHSR reply has {} characters for {n} handles",
            b.len()
        )));
    }
    (0..n)
        .map(|i| {
            let e = &b[2 + 5 * i..7 + 5 * i];
            Ok(PortHandleStatus {
                handle: hex_field(&e[..2], "PHSR handle")? as u8,
                status: hex_field(&e[2..], "PHSR status")? as u16,
            })
        })
        .collect()
}

/// Decode a `PHRQ` reply: the new handle as 2 hex digits.
pub fn parse_phrq(text: &str) -> Result<u8, DecodeError> {
    let b = text.as_bytes();
    if b.len() != 2 {
        return Err(DecodeError::Malformed(format!(
            "PHRQ reply `{text}` is not 2 hex digits"
        )));
    }
    Ok(hex_field(b, "PHRQ handle")? as u8)
}

/// The `PVWR` commands that load a tool definition (`.rom`) into `handle`: 64-byte chunks,
/// the last zero-padded, addresses 0000, 0040, ...
pub fn pvwr_commands(handle: u8, rom: &[u8]) -> Vec<String> {
    rom.chunks(64)
        .enumerate()
        .map(|(i, chunk)| {
            let mut s = format!("PVWR:{handle:02X}{:04X}", i * 64);
            for k in 0..64 {
                s.push_str(&format!("{:02X}", chunk.get(k).copied().unwrap_or(0)));
            }
            s
        })
        .collect()
}
