//! The NDI driver (robocal-drivers) against the NDI simulator, over TCP and over a pty,
//! with every injectable fault: fault -> error kind -> recovery.

use nalgebra::Isometry3;
use robocal_drivers::ndi::{NdiClient, NdiConfig, NdiTracker, ReplyMode};
use robocal_drivers::{ErrorKind, MarkerToTracker, MarkerTracker, ToolStatus};
use robocal_mocks::ndi::{self, SimNdiConfig, StaticTracker, TrackerSource, WorldTracker};
use robocal_mocks::scenario::Protocol;
use robocal_mocks::world::control::Fault;
use robocal_mocks::{Scenario, WorldHandle};
use std::sync::Arc;
use std::time::Duration;

fn world() -> WorldHandle {
    let mut s = Scenario::single_arm("ur5e", 7);
    s.trackers[0].protocol = Protocol::NdiTcp;
    s.trackers[0].kind = robocal_mocks::scenario::TrackerKind::NdiPolarisVega;
    // The home pose of the preset is outside a Polaris pyramid; volume checks are tested
    // with the static source below.
    s.trackers[0].effects.volume = Some(robocal_mocks::scenario::VolumeKind::Unbounded);
    WorldHandle::from_scenario(&s).expect("scenario")
}

fn rom(tag: u8) -> Vec<u8> {
    // A tool definition is opaque to the simulator; 752 bytes like a typical passive .rom.
    (0..752u32).map(|i| (i as u8) ^ tag).collect()
}

fn fast() -> NdiConfig {
    NdiConfig {
        reply_timeout: Duration::from_millis(400),
        connect_timeout: Duration::from_secs(2),
    }
}

fn pose_close(a: &Isometry3<f64>, b: &Isometry3<f64>, mm: f64, rad: f64) -> bool {
    (a.translation.vector - b.translation.vector).norm() <= mm
        && a.rotation.angle_to(&b.rotation) <= rad
}

fn visible(s: &ToolStatus) -> Isometry3<f64> {
    match s {
        ToolStatus::Visible { pose, .. } => pose.0,
        other => panic!("expected a visible tool, got {other:?}"),
    }
}

async fn tcp_tracker(
    source: Arc<dyn TrackerSource>,
    config: SimNdiConfig,
    mode: ReplyMode,
    tools: usize,
) -> (ndi::SimNdi, NdiTracker<tokio::net::TcpStream>) {
    let sim = ndi::serve_tcp(source, config, "127.0.0.1:0".parse().unwrap())
        .await
        .expect("bind");
    let addr = sim.addr().unwrap().to_string();
    let client = NdiClient::connect(&addr, fast()).await.expect("connect");
    let roms: Vec<(String, Vec<u8>)> = (0..tools)
        .map(|i| (format!("tool{i}"), rom(i as u8)))
        .collect();
    let tracker = NdiTracker::setup(client, &roms, mode).await.expect("setup");
    (sim, tracker)
}

fn world_source(w: &WorldHandle) -> Arc<dyn TrackerSource> {
    Arc::new(WorldTracker {
        world: w.clone(),
        index: 0,
        name: "tracker".into(),
    })
}

#[tokio::test]
async fn bx_and_tx_over_tcp_equal_the_world_marker_pose() {
    let w = world();
    for (mode, mm, rad) in [
        // BX: float32 -> ~1e-4 mm at 2 m.
        (ReplyMode::Binary, 1e-3, 1e-6),
        // TX: 0.01 mm and 1e-4 quaternion resolution.
        (ReplyMode::Text, 0.0051 * 3f64.sqrt(), 2.5e-4),
    ] {
        let (sim, tracker) = tcp_tracker(world_source(&w), SimNdiConfig::default(), mode, 1).await;
        let f1 = tracker.frame().await.expect("frame");
        let truth = w.marker_truth(0).expect("truth");
        let got = visible(f1.tool(Some("tool0")).expect("tool0"));
        assert!(
            pose_close(&got, &truth, mm, rad),
            "{mode:?}: got {got:?}, truth {truth:?}"
        );
        let f2 = tracker.frame().await.expect("frame");
        assert_eq!(f2.frame_number, f1.frame_number + 1, "frame counter");
        tracker.stop().await.expect("TSTOP");
        let log = sim.log();
        for word in [
            "INIT", "PHSR", "PHRQ", "PVWR", "PINIT", "PENA", "TSTART", "TSTOP",
        ] {
            assert!(log.iter().any(|w| w == word), "{word} not sent: {log:?}");
        }
        // 752 bytes -> 12 PVWR chunks of 64.
        assert_eq!(log.iter().filter(|w| *w == "PVWR").count(), 12);
    }
}

