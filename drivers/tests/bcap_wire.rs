//! The b-CAP client against a scripted controller that speaks only the literal bytes of the
//! protocol brief §2.2 (produced there by DENSO's Python client packing rules).

use robocal_drivers::bcap::frame::hresult;
use robocal_drivers::bcap::BcapClient;
use robocal_drivers::{DeviceError, ErrorKind};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

fn hex(s: &str) -> Vec<u8> {
    let s: String = s.split_whitespace().collect();
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

#[tokio::test]
async fn service_start_and_handle_reply_byte_for_byte() {
    let (io, mut ctl) = tokio::io::duplex(4096);
    tokio::spawn(async move {
        let mut req = vec![0u8; 30];
        ctl.read_exact(&mut req).await.unwrap();
        assert_eq!(
            req,
            hex("01 1e000000 0100 0000 01000000 0100 0a000000 0800 01000000 00000000 04")
        );
        // An S_EXECUTING keepalive for serial 1 first, then S_OK.
        ctl.write_all(&hex("01 10000000 0100 0000 00090000 0000 04"))
            .await
            .unwrap();
        ctl.write_all(&hex("01 10000000 0100 0000 00000000 0000 04"))
            .await
            .unwrap();
        // Controller_Connect (serial 2): read its length, then answer with the brief's handle
        // reply, preceded by a stale reply for serial 1 that the client must discard.
        let mut head = [0u8; 5];
        ctl.read_exact(&mut head).await.unwrap();
        let len = u32::from_le_bytes(head[1..5].try_into().unwrap()) as usize;
        let mut rest = vec![0u8; len - 5];
        ctl.read_exact(&mut rest).await.unwrap();
        assert_eq!(&rest[..2], &[0x02, 0x00], "serial 2");
        assert_eq!(&rest[4..8], &3i32.to_le_bytes(), "function 3");
        ctl.write_all(&hex("01 10000000 0100 0000 00000000 0000 04"))
            .await
            .unwrap();
        ctl.write_all(&hex(
            "01 1e000000 0200 0000 00000000 0100 0a000000 0300 01000000 01000000 04",
        ))
        .await
        .unwrap();
        // Controller_GetRobot (serial 3): refuse with E_HANDLE (0x80070006).
        let mut head = [0u8; 5];
        ctl.read_exact(&mut head).await.unwrap();
        let len = u32::from_le_bytes(head[1..5].try_into().unwrap()) as usize;
        let mut rest = vec![0u8; len - 5];
        ctl.read_exact(&mut rest).await.unwrap();
        ctl.write_all(&hex("01 10000000 0300 0000 06000780 0000 04"))
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_secs(1)).await;
    });
    let c = BcapClient::attach(io, Duration::from_millis(500));
    c.service_start("").await.unwrap();
    let h = c
        .controller_connect("", "CaoProv.DENSO.VRC", "localhost", "")
        .await
        .unwrap();
    assert_eq!(h, 1);
    let e = c.controller_get_robot(h, "Arm").await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::DeviceRejected);
    assert_eq!(e.hresult(), Some(hresult::E_HANDLE));
    // Silence: timeout.
    let e = c.service_stop().await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Timeout);
}
