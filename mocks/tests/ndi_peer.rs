//! Proof against code nobody here wrote: scikit-surgerynditracker 1.0.6 + ndicapi 3.7.6
//! (venv `.venv/peers-ndi`, installed by `.ci/peers.sh`) configured for a Polaris Vega at the
//! simulator's address reads tool transforms equal to the world's marker poses; our driver
//! reads the same poses from the same simulator.

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use robocal_drivers::ndi::{NdiClient, NdiConfig, NdiTracker, ReplyMode};
use robocal_drivers::{MarkerToTracker, MarkerTracker, ToolStatus};
use robocal_mocks::ndi::{self, SimNdiConfig, StaticTracker, TrackerSource, WorldTracker};
use robocal_mocks::scenario::{Protocol, TrackerKind, VolumeKind};
use robocal_mocks::{Scenario, WorldHandle};
use std::path::PathBuf;
use std::sync::Arc;

mod peer;

fn world() -> WorldHandle {
    let mut s = Scenario::single_arm("ur5e", 11);
    s.trackers[0].protocol = Protocol::NdiTcp;
    s.trackers[0].kind = TrackerKind::NdiPolarisVega;
    s.trackers[0].effects.volume = Some(VolumeKind::Unbounded);
    WorldHandle::from_scenario(&s).expect("scenario")
}

fn rom_files(dir: &std::path::Path, n: usize) -> Vec<PathBuf> {
    (0..n)
        .map(|i| {
            let p = dir.join(format!("tool{i}.rom"));
            let bytes: Vec<u8> = (0..752u32)
                .map(|k| (k as u8).wrapping_mul(7) ^ i as u8)
                .collect();
            std::fs::write(&p, bytes).unwrap();
            p
        })
        .collect()
}

/// Run the peer script; returns its JSON frames.
async fn run_peer(
    py: &PathBuf,
    addr: std::net::SocketAddr,
    frames: usize,
    roms: &[PathBuf],
) -> Vec<serde_json::Value> {
    run_peer_args(
        py,
        vec![
            "vega".into(),
            addr.ip().to_string(),
            addr.port().to_string(),
        ],
        frames,
        roms,
    )
    .await
}

async fn run_peer_args(
    py: &PathBuf,
    target: Vec<String>,
    frames: usize,
    roms: &[PathBuf],
) -> Vec<serde_json::Value> {
    let mut args = target;
    args.push(frames.to_string());
    args.extend(roms.iter().map(|r| r.display().to_string()));
    peer::run_json_lines(
        py,
        "ndi_sksurgery.py",
        args,
        std::time::Duration::from_secs(60),
    )
    .await
}

fn row_pose(row: &serde_json::Value) -> Isometry3<f64> {
    let v: Vec<f64> = row
        .as_array()
        .expect("7 numbers")
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    assert_eq!(v.len(), 7);
    Isometry3::from_parts(
        Translation3::new(v[4], v[5], v[6]),
        UnitQuaternion::from_quaternion(Quaternion::new(v[0], v[1], v[2], v[3])),
    )
}