#[tokio::test]
async fn serial_over_pty_with_baud_change() {
    let w = world();
    let sim = ndi::serve_pty(world_source(&w), SimNdiConfig::default()).expect("pty");
    let client = NdiClient::open_serial(sim.path().unwrap(), fast()).expect("open pty");
    client.init().await.expect("INIT");
    client.set_baud(115200).await.expect("COMM");
    let tracker = NdiTracker::setup(client, &[("probe".into(), rom(1))], ReplyMode::Binary)
        .await
        .expect("setup");
    let f = tracker.frame().await.expect("frame");
    let truth = w.marker_truth(0).unwrap();
    assert!(pose_close(
        &visible(f.tool(Some("probe")).unwrap()),
        &truth,
        1e-3,
        1e-6
    ));
    assert!(sim.log().iter().any(|w| w == "COMM"));
}

#[tokio::test]
async fn occlusion_gives_missing_then_recovers() {
    let w = world();
    let (_sim, tracker) = tcp_tracker(
        world_source(&w),
        SimNdiConfig::default(),
        ReplyMode::Binary,
        1,
    )
    .await;
    w.control().set_occluded(0, true);
    let f = tracker.frame().await.unwrap();
    assert_eq!(f.tool(None), Some(&ToolStatus::Missing));
    w.control().set_occluded(0, false);
    let f = tracker.frame().await.unwrap();
    assert!(matches!(f.tool(None), Some(ToolStatus::Visible { .. })));
}

#[tokio::test]
async fn several_tools_missing_and_out_of_volume_in_both_modes() {
    let pose = MarkerToTracker(Isometry3::translation(10.0, -20.0, -1500.0));
    for mode in [ReplyMode::Binary, ReplyMode::Text] {
        let src = Arc::new(StaticTracker::new(vec![
            ToolStatus::Visible { pose, rms_mm: 0.12 },
            ToolStatus::Missing,
            ToolStatus::OutOfVolume,
        ]));
        let (_sim, tracker) = tcp_tracker(src.clone(), SimNdiConfig::default(), mode, 3).await;
        let f = tracker.frame().await.unwrap();
        let got = visible(f.tool(Some("tool0")).unwrap());
        assert!(pose_close(&got, &pose.0, 0.01, 1e-4), "{mode:?}");
        assert_eq!(
            f.tool(Some("tool1")),
            Some(&ToolStatus::Missing),
            "{mode:?}"
        );
        assert_eq!(
            f.tool(Some("tool2")),
            Some(&ToolStatus::OutOfVolume),
            "{mode:?}"
        );
        if let Some(ToolStatus::Visible { rms_mm, .. }) = f.tool(Some("tool0")) {
            assert!((rms_mm - 0.12).abs() < 1e-4);
        }
    }
}

