//! RTDE bytes ↔ packages (no I/O). Pure functions plus tokio-util codecs for each side.
//!
//! Every length comes from a `u16`, so no decoder can allocate more than 64 KiB per package.

use super::frame::{kind, ControllerVersion, DataType, Reply, Request, TextMessage, Value};
use bytes::{Buf, BufMut, BytesMut};

/// A malformed RTDE package.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CodecError {
    /// The size field is below the 3-byte header.
    #[error("package size {size} is smaller than the 3-byte header")]
    BadSize {
        /// The size field.
        size: u16,
    },
    /// Unknown type letter.
    #[error("unknown package type 0x{kind:02x}")]
    UnknownType {
        /// The type byte.
        kind: u8,
    },
    /// A payload of the wrong length for its type.
    #[error("package '{kind}': payload length {len} does not fit (expected {expected})")]
    BadLength {
        /// The type letter.
        kind: char,
        /// Actual payload length.
        len: usize,
        /// What was expected.
        expected: &'static str,
    },
    /// Text that is not valid UTF-8 (names, types, messages).
    #[error("package '{kind}': text is not UTF-8")]
    BadText {
        /// The type letter.
        kind: char,
    },
    /// Encoding something that does not fit the wire (package > 65535 bytes, text > 255).
    #[error("cannot encode: {detail}")]
    TooLong {
        /// What overflowed.
        detail: String,
    },
    /// Data fields do not match the recipe.
    #[error("data package: {detail}")]
    BadFields {
        /// What is wrong.
        detail: String,
    },
    /// The transport failed.
    #[error("i/o: {0}")]
    Io(#[from] std::io::Error),
}

/// Split one complete package off `buf`: `Ok(None)` when more bytes are needed.
pub fn split_package(buf: &mut BytesMut) -> Result<Option<(u8, BytesMut)>, CodecError> {
    if buf.len() < 3 {
        return Ok(None);
    }
    let size = u16::from_be_bytes([buf[0], buf[1]]);
    if size < 3 {
        return Err(CodecError::BadSize { size });
    }
    if buf.len() < size as usize {
        // No `reserve(size)`: a lying size field must not make us allocate ahead of data.
        return Ok(None);
    }
    let mut pkg = buf.split_to(size as usize);
    let kind = pkg[2];
    pkg.advance(3);
    Ok(Some((kind, pkg)))
}

fn put_header(dst: &mut BytesMut, kind: u8, payload_len: usize) -> Result<(), CodecError> {
    let size = payload_len + 3;
    let size = u16::try_from(size).map_err(|_| CodecError::TooLong {
        detail: format!("package '{}' of {size} bytes", kind as char),
    })?;
    dst.reserve(size as usize);
    dst.put_u16(size);
    dst.put_u8(kind);
    Ok(())
}

fn text_payload(t: &TextMessage) -> Result<Vec<u8>, CodecError> {
    let mut p = Vec::new();
    for s in [&t.message, &t.source] {
        let n = u8::try_from(s.len()).map_err(|_| CodecError::TooLong {
            detail: "text message field longer than 255 bytes".into(),
        })?;
        p.push(n);
        p.extend_from_slice(s.as_bytes());
    }
    p.push(t.level);
    Ok(p)
}

fn decode_text(p: &[u8]) -> Result<TextMessage, CodecError> {
    let bad = || CodecError::BadLength {
        kind: 'M',
        len: p.len(),
        expected: "u8 len + msg + u8 len + src + u8 level",
    };
    let mut rest = p;
    let take = |rest: &mut &[u8]| -> Result<String, CodecError> {
        let (&n, r) = rest.split_first().ok_or_else(bad)?;
        if r.len() < n as usize {
            return Err(bad());
        }
        let (s, r) = r.split_at(n as usize);
        *rest = r;
        String::from_utf8(s.to_vec()).map_err(|_| CodecError::BadText { kind: 'M' })
    };
    let message = take(&mut rest)?;
    let source = take(&mut rest)?;
    if rest.len() != 1 {
        return Err(bad());
    }
    Ok(TextMessage {
        message,
        source,
        level: rest[0],
    })
}

fn split_names(kind: char, p: &[u8]) -> Result<Vec<String>, CodecError> {
    let s = std::str::from_utf8(p).map_err(|_| CodecError::BadText { kind })?;
    // ur_rtde appends a comma after every name; ignore empty tokens.
    Ok(s.split(',')
        .map(str::trim)
        .filter(|t| !t.is_empty())
        .map(str::to_owned)
        .collect())
}

