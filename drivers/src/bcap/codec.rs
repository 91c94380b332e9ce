//! b-CAP bytes ↔ packets (no I/O). All little-endian. Every count and length is checked
//! against the bytes actually present before anything is allocated, and packets are capped at
//! [`MAX_PACKET`], so hostile input cannot cause large allocations.

use super::frame::{vt, Packet, Variant, EOT, MAX_DEPTH, MAX_PACKET, MIN_PACKET, SOH};
use bytes::{BufMut, BytesMut};

/// A malformed b-CAP packet.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CodecError {
    /// First byte is not SOH.
    #[error("packet does not start with SOH (0x{0:02x})")]
    NoSoh(u8),
    /// The peer speaks another protocol (HTTP, a text banner): the wrong port or service.
    #[error(
        "the device answered with {0}, not b-CAP: wrong port? (an RC8 serves b-CAP on TCP 5007)"
    )]
    NotBcap(String),
    /// Length field outside [16, MAX_PACKET].
    #[error("packet length {0} outside [16, {MAX_PACKET}]")]
    BadLength(u32),
    /// Last byte is not EOT.
    #[error("packet does not end with EOT (0x{0:02x})")]
    NoEot(u8),
    /// Argument / VARIANT layout does not fit the packet.
    #[error("malformed arguments: {0}")]
    BadArgs(String),
    /// A VARIANT type this codec does not know.
    #[error("unsupported VARIANT type 0x{0:04x}")]
    UnsupportedType(u16),
    /// BSTR that is not valid UTF-16.
    #[error("BSTR is not valid UTF-16")]
    BadString,
    /// Packet too large to encode.
    #[error("packet of {0} bytes exceeds the {MAX_PACKET}-byte cap")]
    TooLarge(usize),
    /// Transport failure.
    #[error("i/o: {0}")]
    Io(#[from] std::io::Error),
}

struct Rd<'a> {
    b: &'a [u8],
}

impl<'a> Rd<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], CodecError> {
        if self.b.len() < n {
            return Err(CodecError::BadArgs(format!(
                "need {n} bytes, {} left",
                self.b.len()
            )));
        }
        let (h, t) = self.b.split_at(n);
        self.b = t;
        Ok(h)
    }
    fn u16(&mut self) -> Result<u16, CodecError> {
        Ok(u16::from_le_bytes(self.take(2)?.try_into().expect("2")))
    }
    fn u32(&mut self) -> Result<u32, CodecError> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().expect("4")))
    }
    fn u64(&mut self) -> Result<u64, CodecError> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().expect("8")))
    }
    /// `count` elements of `size` bytes each must fit in what is left.
    fn check_count(&self, count: u32, size: usize) -> Result<usize, CodecError> {
        let n = count as usize;
        if n.saturating_mul(size) > self.b.len() {
            return Err(CodecError::BadArgs(format!(
                "array of {n} x {size} bytes exceeds the {} bytes left",
                self.b.len()
            )));
        }
        Ok(n)
    }
    fn bstr(&mut self) -> Result<String, CodecError> {
        let len = self.u32()? as usize;
        if !len.is_multiple_of(2) {
            return Err(CodecError::BadString);
        }
        let raw = self.take(len)?;
        let units: Vec<u16> = raw
            .chunks_exact(2)
            .map(|c| u16::from_le_bytes([c[0], c[1]]))
            .collect();
        String::from_utf16(&units).map_err(|_| CodecError::BadString)
    }
}

fn put_bstr(dst: &mut Vec<u8>, s: &str) {
    let units: Vec<u16> = s.encode_utf16().collect();
    dst.extend_from_slice(&((units.len() * 2) as u32).to_le_bytes());
    for u in units {
        dst.extend_from_slice(&u.to_le_bytes());
    }
}