/// Fault -> error kind -> recovery (the next frame is good).
#[tokio::test]
async fn every_wire_fault_maps_to_its_kind_and_the_next_frame_recovers() {
    let pose = MarkerToTracker(Isometry3::translation(1.0, 2.0, -1200.0));
    let cases: Vec<(Fault, ErrorKind)> = vec![
        (Fault::BadCrc, ErrorKind::Protocol),
        (Fault::Truncated, ErrorKind::Timeout),
        (Fault::Silence { secs: 1.0 }, ErrorKind::Timeout),
        (Fault::ErrorReply { code: 0x0C }, ErrorKind::DeviceRejected),
        (
            Fault::Garbage {
                bytes: vec![0x00, 0xFF, 0x13, 0x88],
            },
            ErrorKind::Timeout,
        ),
        (
            Fault::Garbage {
                bytes: b"ERR\xFFOR\r".to_vec(),
            },
            ErrorKind::Protocol,
        ),
    ];
    for mode in [ReplyMode::Binary, ReplyMode::Text] {
        let src = Arc::new(StaticTracker::new(vec![ToolStatus::Visible {
            pose,
            rms_mm: 0.1,
        }]));
        let (_sim, tracker) = tcp_tracker(src.clone(), SimNdiConfig::default(), mode, 1).await;
        for (fault, kind) in &cases {
            src.inject(fault.clone());
            let err = tracker
                .frame()
                .await
                .expect_err(&format!("{fault:?} must fail"));
            assert_eq!(err.kind(), *kind, "{mode:?} {fault:?}: {err}");
            let ok = tracker
                .frame()
                .await
                .unwrap_or_else(|e| panic!("{mode:?} after {fault:?}: {e}"));
            assert!(pose_close(
                &visible(ok.tool(None).unwrap()),
                &pose.0,
                0.01,
                1e-4
            ));
        }
    }
}

#[tokio::test]
async fn dropped_link_is_disconnected_and_a_reconnect_recovers() {
    let pose = MarkerToTracker(Isometry3::translation(1.0, 2.0, -1200.0));
    let src = Arc::new(StaticTracker::new(vec![ToolStatus::Visible {
        pose,
        rms_mm: 0.1,
    }]));
    let (sim, tracker) =
        tcp_tracker(src.clone(), SimNdiConfig::default(), ReplyMode::Binary, 1).await;
    src.inject(Fault::DropLink);
    let err = tracker.frame().await.expect_err("link dropped");
    assert_eq!(err.kind(), ErrorKind::Disconnected, "{err}");
    // Reconnect: the device keeps its tools and tracking state, as a Vega does.
    let client = NdiClient::connect(&sim.addr().unwrap().to_string(), fast())
        .await
        .unwrap();
    let reply = client.bx(0x0801).await.expect("BX after reconnect");
    assert_eq!(reply.handles.len(), 1);
}

/// A tracker opened with `connect_tcp` rebuilds its session by itself: a dropped link, a
/// silence past the reply deadline and a truncated reply each cost one frame's retry, never
/// an error, and the rebuilt session tracks the same tool (the old handle freed, not doubled).
#[tokio::test]
async fn reconnecting_tracker_survives_drop_silence_and_truncation() {
    let pose = MarkerToTracker(Isometry3::translation(1.0, 2.0, -1200.0));
    let src = Arc::new(StaticTracker::new(vec![ToolStatus::Visible {
        pose,
        rms_mm: 0.1,
    }]));
    let sim = ndi::serve_tcp(
        src.clone(),
        SimNdiConfig::default(),
        "127.0.0.1:0".parse().unwrap(),
    )
    .await
    .expect("bind");
    let addr = sim.addr().unwrap().to_string();
    let tracker = NdiTracker::connect_tcp(
        &addr,
        fast(),
        &[("probe".into(), rom(1))],
        ReplyMode::Binary,
    )
    .await
    .expect("connect + start-up");
    for fault in [
        Fault::DropLink,
        Fault::Silence { secs: 1.0 },
        Fault::Truncated,
        Fault::DropLink,
    ] {
        src.inject(fault.clone());
        let f = tracker
            .frame()
            .await
            .unwrap_or_else(|e| panic!("after {fault:?} the tracker must reconnect: {e}"));
        assert_eq!(f.tools.len(), 1, "after {fault:?}: {:?}", f.tools);
        assert_eq!(f.tools[0].tool, "probe");
        assert!(pose_close(
            &visible(&f.tools[0].status),
            &pose.0,
            0.01,
            1e-4
        ));
        assert_eq!(tracker.tools().await.len(), 1);
    }
    // A fault that is not a link problem is still reported (and the next frame is good).
    src.inject(Fault::ErrorReply { code: 0x0C });
    let err = tracker.frame().await.expect_err("device error");
    assert_eq!(err.kind(), ErrorKind::DeviceRejected, "{err}");
    tracker.frame().await.expect("next frame");
    // A tracker that cannot reach its device at all says where it tried.
    drop(sim);
    let err = NdiTracker::connect_tcp(
        "127.0.0.1:9",
        fast(),
        &[("probe".into(), rom(1))],
        ReplyMode::Binary,
    )
    .await
    .expect_err("nothing listens on port 9");
    assert!(err.to_string().contains("127.0.0.1:9"), "{err}");
}

