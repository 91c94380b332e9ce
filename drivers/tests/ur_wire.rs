//! The RTDE client against a scripted controller that speaks only literal bytes (protocol
//! brief §1.2 examples), so a bug shared by our codec and our simulator cannot hide here.

use robocal_drivers::ur::rtde::{RtdeClient, RtdeConfig};
use robocal_drivers::{DeviceError, ErrorKind};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

async fn expect(s: &mut (impl AsyncReadExt + Unpin), want: &[u8]) {
    let mut got = vec![0u8; want.len()];
    s.read_exact(&mut got).await.unwrap();
    assert_eq!(got, want);
}

#[tokio::test]
async fn handshake_and_stream_byte_for_byte() {
    let (client_io, mut ctl) = tokio::io::duplex(4096);
    let controller = tokio::spawn(async move {
        // V(2) -> accepted
        expect(&mut ctl, &[0x00, 0x05, 0x56, 0x00, 0x02]).await;
        ctl.write_all(&[0x00, 0x04, 0x56, 0x01]).await.unwrap();
        // v -> 5.11.1.109036
        expect(&mut ctl, &[0x00, 0x03, 0x76]).await;
        ctl.write_all(&[
            0x00, 0x13, 0x76, 0, 0, 0, 5, 0, 0, 0, 0x0b, 0, 0, 0, 1, 0, 0x01, 0xa9, 0xec,
        ])
        .await
        .unwrap();
        // O(500 Hz, "timestamp,actual_q") -> recipe 1, "DOUBLE,VECTOR6D"
        let mut o = vec![0x00, 0x1d, 0x4f, 0x40, 0x7f, 0x40, 0, 0, 0, 0, 0];
        o.extend_from_slice(b"timestamp,actual_q");
        expect(&mut ctl, &o).await;
        let mut r = vec![0x00, 0x13, 0x4f, 0x01];
        r.extend_from_slice(b"DOUBLE,VECTOR6D");
        ctl.write_all(&r).await.unwrap();
        // S -> accepted
        expect(&mut ctl, &[0x00, 0x03, 0x53]).await;
        ctl.write_all(&[0x00, 0x04, 0x53, 0x01]).await.unwrap();
        // A stray text message (level INFO) the client must skip, then one data package:
        // 3 + 1 + 8 + 48 = 60 = 0x3c bytes; timestamp 1.5, actual_q = 0.1 .. 0.6.
        let mut m = vec![0x00, 0x0c, 0x4d, 3];
        m.extend_from_slice(b"hi!");
        m.extend_from_slice(&[3]);
        m.extend_from_slice(b"ctl");
        m.push(3);
        ctl.write_all(&m).await.unwrap();
        let mut u = vec![0x00, 0x3c, 0x55, 0x01];
        u.extend_from_slice(&1.5f64.to_be_bytes());
        for i in 1..=6 {
            u.extend_from_slice(&(i as f64 / 10.0).to_be_bytes());
        }
        ctl.write_all(&u).await.unwrap();
        // Then fall silent (keep the pipe open).
        tokio::time::sleep(Duration::from_secs(2)).await;
        drop(ctl);
    });
    let cfg = RtdeConfig {
        frequency_hz: 500.0,
        outputs: vec!["timestamp".into(), "actual_q".into()],
        request_timeout: Duration::from_secs(1),
        stream_timeout: Duration::from_millis(300),
    };
    let c = RtdeClient::attach(client_io, cfg).await.unwrap();
    assert_eq!(c.version().to_string(), "5.11.1.109036");
    let s = c.latest().await.unwrap();
    assert_eq!(s.double("timestamp"), Some(1.5));
    assert_eq!(s.vec6("actual_q"), Some([0.1, 0.2, 0.3, 0.4, 0.5, 0.6]));
    // Silence: the next sample times out.
    let e = c.next_sample().await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Timeout);
    // Closed pipe: disconnected.
    controller.await.unwrap();
    let e = c.next_sample().await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Disconnected);
}

#[tokio::test]
async fn not_found_output_is_device_rejected() {
    let (client_io, mut ctl) = tokio::io::duplex(4096);
    tokio::spawn(async move {
        let mut buf = [0u8; 5];
        ctl.read_exact(&mut buf).await.unwrap();
        ctl.write_all(&[0x00, 0x04, 0x56, 0x01]).await.unwrap();
        let mut buf = [0u8; 3];
        ctl.read_exact(&mut buf).await.unwrap();
        ctl.write_all(&[
            0x00, 0x13, 0x76, 0, 0, 0, 5, 0, 0, 0, 0x0b, 0, 0, 0, 1, 0, 0x01, 0xa9, 0xec,
        ])
        .await
        .unwrap();
        let mut hdr = [0u8; 2];
        ctl.read_exact(&mut hdr).await.unwrap();
        let mut rest = vec![0u8; u16::from_be_bytes(hdr) as usize - 2];
        ctl.read_exact(&mut rest).await.unwrap();
        let mut r = vec![0x00, 0x00, 0x4f, 0x01];
        r.extend_from_slice(b"VECTOR6D,NOT_FOUND");
        let n = r.len() as u16;
        r[..2].copy_from_slice(&n.to_be_bytes());
        ctl.write_all(&r).await.unwrap();
        tokio::time::sleep(Duration::from_millis(200)).await;
    });
    let cfg = RtdeConfig {
        outputs: vec!["actual_q".into(), "bogus".into()],
        ..RtdeConfig::default()
    };
    let e = RtdeClient::attach(client_io, cfg).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::DeviceRejected, "{e}");
    assert!(e.to_string().contains("bogus"));
}