/// Encode one VARIANT (vt, count, data) without the top-level length prefix.
pub fn encode_variant(v: &Variant, dst: &mut Vec<u8>) {
    fn head(dst: &mut Vec<u8>, t: u16, n: usize) {
        dst.extend_from_slice(&t.to_le_bytes());
        dst.extend_from_slice(&(n as u32).to_le_bytes());
    }
    match v {
        Variant::Empty => head(dst, vt::EMPTY, 1),
        Variant::Null => head(dst, vt::NULL, 1),
        Variant::I2(x) => {
            head(dst, vt::I2, 1);
            dst.extend_from_slice(&x.to_le_bytes())
        }
        Variant::I4(x) => {
            head(dst, vt::I4, 1);
            dst.extend_from_slice(&x.to_le_bytes())
        }
        Variant::R4(x) => {
            head(dst, vt::R4, 1);
            dst.extend_from_slice(&x.to_le_bytes())
        }
        Variant::R8(x) => {
            head(dst, vt::R8, 1);
            dst.extend_from_slice(&x.to_le_bytes())
        }
        Variant::Cy(x) => {
            head(dst, vt::CY, 1);
            dst.extend_from_slice(&x.to_le_bytes())
        }
        Variant::Date(x) => {
            head(dst, vt::DATE, 1);
            dst.extend_from_slice(&x.to_le_bytes())
        }
        Variant::Bstr(s) => {
            head(dst, vt::BSTR, 1);
            put_bstr(dst, s)
        }
        Variant::Error(x) => {
            head(dst, vt::ERROR, 1);
            dst.extend_from_slice(&x.to_le_bytes())
        }
        Variant::Bool(b) => {
            head(dst, vt::BOOL, 1);
            dst.extend_from_slice(&(if *b { -1i16 } else { 0 }).to_le_bytes())
        }
        Variant::Ui1(x) => {
            head(dst, vt::UI1, 1);
            dst.push(*x)
        }
        Variant::Ui2(x) => {
            head(dst, vt::UI2, 1);
            dst.extend_from_slice(&x.to_le_bytes())
        }
        Variant::Ui4(x) => {
            head(dst, vt::UI4, 1);
            dst.extend_from_slice(&x.to_le_bytes())
        }
        Variant::I8(x) => {
            head(dst, vt::I8, 1);
            dst.extend_from_slice(&x.to_le_bytes())
        }
        Variant::Ui8(x) => {
            head(dst, vt::UI8, 1);
            dst.extend_from_slice(&x.to_le_bytes())
        }
        Variant::I2Array(a) => {
            head(dst, vt::I2 | vt::ARRAY, a.len());
            a.iter()
                .for_each(|x| dst.extend_from_slice(&x.to_le_bytes()))
        }
        Variant::I4Array(a) => {
            head(dst, vt::I4 | vt::ARRAY, a.len());
            a.iter()
                .for_each(|x| dst.extend_from_slice(&x.to_le_bytes()))
        }
        Variant::R4Array(a) => {
            head(dst, vt::R4 | vt::ARRAY, a.len());
            a.iter()
                .for_each(|x| dst.extend_from_slice(&x.to_le_bytes()))
        }
        Variant::R8Array(a) => {
            head(dst, vt::R8 | vt::ARRAY, a.len());
            a.iter()
                .for_each(|x| dst.extend_from_slice(&x.to_le_bytes()))
        }
        Variant::BstrArray(a) => {
            head(dst, vt::BSTR | vt::ARRAY, a.len());
            a.iter().for_each(|s| put_bstr(dst, s))
        }
        Variant::BoolArray(a) => {
            head(dst, vt::BOOL | vt::ARRAY, a.len());
            a.iter()
                .for_each(|b| dst.extend_from_slice(&(if *b { -1i16 } else { 0 }).to_le_bytes()))
        }
        Variant::Ui1Array(a) => {
            head(dst, vt::UI1 | vt::ARRAY, a.len());
            dst.extend_from_slice(a)
        }
        Variant::VariantArray(a) => {
            head(dst, vt::VARIANT | vt::ARRAY, a.len());
            a.iter().for_each(|v| encode_variant(v, dst))
        }
    }
}

