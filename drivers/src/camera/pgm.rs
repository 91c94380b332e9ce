//! PGM (Netpbm grey map): `P5` binary and `P2` ASCII, maxval 1..=65535 (16-bit samples are
//! big-endian and scaled to 8 bits). No I/O.

/// Largest image accepted (pixels).
pub const MAX_PIXELS: u64 = 64 * 1024 * 1024;

/// Why a PGM could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("PGM: {0}")]
pub struct PgmError(pub String);

fn bad<T>(m: impl Into<String>) -> Result<T, PgmError> {
    Err(PgmError(m.into()))
}

struct Header<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl Header<'_> {
    fn skip_space(&mut self) {
        while self.pos < self.buf.len() {
            match self.buf[self.pos] {
                b' ' | b'\t' | b'\n' | b'\r' | 0x0B | 0x0C => self.pos += 1,
                b'#' => {
                    while self.pos < self.buf.len() && self.buf[self.pos] != b'\n' {
                        self.pos += 1;
                    }
                }
                _ => break,
            }
        }
    }
    fn number(&mut self, what: &str) -> Result<u64, PgmError> {
        self.skip_space();
        let start = self.pos;
        while self.pos < self.buf.len()
            && self.buf[self.pos].is_ascii_digit()
            && self.pos - start < 12
        {
            self.pos += 1;
        }
        if start == self.pos {
            return bad(format!("expected {what}"));
        }
        std::str::from_utf8(&self.buf[start..self.pos])
            .ok()
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| PgmError(format!("bad {what}")))
    }
}

/// Decode a PGM file: `(width, height, 8-bit pixels row-major)`.
pub fn decode(buf: &[u8]) -> Result<(u32, u32, Vec<u8>), PgmError> {
    let ascii = match buf.get(..2) {
        Some(b"P5") => false,
        Some(b"P2") => true,
        _ => return bad("not a PGM (magic P5 or P2 expected)"),
    };
    let mut h = Header { buf, pos: 2 };
    let width = h.number("width")?;
    let height = h.number("height")?;
    let maxval = h.number("maxval")?;
    if width == 0 || height == 0 || width.saturating_mul(height) > MAX_PIXELS {
        return bad(format!("size {width}x{height} out of range"));
    }
    if maxval == 0 || maxval > 65535 {
        return bad(format!("maxval {maxval} out of range"));
    }
    let n = (width * height) as usize;
    let scale = |v: u64| -> Result<u8, PgmError> {
        if v > maxval {
            return bad(format!("sample {v} above maxval {maxval}"));
        }
        Ok(((v * 255 + maxval / 2) / maxval) as u8)
    };
    let mut out = Vec::with_capacity(n.min(buf.len()));
    if ascii {
        for _ in 0..n {
            out.push(scale(h.number("sample")?)?);
        }
    } else {
        // Exactly one whitespace byte after maxval.
        if h.pos >= buf.len() || !buf[h.pos].is_ascii_whitespace() {
            return bad("missing whitespace after maxval");
        }
        let data = &buf[h.pos + 1..];
        let bytes_per = if maxval > 255 { 2 } else { 1 };
        if data.len() < n * bytes_per {
            return bad(format!("{} data bytes for {n} pixels", data.len()));
        }
        for i in 0..n {
            let v = if bytes_per == 2 {
                u64::from(u16::from_be_bytes([data[2 * i], data[2 * i + 1]]))
            } else {
                u64::from(data[i])
            };
            out.push(scale(v)?);
        }
    }
    Ok((width as u32, height as u32, out))
}

/// Encode 8-bit pixels as a binary `P5` file.
pub fn encode(width: u32, height: u32, data: &[u8]) -> Vec<u8> {
    let mut v = format!("P5\n{width} {height}\n255\n").into_bytes();
    v.extend_from_slice(data);
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn literal_p2_and_p5() {
        // Netpbm PGM: "P2", comment, width height, maxval, samples.
        let p2 = b"P2\n# tiny\n3 2\n15\n0 15 3\n6 9 12\n";
        let (w, h, d) = decode(p2).unwrap();
        assert_eq!((w, h), (3, 2));
        assert_eq!(d, vec![0, 255, 51, 102, 153, 204]);
        let p5 = encode(2, 2, &[1, 2, 3, 250]);
        assert_eq!(&p5[..11], b"P5\n2 2\n255\n");
        assert_eq!(decode(&p5).unwrap(), (2, 2, vec![1, 2, 3, 250]));
        let p16 = [b"P5 1 1 65535\n".as_slice(), &[0xFF, 0xFF]].concat();
        assert_eq!(decode(&p16).unwrap().2, vec![255]);
    }

    #[test]
    fn malformed_files_are_errors() {
        assert!(decode(b"P6\n1 1\n255\n\0\0\0").is_err());
        assert!(decode(b"P5\n2 2\n255\n\x01").is_err(), "short data");
        assert!(decode(b"P5\n0 2\n255\n").is_err());
        assert!(decode(b"P5\n99999999 99999999\n255\n").is_err());
        assert!(decode(b"P2\n1 1\n10\n11\n").is_err(), "sample above maxval");
        assert!(decode(b"P5").is_err());
    }

    #[test]
    fn survives_100k_random_and_mutated_inputs() {
        // Deterministic xorshift: no extra dev-dependency in the library tests.
        let mut s: u64 = 0x5047_4D21;
        let mut rnd = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        let seed = encode(4, 3, &[7; 12]);
        for i in 0..100_000 {
            let mut v = if i % 2 == 0 {
                seed.clone()
            } else {
                b"P2\n2 2\n255\n1 2 3 4\n".to_vec()
            };
            for _ in 0..(rnd() % 4 + 1) {
                let r = rnd() as usize;
                match r % 3 {
                    0 if !v.is_empty() => {
                        let i = r / 3 % v.len();
                        v[i] = (r >> 20) as u8;
                    }
                    1 => v.truncate(r / 3 % (v.len() + 1)),
                    _ => v.insert(r / 3 % (v.len() + 1), (r >> 24) as u8),
                }
            }
            if let Ok((w, h, d)) = decode(&v) {
                assert_eq!(d.len(), (w * h) as usize);
                assert!(d.len() <= v.len() * 2);
            }
        }
    }
}