fn one_byte(kind: char, p: &[u8]) -> Result<u8, CodecError> {
    match p {
        [b] => Ok(*b),
        _ => Err(CodecError::BadLength {
            kind,
            len: p.len(),
            expected: "1",
        }),
    }
}

/// Encode a client → controller package.
pub fn encode_request(req: &Request, dst: &mut BytesMut) -> Result<(), CodecError> {
    match req {
        Request::ProtocolVersion(v) => {
            put_header(dst, kind::PROTOCOL_VERSION, 2)?;
            dst.put_u16(*v);
        }
        Request::GetControllerVersion => put_header(dst, kind::CONTROLLER_VERSION, 0)?,
        Request::Text(t) => {
            let p = text_payload(t)?;
            put_header(dst, kind::TEXT_MESSAGE, p.len())?;
            dst.put_slice(&p);
        }
        Request::SetupOutputs { frequency, names } => {
            let s = names.join(",");
            put_header(dst, kind::SETUP_OUTPUTS, 8 + s.len())?;
            dst.put_f64(*frequency);
            dst.put_slice(s.as_bytes());
        }
        Request::SetupInputs { names } => {
            let s = names.join(",");
            put_header(dst, kind::SETUP_INPUTS, s.len())?;
            dst.put_slice(s.as_bytes());
        }
        Request::Start => put_header(dst, kind::START, 0)?,
        Request::Pause => put_header(dst, kind::PAUSE, 0)?,
        Request::Data { recipe_id, payload } => {
            put_header(dst, kind::DATA, 1 + payload.len())?;
            dst.put_u8(*recipe_id);
            dst.put_slice(payload);
        }
    }
    Ok(())
}

/// Decode the payload of a client → controller package.
pub fn decode_request(kind_byte: u8, p: &[u8]) -> Result<Request, CodecError> {
    let k = kind_byte as char;
    Ok(match kind_byte {
        kind::PROTOCOL_VERSION => match p {
            [a, b] => Request::ProtocolVersion(u16::from_be_bytes([*a, *b])),
            _ => {
                return Err(CodecError::BadLength {
                    kind: k,
                    len: p.len(),
                    expected: "2",
                })
            }
        },
        kind::CONTROLLER_VERSION => {
            expect_empty(k, p)?;
            Request::GetControllerVersion
        }
        kind::TEXT_MESSAGE => Request::Text(decode_text(p)?),
        kind::SETUP_OUTPUTS => {
            if p.len() < 8 {
                return Err(CodecError::BadLength {
                    kind: k,
                    len: p.len(),
                    expected: ">= 8",
                });
            }
            let frequency = f64::from_be_bytes(p[..8].try_into().expect("8 bytes"));
            Request::SetupOutputs {
                frequency,
                names: split_names(k, &p[8..])?,
            }
        }
        kind::SETUP_INPUTS => Request::SetupInputs {
            names: split_names(k, p)?,
        },
        kind::START => {
            expect_empty(k, p)?;
            Request::Start
        }
        kind::PAUSE => {
            expect_empty(k, p)?;
            Request::Pause
        }
        kind::DATA => {
            let (&recipe_id, rest) = p.split_first().ok_or(CodecError::BadLength {
                kind: k,
                len: 0,
                expected: ">= 1",
            })?;
            Request::Data {
                recipe_id,
                payload: rest.to_vec(),
            }
        }
        other => return Err(CodecError::UnknownType { kind: other }),
    })
}

fn expect_empty(kind: char, p: &[u8]) -> Result<(), CodecError> {
    if p.is_empty() {
        Ok(())
    } else {
        Err(CodecError::BadLength {
            kind,
            len: p.len(),
            expected: "0",
        })
    }
}