fn decode_variant(r: &mut Rd<'_>, depth: usize) -> Result<Variant, CodecError> {
    if depth > MAX_DEPTH {
        return Err(CodecError::BadArgs("VARIANT arrays nested too deep".into()));
    }
    let t = r.u16()?;
    let count = r.u32()?;
    macro_rules! arr {
        ($size:expr, $conv:expr) => {{
            let n = r.check_count(count, $size)?;
            let raw = r.take(n * $size)?;
            raw.chunks_exact($size).map($conv).collect()
        }};
    }
    if t & vt::ARRAY == 0 {
        if count != 1 {
            return Err(CodecError::BadArgs(format!(
                "scalar VARIANT 0x{t:04x} with count {count}"
            )));
        }
        return Ok(match t {
            vt::EMPTY => Variant::Empty,
            vt::NULL => Variant::Null,
            vt::I2 => Variant::I2(r.u16()? as i16),
            vt::I4 => Variant::I4(r.u32()? as i32),
            vt::R4 => Variant::R4(f32::from_bits(r.u32()?)),
            vt::R8 => Variant::R8(f64::from_bits(r.u64()?)),
            vt::CY => Variant::Cy(r.u64()? as i64),
            vt::DATE => Variant::Date(f64::from_bits(r.u64()?)),
            vt::BSTR => Variant::Bstr(r.bstr()?),
            vt::ERROR => Variant::Error(r.u32()? as i32),
            vt::BOOL => Variant::Bool(r.u16()? != 0),
            vt::UI1 => Variant::Ui1(r.take(1)?[0]),
            vt::UI2 => Variant::Ui2(r.u16()?),
            vt::UI4 => Variant::Ui4(r.u32()?),
            vt::I8 => Variant::I8(r.u64()? as i64),
            vt::UI8 => Variant::Ui8(r.u64()?),
            other => return Err(CodecError::UnsupportedType(other)),
        });
    }
    Ok(match t & !vt::ARRAY {
        vt::I2 => Variant::I2Array(arr!(2, |c: &[u8]| i16::from_le_bytes([c[0], c[1]]))),
        vt::I4 => Variant::I4Array(arr!(4, |c: &[u8]| i32::from_le_bytes(
            c.try_into().expect("4")
        ))),
        vt::R4 => Variant::R4Array(arr!(4, |c: &[u8]| f32::from_le_bytes(
            c.try_into().expect("4")
        ))),
        vt::R8 => Variant::R8Array(arr!(8, |c: &[u8]| f64::from_le_bytes(
            c.try_into().expect("8")
        ))),
        vt::BOOL => Variant::BoolArray(arr!(2, |c: &[u8]| c[0] != 0 || c[1] != 0)),
        vt::UI1 => Variant::Ui1Array(arr!(1, |c: &[u8]| c[0])),
        vt::BSTR => {
            // Each BSTR needs at least its 4-byte length.
            let n = r.check_count(count, 4)?;
            let mut v = Vec::with_capacity(n);
            for _ in 0..n {
                v.push(r.bstr()?);
            }
            Variant::BstrArray(v)
        }
        vt::VARIANT => {
            // Each nested VARIANT needs at least its 6-byte head.
            let n = r.check_count(count, 6)?;
            let mut v = Vec::with_capacity(n);
            for _ in 0..n {
                v.push(decode_variant(r, depth + 1)?);
            }
            Variant::VariantArray(v)
        }
        other => return Err(CodecError::UnsupportedType(other | vt::ARRAY)),
    })
}

/// Decode one VARIANT from exactly `bytes` (testing / fuzzing helper).
pub fn decode_variant_exact(bytes: &[u8]) -> Result<Variant, CodecError> {
    let mut r = Rd { b: bytes };
    let v = decode_variant(&mut r, 0)?;
    if !r.b.is_empty() {
        return Err(CodecError::BadArgs(format!("{} trailing bytes", r.b.len())));
    }
    Ok(v)
}

/// Encode a packet (TCP form: no CRC).
pub fn encode_packet(p: &Packet, dst: &mut BytesMut) -> Result<(), CodecError> {
    let mut body = Vec::new();
    for a in &p.args {
        let mut v = Vec::new();
        encode_variant(a, &mut v);
        body.extend_from_slice(&(v.len() as u32).to_le_bytes());
        body.extend_from_slice(&v);
    }
    let total = MIN_PACKET + body.len();
    if total > MAX_PACKET || p.args.len() > u16::MAX as usize {
        return Err(CodecError::TooLarge(total));
    }
    dst.reserve(total);
    dst.put_u8(SOH);
    dst.put_u32_le(total as u32);
    dst.put_u16_le(p.serial);
    dst.put_u16_le(p.reserved);
    dst.put_i32_le(p.code);
    dst.put_u16_le(p.args.len() as u16);
    dst.put_slice(&body);
    dst.put_u8(EOT);
    Ok(())
}