#[tokio::test]
async fn device_errors_for_protocol_misuse() {
    let src: Arc<dyn TrackerSource> = Arc::new(StaticTracker::new(vec![]));
    let sim = ndi::serve_tcp(src, SimNdiConfig::default(), "127.0.0.1:0".parse().unwrap())
        .await
        .unwrap();
    let client = NdiClient::connect(&sim.addr().unwrap().to_string(), fast())
        .await
        .unwrap();
    let code = |e: robocal_drivers::ndi::Error| match e {
        robocal_drivers::ndi::Error::Device { code, .. } => code,
        other => panic!("expected a device error, got {other}"),
    };
    // Before INIT: system not initialised.
    assert_eq!(code(client.start_tracking().await.unwrap_err()), 0x10);
    client.init().await.unwrap();
    // Tracking data before TSTART: invalid in this mode.
    assert_eq!(code(client.bx(0x0801).await.unwrap_err()), 0x0C);
    // Unknown handle.
    assert_eq!(code(client.init_handle(0x42).await.unwrap_err()), 0x2B);
    // Unknown command.
    assert_eq!(code(client.expect_okay("FOO:").await.unwrap_err()), 0x01);
    // PINIT without a tool definition.
    let h = codec_phrq(&client).await;
    assert_eq!(code(client.init_handle(h).await.unwrap_err()), 0x0D);
    // PENA before PINIT.
    assert_eq!(code(client.enable_handle(h).await.unwrap_err()), 0x0E);
    let err = client.enable_handle(h).await.unwrap_err();
    assert_eq!(
        robocal_drivers::DeviceError::kind(&err),
        ErrorKind::DeviceRejected
    );
    // The space form without CRC is accepted.
    client.expect_okay("INIT ").await.unwrap();
    let ver = client.version(0).await.unwrap();
    assert!(ver.lines().any(|l| l.starts_with("Freeze Tag:")), "{ver}");
}

async fn codec_phrq(client: &NdiClient<tokio::net::TcpStream>) -> u8 {
    let text = client.expect_text("PHRQ:*********1****").await.unwrap();
    robocal_drivers::ndi::codec::parse_phrq(&text).unwrap()
}

#[test]
fn bad_command_crc_is_error04() {
    let mut dev = robocal_mocks::ndi::NdiDevice::new(
        Arc::new(StaticTracker::new(vec![])),
        SimNdiConfig::default(),
    );
    let out = dev.handle_line(b"INIT:0000");
    assert_eq!(
        out,
        robocal_mocks::ndi::device::Output::Send(
            b"ERROR04"
                .iter()
                .copied()
                .chain(format!("{:04X}\r", robocal_drivers::ndi::codec::crc16(b"ERROR04")).bytes())
                .collect()
        )
    );
}

#[tokio::test]
async fn serve_registry_starts_tcp_and_serial_trackers() {
    let w = world();
    for protocol in [Protocol::NdiTcp, Protocol::NdiSerial] {
        let eps = robocal_mocks::serve::start_device(&w, "tracker", protocol, &Default::default())
            .await
            .expect("registry");
        assert_eq!(eps.len(), 1);
        let roms = [("probe".to_string(), rom(3))];
        let frame = match (&eps[0].addr, &eps[0].path) {
            (Some(addr), _) => {
                let c = NdiClient::connect(&addr.to_string(), fast()).await.unwrap();
                let t = NdiTracker::setup(c, &roms, ReplyMode::Binary)
                    .await
                    .unwrap();
                t.frame().await.unwrap()
            }
            (None, Some(path)) => {
                let c = NdiClient::open_serial(path, fast()).unwrap();
                let t = NdiTracker::setup(c, &roms, ReplyMode::Text).await.unwrap();
                t.frame().await.unwrap()
            }
            _ => panic!("endpoint without address or path"),
        };
        assert!(matches!(
            frame.tool(Some("probe")),
            Some(ToolStatus::Visible { .. })
        ));
        eps[0].abort();
    }
}