/// Encode a controller → client package.
pub fn encode_reply(rep: &Reply, dst: &mut BytesMut) -> Result<(), CodecError> {
    match rep {
        Reply::ProtocolVersion(ok) => {
            put_header(dst, kind::PROTOCOL_VERSION, 1)?;
            dst.put_u8(*ok as u8);
        }
        Reply::ControllerVersion(v) => {
            put_header(dst, kind::CONTROLLER_VERSION, 16)?;
            for x in [v.major, v.minor, v.bugfix, v.build] {
                dst.put_u32(x);
            }
        }
        Reply::Text(t) => {
            let p = text_payload(t)?;
            put_header(dst, kind::TEXT_MESSAGE, p.len())?;
            dst.put_slice(&p);
        }
        Reply::SetupOutputs { recipe_id, types } | Reply::SetupInputs { recipe_id, types } => {
            let k = if matches!(rep, Reply::SetupOutputs { .. }) {
                kind::SETUP_OUTPUTS
            } else {
                kind::SETUP_INPUTS
            };
            let s = types.join(",");
            put_header(dst, k, 1 + s.len())?;
            dst.put_u8(*recipe_id);
            dst.put_slice(s.as_bytes());
        }
        Reply::Start(ok) => {
            put_header(dst, kind::START, 1)?;
            dst.put_u8(*ok as u8);
        }
        Reply::Pause(ok) => {
            put_header(dst, kind::PAUSE, 1)?;
            dst.put_u8(*ok as u8);
        }
        Reply::Data { recipe_id, payload } => {
            put_header(dst, kind::DATA, 1 + payload.len())?;
            dst.put_u8(*recipe_id);
            dst.put_slice(payload);
        }
    }
    Ok(())
}

/// Decode the payload of a controller → client package.
pub fn decode_reply(kind_byte: u8, p: &[u8]) -> Result<Reply, CodecError> {
    let k = kind_byte as char;
    Ok(match kind_byte {
        kind::PROTOCOL_VERSION => Reply::ProtocolVersion(one_byte(k, p)? != 0),
        kind::CONTROLLER_VERSION => {
            if p.len() != 16 {
                return Err(CodecError::BadLength {
                    kind: k,
                    len: p.len(),
                    expected: "16",
                });
            }
            let w = |i: usize| u32::from_be_bytes(p[4 * i..4 * i + 4].try_into().expect("4"));
            Reply::ControllerVersion(ControllerVersion {
                major: w(0),
                minor: w(1),
                bugfix: w(2),
                build: w(3),
            })
        }
        kind::TEXT_MESSAGE => Reply::Text(decode_text(p)?),
        kind::SETUP_OUTPUTS | kind::SETUP_INPUTS => {
            let (&recipe_id, rest) = p.split_first().ok_or(CodecError::BadLength {
                kind: k,
                len: 0,
                expected: ">= 1",
            })?;
            let types = split_names(k, rest)?;
            if kind_byte == kind::SETUP_OUTPUTS {
                Reply::SetupOutputs { recipe_id, types }
            } else {
                Reply::SetupInputs { recipe_id, types }
            }
        }
        kind::START => Reply::Start(one_byte(k, p)? != 0),
        kind::PAUSE => Reply::Pause(one_byte(k, p)? != 0),
        kind::DATA => {
            let (&recipe_id, rest) = p.split_first().ok_or(CodecError::BadLength {
                kind: k,
                len: 0,
                expected: ">= 1",
            })?;
            Reply::Data {
                recipe_id,
                payload: rest.to_vec(),
            }
        }
        other => return Err(CodecError::UnknownType { kind: other }),
    })
}

/// Encode data fields (without the recipe id) in recipe order.
pub fn encode_fields(values: &[Value], dst: &mut Vec<u8>) {
    for v in values {
        match v {
            Value::Bool(b) => dst.push(*b as u8),
            Value::Uint8(x) => dst.push(*x),
            Value::Uint32(x) => dst.extend_from_slice(&x.to_be_bytes()),
            Value::Uint64(x) => dst.extend_from_slice(&x.to_be_bytes()),
            Value::Int32(x) => dst.extend_from_slice(&x.to_be_bytes()),
            Value::Double(x) => dst.extend_from_slice(&x.to_be_bytes()),
            Value::Vector3d(a) => a
                .iter()
                .for_each(|x| dst.extend_from_slice(&x.to_be_bytes())),
            Value::Vector6d(a) => a
                .iter()
                .for_each(|x| dst.extend_from_slice(&x.to_be_bytes())),
            Value::Vector6Int32(a) => a
                .iter()
                .for_each(|x| dst.extend_from_slice(&x.to_be_bytes())),
            Value::Vector6Uint32(a) => a
                .iter()
                .for_each(|x| dst.extend_from_slice(&x.to_be_bytes())),
        }
    }
}