/// Bytes of a packet as a `Vec` (convenience).
pub fn packet_bytes(p: &Packet) -> Result<Vec<u8>, CodecError> {
    let mut b = BytesMut::new();
    encode_packet(p, &mut b)?;
    Ok(b.to_vec())
}

/// Decode one complete packet (`bytes` is exactly the packet, SOH..EOT).
pub fn decode_packet(bytes: &[u8]) -> Result<Packet, CodecError> {
    if bytes.len() < MIN_PACKET {
        return Err(CodecError::BadLength(bytes.len() as u32));
    }
    if bytes[0] != SOH {
        return Err(CodecError::NoSoh(bytes[0]));
    }
    let len = u32::from_le_bytes(bytes[1..5].try_into().expect("4"));
    if len as usize != bytes.len() {
        return Err(CodecError::BadLength(len));
    }
    if bytes[bytes.len() - 1] != EOT {
        return Err(CodecError::NoEot(bytes[bytes.len() - 1]));
    }
    let mut r = Rd {
        b: &bytes[5..bytes.len() - 1],
    };
    let serial = r.u16()?;
    let reserved = r.u16()?;
    let code = r.u32()? as i32;
    let argc = r.u16()?;
    // Each argument needs at least 4 (length) + 6 (VARIANT head) bytes.
    let n = r.check_count(argc as u32, 10)?;
    let mut args = Vec::with_capacity(n);
    for i in 0..n {
        let alen = r.u32()? as usize;
        let raw = r.take(alen).map_err(|_| {
            CodecError::BadArgs(format!("argument {i} length {alen} exceeds the packet"))
        })?;
        let mut ar = Rd { b: raw };
        args.push(decode_variant(&mut ar, 0)?);
        if !ar.b.is_empty() {
            return Err(CodecError::BadArgs(format!(
                "argument {i}: {} bytes after the VARIANT",
                ar.b.len()
            )));
        }
    }
    if !r.b.is_empty() {
        return Err(CodecError::BadArgs(format!(
            "{} bytes after the last argument",
            r.b.len()
        )));
    }
    Ok(Packet {
        serial,
        reserved,
        code,
        args,
    })
}

/// The error for bytes that do not start with SOH: another protocol named when it is
/// recognisable (an HTTP status line, printable text), else the first byte.
fn not_soh(buf: &[u8]) -> CodecError {
    if buf.starts_with(b"HTTP/") {
        return CodecError::NotBcap("HTTP".into());
    }
    let head: Vec<u8> = buf.iter().take(24).copied().collect();
    let text = head.len() >= 4
        && head
            .iter()
            .all(|b| b.is_ascii_graphic() || *b == b' ' || *b == b'\r' || *b == b'\n');
    if text {
        let line = String::from_utf8_lossy(&head);
        let line = line.lines().next().unwrap_or_default();
        return CodecError::NotBcap(format!("text ({line:?})"));
    }
    CodecError::NoSoh(buf[0])
}

/// Split one complete packet off `buf` (`Ok(None)`: need more bytes).
pub fn split_packet(buf: &mut BytesMut) -> Result<Option<BytesMut>, CodecError> {
    if buf.is_empty() {
        return Ok(None);
    }
    if buf[0] != SOH {
        return Err(not_soh(buf));
    }
    if buf.len() < 5 {
        return Ok(None);
    }
    let len = u32::from_le_bytes(buf[1..5].try_into().expect("4"));
    if (len as usize) < MIN_PACKET || len as usize > MAX_PACKET {
        return Err(CodecError::BadLength(len));
    }
    if buf.len() < len as usize {
        // No `reserve(len)`: a lying length field must not make us allocate ahead of data.
        return Ok(None);
    }
    Ok(Some(buf.split_to(len as usize)))
}

/// tokio-util codec for b-CAP over TCP (same framing both ways).
#[derive(Debug, Default, Clone, Copy)]
pub struct BcapCodec;

impl tokio_util::codec::Decoder for BcapCodec {
    type Item = Packet;
    type Error = CodecError;
    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<Packet>, CodecError> {
        match split_packet(src)? {
            Some(p) => decode_packet(&p).map(Some),
            None => Ok(None),
        }
    }
}