fn close(a: &Isometry3<f64>, b: &Isometry3<f64>, mm: f64, rad: f64) -> bool {
    (a.translation.vector - b.translation.vector).norm() <= mm
        && a.rotation.angle_to(&b.rotation) <= rad
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sksurgerynditracker_reads_the_world_marker_pose_bx_and_tx() {
    let Some(py) = peer::python("ndi", "NDI peer test") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let roms = rom_files(dir.path(), 1);
    // Freeze tag " Polaris Vega 007" makes the client use BX:0801, " Polaris Vega 008" TX:0801.
    for (tag, capture, mm, rad) in [
        (" Polaris Vega 007", "BX:0801", 1e-3, 1e-6),
        (" Polaris Vega 008", "TX:0801", 0.009, 2.5e-4),
    ] {
        let w = world();
        let source: Arc<dyn TrackerSource> = Arc::new(WorldTracker {
            world: w.clone(),
            index: 0,
            name: "tracker".into(),
        });
        let config = SimNdiConfig {
            freeze_tag: tag.into(),
            ..SimNdiConfig::default()
        };
        let sim = ndi::serve_tcp(source, config, "127.0.0.1:0".parse().unwrap())
            .await
            .unwrap();
        let frames = run_peer(&py, sim.addr().unwrap(), 3, &roms).await;
        assert_eq!(frames.len(), 3);
        let truth = w.marker_truth(0).unwrap();
        let mut last_frame = 0;
        for f in &frames {
            assert_eq!(f["capture"], capture);
            assert_eq!(f["handles"][0], 1, "first PHRQ handle is 01");
            let pose = row_pose(&f["tracking"][0]);
            assert!(
                close(&pose, &truth, mm, rad),
                "{capture}: peer {pose:?} vs truth {truth:?}"
            );
            let q = f["quality"][0].as_f64().unwrap();
            // The world reports fit RMS = 0.05 mm x (1 + 0.2 |N(0,1)|).
            assert!((0.0499..0.2).contains(&q), "fit RMS {q}");
            let n = f["frame_numbers"][0].as_i64().unwrap();
            assert!(n > last_frame, "frame numbers increase");
            last_frame = n;
        }
        let log = sim.log();
        assert_eq!(
            log.iter().filter(|w| *w == "PVWR").count(),
            16,
            "1024 bytes in 16 PVWR"
        );
        assert!(log.iter().any(|w| w == "TSTOP"));
        // Our driver reads the same pose from the same simulator.
        let client = NdiClient::connect(&sim.addr().unwrap().to_string(), NdiConfig::default())
            .await
            .unwrap();
        let mode = if capture == "BX:0801" {
            ReplyMode::Binary
        } else {
            ReplyMode::Text
        };
        let rom = std::fs::read(&roms[0]).unwrap();
        let ours = NdiTracker::setup(client, &[("probe".into(), rom)], mode)
            .await
            .unwrap();
        let f = ours.frame().await.unwrap();
        let ToolStatus::Visible { pose, .. } = f.tool(Some("probe")).unwrap() else {
            panic!("not visible: {f:?}")
        };
        assert!(close(&pose.0, &truth, mm, rad));
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sksurgerynditracker_sees_missing_as_nan_for_one_of_two_tools() {
    let Some(py) = peer::python("ndi", "NDI peer test") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let roms = rom_files(dir.path(), 2);
    let pose = Isometry3::from_parts(
        Translation3::new(-12.34, 5.0, -1987.0),
        UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3),
    );
    let src = Arc::new(StaticTracker::new(vec![
        ToolStatus::Missing,
        ToolStatus::Visible {
            pose: MarkerToTracker(pose),
            rms_mm: 0.25,
        },
    ]));
    let sim = ndi::serve_tcp(src, SimNdiConfig::default(), "127.0.0.1:0".parse().unwrap())
        .await
        .unwrap();
    let frames = run_peer(&py, sim.addr().unwrap(), 1, &roms).await;
    let f = &frames[0];
    assert_eq!(f["handles"], serde_json::json!([1, 2]));
    assert!(f["tracking"][0].is_null(), "MISSING -> NaN: {f}");
    assert!(
        close(&row_pose(&f["tracking"][1]), &pose, 1e-3, 1e-6),
        "{f}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sksurgerynditracker_polaris_over_the_pty_serial_simulator() {
    let Some(py) = peer::python("ndi", "NDI peer test") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let roms = rom_files(dir.path(), 1);
    let w = world();
    let source: Arc<dyn TrackerSource> = Arc::new(WorldTracker {
        world: w.clone(),
        index: 0,
        name: "tracker".into(),
    });
    let sim = ndi::serve_pty(source, SimNdiConfig::default()).unwrap();
    let path = sim.path().unwrap().to_string();
    let frames = run_peer_args(&py, vec!["polaris".into(), path], 2, &roms).await;
    assert_eq!(frames.len(), 2);
    let truth = w.marker_truth(0).unwrap();
    for f in &frames {
        assert_eq!(f["capture"], "BX:0801");
        let pose = row_pose(&f["tracking"][0]);
        assert!(
            close(&pose, &truth, 1e-3, 1e-6),
            "peer {pose:?} vs truth {truth:?}"
        );
    }
    let log = sim.log();
    for word in [
        "INIT", "GETINFO", "COMM", "PHRQ", "PVWR", "PINIT", "PENA", "TSTART", "BX", "TSTOP",
    ] {
        assert!(log.iter().any(|w| w == word), "{word} missing from {log:?}");
    }
}