/// Decode data fields (without the recipe id) with the recipe's types. The payload must have
/// exactly the recipe's length.
pub fn decode_fields(types: &[DataType], p: &[u8]) -> Result<Vec<Value>, CodecError> {
    let need: usize = types.iter().map(|t| t.size()).sum();
    if need != p.len() {
        return Err(CodecError::BadFields {
            detail: format!("recipe needs {need} bytes, package has {}", p.len()),
        });
    }
    let mut buf = p;
    let mut out = Vec::with_capacity(types.len());
    fn f6(buf: &mut &[u8]) -> [f64; 6] {
        std::array::from_fn(|_| buf.get_f64())
    }
    for t in types {
        out.push(match t {
            DataType::Bool => Value::Bool(buf.get_u8() != 0),
            DataType::Uint8 => Value::Uint8(buf.get_u8()),
            DataType::Uint32 => Value::Uint32(buf.get_u32()),
            DataType::Uint64 => Value::Uint64(buf.get_u64()),
            DataType::Int32 => Value::Int32(buf.get_i32()),
            DataType::Double => Value::Double(buf.get_f64()),
            DataType::Vector3d => Value::Vector3d(std::array::from_fn(|_| buf.get_f64())),
            DataType::Vector6d => Value::Vector6d(f6(&mut buf)),
            DataType::Vector6Int32 => Value::Vector6Int32(std::array::from_fn(|_| buf.get_i32())),
            DataType::Vector6Uint32 => Value::Vector6Uint32(std::array::from_fn(|_| buf.get_u32())),
        });
    }
    Ok(out)
}

/// Client side: encodes [`Request`], decodes [`Reply`].
#[derive(Debug, Default, Clone, Copy)]
pub struct ClientCodec;

impl tokio_util::codec::Decoder for ClientCodec {
    type Item = Reply;
    type Error = CodecError;
    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<Reply>, CodecError> {
        match split_package(src)? {
            Some((k, p)) => decode_reply(k, &p).map(Some),
            None => Ok(None),
        }
    }
}

impl tokio_util::codec::Encoder<Request> for ClientCodec {
    type Error = CodecError;
    fn encode(&mut self, item: Request, dst: &mut BytesMut) -> Result<(), CodecError> {
        encode_request(&item, dst)
    }
}

/// Controller side: decodes [`Request`], encodes [`Reply`].
#[derive(Debug, Default, Clone, Copy)]
pub struct ServerCodec;

impl tokio_util::codec::Decoder for ServerCodec {
    type Item = Request;
    type Error = CodecError;
    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<Request>, CodecError> {
        match split_package(src)? {
            Some((k, p)) => decode_request(k, &p).map(Some),
            None => Ok(None),
        }
    }
}

