//! ASCII encoding and decoding of DL-RS1A lines (no I/O).
//!
//! Requests end with `\r\n` (the unit also accepts `\r`); replies always end with `\r\n`.

use super::frame::{Reply, Request, Value};

/// Longest reply line accepted (bytes, without delimiter): 16 amplifiers x (2 + 1 + 10 + 1)
/// plus the prefix fits well within this.
pub const MAX_LINE: usize = 512;

/// Why a line could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct DecodeError(pub String);

fn err<T>(msg: impl Into<String>) -> Result<T, DecodeError> {
    Err(DecodeError(msg.into()))
}

/// Encode a request, with the `\r\n` delimiter.
pub fn encode_request(req: &Request) -> Vec<u8> {
    let body = match req {
        Request::M0 => "M0".to_string(),
        Request::Ms => "MS".to_string(),
        Request::Sr { id, data_no } => format!("SR,{id:02},{data_no:03}"),
        Request::Sw { id, data_no, value } => format!("SW,{id:02},{data_no:03},{value}"),
        Request::Aw { data_no, value } => format!("AW,{data_no:03},{value}"),
    };
    format!("{body}\r\n").into_bytes()
}

/// Split one line off the front of `buf`: returns `(line without CR/LF, bytes consumed)`.
/// A line longer than [`MAX_LINE`] without delimiter is returned as an over-long line so the
/// caller can drop it.
pub fn take_line(buf: &[u8]) -> Option<(&[u8], usize)> {
    match buf.iter().position(|&b| b == b'\n') {
        Some(p) => {
            let line = &buf[..p];
            let line = line.strip_suffix(b"\r").unwrap_or(line);
            Some((line, p + 1))
        }
        None if buf.len() > MAX_LINE => Some((buf, buf.len())),
        None => None,
    }
}

/// Whether `line` is a reply to `command` (its echo prefix, or an `ER,<command>,` line).
pub fn is_reply_to(line: &[u8], command: &str) -> bool {
    let c = command.as_bytes();
    (line.starts_with(c) && line.get(c.len()).is_none_or(|&b| b == b','))
        || (line.starts_with(b"ER,") && line[3..].starts_with(c))
}

fn digits<T: std::str::FromStr>(s: &str, n: usize, what: &str) -> Result<T, DecodeError> {
    if s.len() != n || !s.bytes().all(|b| b.is_ascii_digit()) {
        return err(format!("{what} `{s}` is not {n} digits"));
    }
    s.parse().or_else(|_| err(format!("{what} `{s}`")))
}

/// Parse one measured-value field (`+123.45`, `+EEE.EE`, `+999.99`, ...).
pub fn parse_value(field: &str) -> Result<Value, DecodeError> {
    if field.is_empty() || field.len() > 10 {
        return err(format!(
            "value field `{field}` has {} characters",
            field.len()
        ));
    }
    let body = field.strip_prefix(['+', '-']).unwrap_or(field);
    let negative = field.starts_with('-');
    if !body.is_empty() && body.bytes().all(|b| b == b'E' || b == b'.') && body.contains('E') {
        return Ok(Value::AmplifierError);
    }
    let numeric = !body.is_empty()
        && body.bytes().all(|b| b.is_ascii_digit() || b == b'.')
        && body.bytes().filter(|&b| b == b'.').count() <= 1
        && body.bytes().any(|b| b.is_ascii_digit());
    if numeric {
        if body.bytes().all(|b| b == b'9' || b == b'.') && body.len() >= 3 {
            // The display limits (+999.99 / -999.99 on the IL-600; same form on other heads).
            return Ok(if negative {
                Value::LowerLimit
            } else {
                Value::UpperLimit
            });
        }
        let v: f64 = body.parse().or_else(|_| err(format!("value `{field}`")))?;
        return Ok(Value::Measured(if negative { -v } else { v }));
    }
    if field
        .bytes()
        .all(|b| b.is_ascii_digit() || b.is_ascii_uppercase() || b"+-.".contains(&b))
    {
        return Ok(Value::NoMeasurement(field.to_string()));
    }
    err(format!(
        "value field `{field}` has characters outside the manual's set"
    ))
}

