//! The KEYENCE driver (robocal-drivers) against the DL-RS1A simulator on a pty: world
//! readings, special values, every injectable fault (fault -> error kind -> recovery).

use robocal_drivers::keyence::{Error, Il600, Il600Config, KeyenceClient, KeyenceConfig, Value};
use robocal_drivers::{DeviceError, ErrorKind, RangeReading, RangeSensor};
use robocal_mocks::keyence::{self, LaserSample, SimKeyenceConfig, StaticLaser, WorldLaser};
use robocal_mocks::scenario::{LaserConfig, PlaneConfig, Protocol};
use robocal_mocks::world::control::Fault;
use robocal_mocks::{Scenario, WorldHandle};
use std::sync::Arc;
use std::time::Duration;

fn fast() -> KeyenceConfig {
    KeyenceConfig {
        reply_timeout: Duration::from_millis(300),
        ..KeyenceConfig::default()
    }
}

/// A UR5e at home with an IL-600 on the flange looking at a plane 650 mm away.
fn world_with_laser() -> WorldHandle {
    let mut s = Scenario::single_arm("ur5e", 3);
    let laser = LaserConfig {
        name: "laser".into(),
        kind: "keyence-il600".into(),
        protocol: Protocol::DlRs1a,
        arm: "arm".into(),
        beam_origin_mm: [0.0, 0.0, 50.0],
        beam_dir: [0.0, 0.0, 1.0],
        min_mm: 200.0,
        max_mm: 1000.0,
        max_incidence_deg: 60.0,
        rate_hz: 1000.0,
        effects: Default::default(),
    };
    s.lasers.push(laser);
    let flange = WorldHandle::from_scenario(&s).unwrap().arm_true_flange(0);
    let o = flange * nalgebra::Point3::new(0.0, 0.0, 50.0);
    let u = flange.rotation * nalgebra::Vector3::z();
    let p = o + u * 650.0;
    s.scene.planes.push(PlaneConfig {
        name: "P1".into(),
        normal: [-u.x, -u.y, -u.z],
        through_mm: [p.x, p.y, p.z],
    });
    WorldHandle::from_scenario(&s).unwrap()
}

#[tokio::test]
async fn il600_reads_the_world_distance_to_the_display_resolution() {
    let w = world_with_laser();
    let source = Arc::new(WorldLaser {
        world: w.clone(),
        index: 0,
        name: "laser".into(),
    });
    let sim = keyence::serve_pty(source, SimKeyenceConfig::default()).unwrap();
    let client = KeyenceClient::open_serial(sim.path(), fast()).unwrap();
    let il = Il600::new(client, Il600Config::default());
    let (truth, _, surface) = w.laser_truth(0).expect("beam hits the plane");
    assert_eq!(surface, "P1");
    assert!((truth - 650.0).abs() < 1e-6, "{truth}");
    for _ in 0..3 {
        match il.read_range().await.unwrap() {
            RangeReading::Distance(d) => {
                assert!((d - truth).abs() <= 0.005 + 1e-9, "{d} vs {truth}")
            }
            other => panic!("{other:?}"),
        }
    }
    // The world forces out-of-range samples: the unit sends its no-measurement string.
    w.control().force_out_of_range(0, 1);
    assert_eq!(il.read_range().await.unwrap(), RangeReading::OutOfRange);
    assert!(matches!(
        il.read_range().await.unwrap(),
        RangeReading::Distance(_)
    ));
    // Through the serve registry as well.
    let eps =
        robocal_mocks::serve::start_device(&w, "laser", Protocol::DlRs1a, &Default::default())
            .await
            .unwrap();
    let path = eps[0].path.clone().expect("pty path");
    let il2 = Il600::new(
        KeyenceClient::open_serial(&path, fast()).unwrap(),
        Il600Config::default(),
    );
    assert!(matches!(
        il2.read_range().await.unwrap(),
        RangeReading::Distance(_)
    ));
    eps[0].abort();
}