impl tokio_util::codec::Encoder<Reply> for ServerCodec {
    type Error = CodecError;
    fn encode(&mut self, item: Reply, dst: &mut BytesMut) -> Result<(), CodecError> {
        encode_reply(&item, dst)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio_util::codec::Decoder;

    fn req_bytes(r: &Request) -> Vec<u8> {
        let mut b = BytesMut::new();
        encode_request(r, &mut b).unwrap();
        b.to_vec()
    }
    fn rep_bytes(r: &Reply) -> Vec<u8> {
        let mut b = BytesMut::new();
        encode_reply(r, &mut b).unwrap();
        b.to_vec()
    }

    // Byte examples from `docs/protocols.md` §1.2 (official client / ur_rtde packing rules).
    #[test]
    fn literal_handshake_bytes() {
        // Client `V` with version 2: 00 05 56 00 02; reply 00 04 56 01.
        assert_eq!(
            req_bytes(&Request::ProtocolVersion(2)),
            [0x00, 0x05, 0x56, 0x00, 0x02]
        );
        assert_eq!(
            rep_bytes(&Reply::ProtocolVersion(true)),
            [0x00, 0x04, 0x56, 0x01]
        );
        // Client `v`: 00 03 76; reply 00 13 76 + 00000005 0000000b 00000001 0001a9ec.
        assert_eq!(
            req_bytes(&Request::GetControllerVersion),
            [0x00, 0x03, 0x76]
        );
        let v = Reply::ControllerVersion(ControllerVersion {
            major: 5,
            minor: 11,
            bugfix: 1,
            build: 0x1a9ec,
        });
        let b = rep_bytes(&v);
        assert_eq!(
            b,
            [0x00, 0x13, 0x76, 0, 0, 0, 5, 0, 0, 0, 0x0b, 0, 0, 0, 1, 0, 0x01, 0xa9, 0xec]
        );
        assert_eq!(decode_reply(b[2], &b[3..]).unwrap(), v);
        // `S` 00 03 53 -> 00 04 53 01; `P` likewise with 50.
        assert_eq!(req_bytes(&Request::Start), [0x00, 0x03, 0x53]);
        assert_eq!(rep_bytes(&Reply::Start(true)), [0x00, 0x04, 0x53, 0x01]);
        assert_eq!(req_bytes(&Request::Pause), [0x00, 0x03, 0x50]);
        assert_eq!(rep_bytes(&Reply::Pause(true)), [0x00, 0x04, 0x50, 0x01]);
    }

    #[test]
    fn literal_output_setup() {
        // Output setup for `timestamp,actual_q` at 500 Hz (official client, no trailing comma):
        // 00 1d 4f 40 7f 40 00 00 00 00 00 + 18 ASCII bytes; reply 00 13 4f 01 + DOUBLE,VECTOR6D.
        let r = Request::SetupOutputs {
            frequency: 500.0,
            names: vec!["timestamp".into(), "actual_q".into()],
        };
        let mut want = vec![0x00, 0x1d, 0x4f, 0x40, 0x7f, 0x40, 0, 0, 0, 0, 0];
        want.extend_from_slice(b"timestamp,actual_q");
        assert_eq!(req_bytes(&r), want);
        let rep = Reply::SetupOutputs {
            recipe_id: 1,
            types: vec!["DOUBLE".into(), "VECTOR6D".into()],
        };
        let mut want = vec![0x00, 0x13, 0x4f, 0x01];
        want.extend_from_slice(b"DOUBLE,VECTOR6D");
        assert_eq!(rep_bytes(&rep), want);
        // ur_rtde's trailing comma form decodes to the same names.
        let mut p = 500f64.to_be_bytes().to_vec();
        p.extend_from_slice(b"timestamp,actual_q,");
        assert_eq!(decode_request(b'O', &p).unwrap(), r);
    }

    #[test]
    fn literal_movej_command_package() {
        // ur_rtde moveJ on input recipe 1: `00 4c 55 01` + int32 1 + 8 doubles + int32 async.
        let mut fields = Vec::new();
        let mut vals = vec![Value::Int32(1)];
        vals.extend((0..8).map(|i| Value::Double(i as f64)));
        vals.push(Value::Int32(0));
        encode_fields(&vals, &mut fields);
        let b = req_bytes(&Request::Data {
            recipe_id: 1,
            payload: fields.clone(),
        });
        assert_eq!(&b[..4], [0x00, 0x4c, 0x55, 0x01]);
        assert_eq!(b.len(), 0x4c);
        let mut types = vec![DataType::Int32];
        types.extend([DataType::Double; 8]);
        types.push(DataType::Int32);
        assert_eq!(decode_fields(&types, &fields).unwrap(), vals);
        // The clear command `00 08 55 04 00 00 00 00`.
        let mut f = Vec::new();
        encode_fields(&[Value::Int32(0)], &mut f);
        assert_eq!(
            req_bytes(&Request::Data {
                recipe_id: 4,
                payload: f
            }),
            [0x00, 0x08, 0x55, 0x04, 0, 0, 0, 0]
        );
    }

    #[test]
    fn partial_frames_wait_for_more_bytes() {
        let full = rep_bytes(&Reply::Start(true));
        let mut c = ClientCodec;
        let mut buf = BytesMut::new();
        for (i, b) in full.iter().enumerate() {
            buf.put_u8(*b);
            let got = c.decode(&mut buf).unwrap();
            if i + 1 < full.len() {
                assert!(got.is_none());
            } else {
                assert_eq!(got, Some(Reply::Start(true)));
            }
        }
        assert!(buf.is_empty());
    }

    #[test]
    fn malformed_packages_are_errors() {
        let mut c = ClientCodec;
        let mut b = BytesMut::from(&[0x00u8, 0x02, 0x56][..]);
        assert!(matches!(
            c.decode(&mut b),
            Err(CodecError::BadSize { size: 2 })
        ));
        assert!(matches!(
            decode_reply(b'v', &[0; 15]),
            Err(CodecError::BadLength { .. })
        ));
        assert!(matches!(
            decode_reply(b'Z', &[]),
            Err(CodecError::UnknownType { kind: b'Z' })
        ));
        assert!(decode_fields(&[DataType::Vector6d], &[0; 47]).is_err());
    }
}
