//! KEYENCE DL-RS1A codec and client: literal lines from the manual, the client over an
//! in-memory duplex (resynchronisation after garbage, deadlines), round trips, and >= 100,000
//! random and mutated inputs through the decoders.

use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use robocal_drivers::keyence::codec;
use robocal_drivers::keyence::{Il600, Il600Config, KeyenceClient, KeyenceConfig, Reply, Value};
use robocal_drivers::{ErrorKind, RangeReading, RangeSensor};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

fn fast() -> KeyenceConfig {
    KeyenceConfig {
        reply_timeout: Duration::from_millis(200),
        ..KeyenceConfig::default()
    }
}

/// A scripted unit: for each expected request, write the given bytes.
fn scripted(script: Vec<(&'static [u8], Vec<u8>)>) -> tokio::io::DuplexStream {
    let (client, mut unit) = tokio::io::duplex(4096);
    tokio::spawn(async move {
        let mut buf = Vec::new();
        for (expect, reply) in script {
            while !buf.ends_with(b"\r\n") {
                let mut b = [0u8; 64];
                let n = unit.read(&mut b).await.unwrap();
                if n == 0 {
                    return;
                }
                buf.extend_from_slice(&b[..n]);
            }
            assert_eq!(buf, expect, "request bytes");
            buf.clear();
            unit.write_all(&reply).await.unwrap();
        }
        // Keep the link open until the client is done.
        let mut b = [0u8; 64];
        while unit.read(&mut b).await.unwrap_or(0) > 0 {}
    });
    client
}

#[tokio::test]
async fn client_resynchronises_after_garbage_lines() {
    let io = scripted(vec![
        // Noise, a stray line and an over-long unterminated run before the real reply.
        (
            b"M0\r\n",
            b"\x00\xff\r\nMS,00,+000.00\r\nM0,+123.45\r\n".to_vec(),
        ),
        (b"M0\r\n", b"M0,+EEE.EE\r\n".to_vec()),
        (b"M0\r\n", b"ER,M0,22\r\n".to_vec()),
        (b"M0\r\n", b"M0,+1".to_vec()),
        (b"M0\r\n", b"M0,-999.99\r\n".to_vec()),
    ]);
    let il = Il600::new(
        KeyenceClient::attach(io, fast()),
        Il600Config {
            amplifier: 0,
            offset_mm: 0.0,
        },
    );
    assert_eq!(
        il.read_range().await.unwrap(),
        RangeReading::Distance(123.45)
    );
    assert_eq!(
        il.read_range().await.unwrap_err().kind(),
        ErrorKind::DeviceRejected
    );
    assert_eq!(
        il.read_range().await.unwrap_err().kind(),
        ErrorKind::DeviceRejected
    );
    assert_eq!(
        il.read_range().await.unwrap_err().kind(),
        ErrorKind::Timeout
    );
    assert_eq!(il.read_range().await.unwrap(), RangeReading::OutOfRange);
}

#[tokio::test]
async fn closed_link_is_disconnected() {
    let (client, unit) = tokio::io::duplex(64);
    drop(unit);
    let c = KeyenceClient::attach(client, fast());
    let e = c.read_all().await.unwrap_err();
    assert_eq!(
        robocal_drivers::DeviceError::kind(&e),
        ErrorKind::Disconnected,
        "{e}"
    );
}

fn format_il600(v: f64) -> String {
    let h = (v * 100.0).round() as i64;
    format!(
        "{}{:03}.{:02}",
        if h < 0 { '-' } else { '+' },
        h.abs() / 100,
        h.abs() % 100
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(3000))]
    #[test]
    fn m0_round_trip(values in prop::collection::vec(-999.98f64..999.98, 1..16)) {
        let line = format!("M0,{}", values.iter().map(|v| format_il600(*v)).collect::<Vec<_>>().join(","));
        let Reply::M0(got) = codec::decode_line(line.as_bytes()).unwrap() else {
            return Err(TestCaseError::fail("not M0"));
        };
        prop_assert_eq!(got.len(), values.len());
        for (g, v) in got.iter().zip(&values) {
            match g {
                Value::Measured(x) => prop_assert!((x - v).abs() <= 0.005 + 1e-9),
                // A value that rounds to 999.99 reads as the display limit, as on the unit.
                Value::UpperLimit | Value::LowerLimit => prop_assert!(v.abs() >= 999.985 - 1e-9),
                other => return Err(TestCaseError::fail(format!("{other:?}"))),
            }
        }
    }

    #[test]
    fn sr_round_trip(id in 0u8..15, dno in 0u16..1000, data in "[0-9+.-]{1,10}") {
        let req = codec::encode_request(&robocal_drivers::keyence::Request::Sr { id, data_no: dno });
        prop_assert_eq!(req, format!("SR,{id:02},{dno:03}\r\n").into_bytes());
        let line = format!("SR,{id:02},{dno:03},{data}");
        prop_assert_eq!(
            codec::decode_line(line.as_bytes()).unwrap(),
            Reply::Sr { id, data_no: dno, data: data.clone() }
        );
    }
}

fn mutate(rng: &mut impl Rng, seed: &[u8]) -> Vec<u8> {
    let mut v = seed.to_vec();
    for _ in 0..rng.random_range(1..5) {
        match rng.random_range(0..4) {
            0 if !v.is_empty() => {
                let i = rng.random_range(0..v.len());
                v[i] = if rng.random_bool(0.5) {
                    rng.random()
                } else {
                    b",+-.0E9\r\n"[rng.random_range(0..9)]
                };
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

/// >= 100,000 random and mutated inputs: no panic, bounded output.
#[test]
fn decoders_survive_100k_random_and_mutated_inputs() {
    let mut rng = rand::rngs::StdRng::seed_from_u64(0x4B45_5945);
    let seeds: [&[u8]; 6] = [
        b"M0,+123.45,-001.00,+EEE.EE",
        b"MS,04,+001.50,01,-999.99",
        b"SR,00,033,00000",
        b"SW,00,001",
        b"ER,SR,65",
        b"AW,005",
    ];
    let mut n = 0;
    for i in 0..120_000usize {
        let input = if i % 3 == 0 {
            let len = rng.random_range(0..80);
            (0..len).map(|_| rng.random()).collect()
        } else {
            mutate(&mut rng, seeds[i % seeds.len()])
        };
        if let Some((line, used)) = codec::take_line(&input) {
            assert!(used <= input.len() && line.len() <= used);
        }
        match codec::decode_line(&input) {
            Ok(Reply::M0(v)) => assert!(v.len() <= input.len() / 2),
            Ok(Reply::Ms(v)) => assert!(v.len() <= input.len() / 4),
            Ok(Reply::Sr { data, .. }) => assert!(data.len() <= 10),
            _ => {}
        }
        let _ = codec::parse_value(&String::from_utf8_lossy(&input));
        n += 1;
    }
    assert!(n >= 100_000);
}