#[tokio::test]
async fn special_values_map_to_out_of_range_or_amplifier_error() {
    let src = Arc::new(StaticLaser::new(LaserSample::Distance(700.0)));
    let sim = keyence::serve_pty(src.clone(), SimKeyenceConfig::default()).unwrap();
    let il = Il600::new(
        KeyenceClient::open_serial(sim.path(), fast()).unwrap(),
        Il600Config::default(),
    );
    assert_eq!(
        il.read_range().await.unwrap(),
        RangeReading::Distance(700.0)
    );
    src.push(LaserSample::Distance(2000.0)); // +999.99
    src.push(LaserSample::Distance(-1000.0)); // -999.99
    src.push(LaserSample::OutOfRange); // no-measurement string
    for _ in 0..3 {
        assert_eq!(il.read_range().await.unwrap(), RangeReading::OutOfRange);
    }
    src.push(LaserSample::AmplifierError);
    let e = il.read_range().await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::DeviceRejected, "{e}");
    assert_eq!(
        il.read_range().await.unwrap(),
        RangeReading::Distance(700.0)
    );
}

#[tokio::test]
async fn every_wire_fault_maps_to_its_kind_and_the_next_reading_recovers() {
    let src = Arc::new(StaticLaser::new(LaserSample::Distance(612.34)));
    let sim = keyence::serve_pty(src.clone(), SimKeyenceConfig::default()).unwrap();
    let il = Il600::new(
        KeyenceClient::open_serial(sim.path(), fast()).unwrap(),
        Il600Config::default(),
    );
    let cases = [
        (Fault::BadCrc, ErrorKind::Protocol),
        (Fault::Truncated, ErrorKind::Timeout),
        (Fault::Silence { secs: 1.0 }, ErrorKind::Timeout),
        (Fault::DropLink, ErrorKind::Timeout),
        (Fault::ErrorReply { code: 29 }, ErrorKind::DeviceRejected),
        (
            Fault::Garbage {
                bytes: b"\x00\xff#garbage\r\n".to_vec(),
            },
            ErrorKind::Timeout,
        ),
        (
            Fault::Garbage {
                bytes: b"M0,+1\x0023.45\r\n".to_vec(),
            },
            ErrorKind::Protocol,
        ),
    ];
    for (fault, kind) in cases {
        src.inject(fault.clone());
        let e = il.read_range().await.expect_err(&format!("{fault:?}"));
        assert_eq!(e.kind(), kind, "{fault:?}: {e}");
        let ok = il
            .read_range()
            .await
            .unwrap_or_else(|e| panic!("after {fault:?}: {e}"));
        match ok {
            RangeReading::Distance(d) => assert!((d - 612.34).abs() < 1e-9),
            other => panic!("{other:?}"),
        }
    }
    // A delay shorter than the deadline is just a slow reply.
    src.inject(Fault::Delay { secs: 0.05 });
    assert!(il.read_range().await.is_ok());
}

#[tokio::test]
async fn items_and_error_numbers() {
    let src = Arc::new(StaticLaser::new(LaserSample::Distance(650.0)));
    let config = SimKeyenceConfig {
        amplifiers: 2,
        ..SimKeyenceConfig::default()
    };
    let sim = keyence::serve_pty(src, config).unwrap();
    let c = KeyenceClient::open_serial(sim.path(), fast()).unwrap();
    assert_eq!(
        c.read_all().await.unwrap(),
        vec![Value::Measured(50.0), Value::Measured(0.0)]
    );
    let outs = c.read_outputs().await.unwrap();
    assert_eq!(outs.len(), 2);
    assert_eq!(outs[0], (4, Value::Measured(50.0)));
    assert_eq!(c.read_item(0, 38).await.unwrap(), "+050.00");
    assert_eq!(c.read_item(0, 33).await.unwrap(), "00000");
    let code = |e: Error| match e {
        Error::Device { code, .. } => code,
        other => panic!("{other}"),
    };
    assert_eq!(
        code(c.read_item(5, 38).await.unwrap_err()),
        65,
        "no such amplifier"
    );
    assert_eq!(
        code(c.write_item(0, 37, "1").await.unwrap_err()),
        22,
        "read-only item"
    );
    c.write_item(1, 1, "+00010").await.unwrap();
    assert_eq!(c.read_item(1, 1).await.unwrap(), "+00010");
    let e = c.read_item(5, 38).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::DeviceRejected);
    assert!(sim.log().iter().any(|c| c == "SW"));
}