impl tokio_util::codec::Encoder<Packet> for BcapCodec {
    type Error = CodecError;
    fn encode(&mut self, item: Packet, dst: &mut BytesMut) -> Result<(), CodecError> {
        encode_packet(&item, dst)
    }
}

#[cfg(test)]
mod tests {
    use super::super::frame::{func, hresult};
    use super::*;
    use tokio_util::codec::Decoder;

    fn hex(s: &str) -> Vec<u8> {
        let s: String = s.split_whitespace().collect();
        (0..s.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
            .collect()
    }

    // The three byte examples of `docs/protocols.md` §2.2, produced there by the packing rules
    // of DENSO's Python client (orin_bcap `Python/bCAPClient/bcapclient.py`, `<bIHhiH`).
    #[test]
    fn service_start_request_bytes() {
        let want = hex("01 1e000000 0100 0000 01000000 0100 0a000000 0800 01000000 00000000 04");
        let p = Packet::request(1, func::SERVICE_START, vec![Variant::Bstr(String::new())]);
        assert_eq!(packet_bytes(&p).unwrap(), want);
        assert_eq!(decode_packet(&want).unwrap(), p);
    }

    #[test]
    fn reply_bytes() {
        let ok = hex("01 10000000 0100 0000 00000000 0000 04");
        assert_eq!(
            decode_packet(&ok).unwrap(),
            Packet::reply(1, hresult::S_OK, vec![])
        );
        let handle = hex("01 1e000000 0200 0000 00000000 0100 0a000000 0300 01000000 01000000 04");
        let p = decode_packet(&handle).unwrap();
        assert_eq!(p, Packet::reply(2, hresult::S_OK, vec![Variant::I4(1)]));
        assert_eq!(packet_bytes(&p).unwrap(), handle);
    }

    #[test]
    fn bstr_is_utf16le_and_arrays_nest() {
        let mut b = Vec::new();
        encode_variant(&Variant::Bstr("Arm".into()), &mut b);
        assert_eq!(b, hex("0800 01000000 06000000 4100 7200 6d00"));
        let v = Variant::VariantArray(vec![
            Variant::R8Array(vec![10.0, -20.5]),
            Variant::Bstr("J".into()),
            Variant::Bstr("@E".into()),
        ]);
        let mut b = Vec::new();
        encode_variant(&v, &mut b);
        // 0x200C, count 3, then the full VARIANTs without the outer length prefix.
        assert_eq!(&b[..6], hex("0c20 03000000").as_slice());
        assert_eq!(&b[6..12], hex("0520 02000000").as_slice());
        assert_eq!(decode_variant_exact(&b).unwrap(), v);
        let mut b = Vec::new();
        encode_variant(&Variant::Bool(true), &mut b);
        assert_eq!(b, hex("0b00 01000000 ffff"));
    }

    #[test]
    fn hostile_counts_fail_without_allocating() {
        // R8 array claiming 2^32-1 elements in a 16-byte body.
        let b = hex("0520 ffffffff 0000000000000000");
        assert!(decode_variant_exact(&b).is_err());
        // Packet claiming 65535 arguments.
        let p = hex("01 10000000 0100 0000 00000000 ffff 04");
        assert!(decode_packet(&p).is_err());
        // Length field beyond the cap.
        let mut buf = BytesMut::from(&hex("01 ffffff7f 0100")[..]);
        assert!(BcapCodec.decode(&mut buf).is_err());
        // Odd BSTR byte length.
        assert!(decode_variant_exact(&hex("0800 01000000 01000000 41")).is_err());
        // Deep nesting.
        let mut v = Variant::Empty;
        for _ in 0..10 {
            v = Variant::VariantArray(vec![v]);
        }
        let mut b = Vec::new();
        encode_variant(&v, &mut b);
        assert!(decode_variant_exact(&b).is_err());
    }

    #[test]
    fn partial_packets_wait() {
        let full = hex("01 1e000000 0200 0000 00000000 0100 0a000000 0300 01000000 01000000 04");
        let mut buf = BytesMut::new();
        let mut c = BcapCodec;
        for (i, b) in full.iter().enumerate() {
            buf.put_u8(*b);
            let r = c.decode(&mut buf).unwrap();
            assert_eq!(r.is_some(), i + 1 == full.len());
        }
    }
}