/// Decode one reply line (without delimiter).
pub fn decode_line(line: &[u8]) -> Result<Reply, DecodeError> {
    if line.len() > MAX_LINE {
        return err(format!("line longer than {MAX_LINE} bytes"));
    }
    if !line.iter().all(|b| (0x20..0x7F).contains(b)) {
        return err("non-printable bytes in a reply line");
    }
    let text = std::str::from_utf8(line).or_else(|_| err("not ASCII"))?;
    let fields: Vec<&str> = text.split(',').collect();
    match fields[0] {
        "M0" => {
            if fields.len() < 2 {
                return err("M0 reply without values");
            }
            Ok(Reply::M0(
                fields[1..]
                    .iter()
                    .map(|f| parse_value(f))
                    .collect::<Result<_, _>>()?,
            ))
        }
        "MS" => {
            if fields.len() < 3 || fields.len().is_multiple_of(2) {
                return err(format!("MS reply with {} fields", fields.len()));
            }
            fields[1..]
                .chunks(2)
                .map(|p| Ok((digits::<u8>(p[0], 2, "control output")?, parse_value(p[1])?)))
                .collect::<Result<_, _>>()
                .map(Reply::Ms)
        }
        "SR" => {
            if fields.len() != 4 {
                return err(format!("SR reply with {} fields", fields.len()));
            }
            if fields[3].is_empty() || fields[3].len() > 10 {
                return err("SR data must have 1..=10 characters");
            }
            Ok(Reply::Sr {
                id: digits(fields[1], 2, "ID")?,
                data_no: digits(fields[2], 3, "data number")?,
                data: fields[3].to_string(),
            })
        }
        "SW" => {
            if fields.len() != 3 {
                return err(format!("SW reply with {} fields", fields.len()));
            }
            Ok(Reply::Sw {
                id: digits(fields[1], 2, "ID")?,
                data_no: digits(fields[2], 3, "data number")?,
            })
        }
        "AW" => {
            if fields.len() != 2 {
                return err(format!("AW reply with {} fields", fields.len()));
            }
            Ok(Reply::Aw {
                data_no: digits(fields[1], 3, "data number")?,
            })
        }
        "ER" => {
            if fields.len() != 3 || fields[1].is_empty() || fields[1].len() > 2 {
                return err(format!("bad ER reply `{text}`"));
            }
            Ok(Reply::Er {
                command: fields[1].to_string(),
                code: digits(fields[2], 2, "error number")?,
            })
        }
        other => err(format!("unknown reply `{other}`")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_match_the_manual() {
        // DL-RS1A manual (IL edition) pp. 9-14: "M0" CR LF; "SR,00,038" CR LF.
        assert_eq!(encode_request(&Request::M0), b"M0\r\n");
        assert_eq!(encode_request(&Request::Ms), b"MS\r\n");
        assert_eq!(
            encode_request(&Request::Sr { id: 0, data_no: 38 }),
            b"SR,00,038\r\n"
        );
        assert_eq!(
            encode_request(&Request::Sw {
                id: 1,
                data_no: 1,
                value: "+00001".into()
            }),
            b"SW,01,001,+00001\r\n"
        );
        assert_eq!(
            encode_request(&Request::Aw {
                data_no: 5,
                value: "0".into()
            }),
            b"AW,005,0\r\n"
        );
    }

    #[test]
    fn manual_example_m0_one_amplifier() {
        // Manual example exchange: "M0\r\n" -> "M0,+123.45\r\n" with one amplifier.
        let (line, used) = take_line(b"M0,+123.45\r\nrest").unwrap();
        assert_eq!(used, 12);
        assert_eq!(
            decode_line(line).unwrap(),
            Reply::M0(vec![Value::Measured(123.45)])
        );
    }

    #[test]
    fn special_values_of_the_il600() {
        // Manual: "+EEE.EE" amplifier error, "+999.99" / "-999.99" display limits.
        assert_eq!(parse_value("+EEE.EE").unwrap(), Value::AmplifierError);
        assert_eq!(parse_value("+999.99").unwrap(), Value::UpperLimit);
        assert_eq!(parse_value("-999.99").unwrap(), Value::LowerLimit);
        assert_eq!(parse_value("-012.34").unwrap(), Value::Measured(-12.34));
        assert_eq!(parse_value("+000.00").unwrap(), Value::Measured(0.0));
        assert!(matches!(
            parse_value("-FFFF.FF").unwrap(),
            Value::NoMeasurement(_)
        ));
        assert!(matches!(
            parse_value("-----").unwrap(),
            Value::NoMeasurement(_)
        ));
        assert!(parse_value("+12a.45").is_err());
        assert!(parse_value("").is_err());
        assert!(parse_value("+1234567890").is_err());
    }

    #[test]
    fn ms_sr_sw_aw_and_errors() {
        assert_eq!(
            decode_line(b"MS,04,+001.50,01,-999.99").unwrap(),
            Reply::Ms(vec![(4, Value::Measured(1.5)), (1, Value::LowerLimit)])
        );
        assert_eq!(
            decode_line(b"SR,00,033,00000").unwrap(),
            Reply::Sr {
                id: 0,
                data_no: 33,
                data: "00000".into()
            }
        );
        assert_eq!(
            decode_line(b"SW,00,001").unwrap(),
            Reply::Sw { id: 0, data_no: 1 }
        );
        assert_eq!(decode_line(b"AW,001").unwrap(), Reply::Aw { data_no: 1 });
        // Manual: ER,<command>,<error number>; 00 invalid command, 65 ID error.
        assert_eq!(
            decode_line(b"ER,M0,00").unwrap(),
            Reply::Er {
                command: "M0".into(),
                code: 0
            }
        );
        assert_eq!(
            decode_line(b"ER,SR,65").unwrap(),
            Reply::Er {
                command: "SR".into(),
                code: 65
            }
        );
        assert!(decode_line(b"MS,04").is_err());
        assert!(decode_line(b"XX,1").is_err());
        assert!(decode_line(b"M0,\x01").is_err());
    }

    #[test]
    fn reply_matching_and_partial_lines() {
        assert!(is_reply_to(b"M0,+1.00", "M0"));
        assert!(is_reply_to(b"ER,M0,00", "M0"));
        assert!(!is_reply_to(b"MS,00,+1.00", "M0"));
        assert!(!is_reply_to(b"M00", "M0"));
        assert_eq!(take_line(b"M0,+12"), None, "partial line waits for LF");
        assert_eq!(take_line(&[b'x'; 600]).map(|(_, n)| n), Some(600));
    }
}
