//! The world's camera read through our own OpenCV driver (feature `opencv`):
//! OpenCV's chessboard detectors find the corners of the rendered board where the world's true
//! camera pose projects the true board corners (in-process renders, lossless), and
//! `VideoCaptureSource` reads the MJPEG-over-HTTP simulator live: fresh frames after the arm
//! moves, reconnection after the link drops.
//!
//! Figures are printed: `cargo test -p robocal-mocks --features opencv --test camera_opencv --
//! --nocapture`.
#![cfg(feature = "opencv")]

use nalgebra::Point3;
use robocal_drivers::camera::opencv::{
    find_chessboard, CaptureConfig, Detector, VideoCaptureSource,
};
use robocal_drivers::{ImageSource, MoveSpeed};
use robocal_mocks::camera::{self, SimCameraConfig};
use robocal_mocks::world::sensors::project;
use robocal_mocks::world::Fault;
use robocal_mocks::{Scenario, WorldHandle};
use std::path::PathBuf;

fn scenario() -> Scenario {
    Scenario::load(&PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenarios/ur5e-camera.toml"))
        .unwrap()
}

/// The true inner corners (px) of the board in camera 0 now, row-major.
fn truth(w: &WorldHandle, s: &Scenario) -> Vec<[f64; 2]> {
    let board = s.scene.chessboard.as_ref().unwrap();
    let cam_in_base = w.camera_in_base(0).unwrap();
    let mut out = Vec::new();
    for j in 1..board.rows {
        for i in 1..board.cols {
            let p = board.placement.isometry()
                * Point3::new(i as f64 * board.square_mm, j as f64 * board.square_mm, 0.0);
            let (u, v) = project(&s.cameras[0], &(cam_in_base.inverse() * p)).unwrap();
            out.push([u, v]);
        }
    }
    out
}

/// Distance of each found corner to the nearest true corner; the match must be one-to-one.
fn errors(found: &[[f64; 2]], truth: &[[f64; 2]]) -> Vec<f64> {
    let mut used = vec![false; truth.len()];
    found
        .iter()
        .map(|f| {
            let (k, d) = truth
                .iter()
                .enumerate()
                .map(|(k, t)| (k, (f[0] - t[0]).hypot(f[1] - t[1])))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap();
            assert!(!used[k], "two corners matched the same true corner");
            used[k] = true;
            d
        })
        .collect()
}

fn rms_max(e: &[f64]) -> (f64, f64) {
    let rms = (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt();
    (rms, e.iter().cloned().fold(0.0, f64::max))
}

const POSES_DEG: [[f64; 6]; 4] = [
    [0.0, -90.0, 90.0, -90.0, -90.0, 0.0],
    [0.0, -90.0, 90.0, -90.0, -85.0, 0.0],
    [0.0, -90.0, 90.0, -90.0, -95.0, 0.0],
    [0.0, -89.0, 89.0, -90.0, -90.0, 0.0],
];

async fn move_to(w: &WorldHandle, deg: &[f64; 6]) {
    let q: Vec<f64> = deg.iter().map(|d| d.to_radians()).collect();
    w.arm_start_move(0, &q, MoveSpeed::default()).unwrap();
    w.arm_wait_arrival(0).await;
}

/// The camera simulator at 10 Hz and our OpenCV driver reading its stream live.
async fn live(w: &WorldHandle, timeout_s: f64) -> (camera::SimCamera, VideoCaptureSource) {
    let cfg = SimCameraConfig {
        rate_hz: 10.0,
        ..SimCameraConfig::default()
    };
    let sim = camera::serve(w.clone(), "cam", cfg, "127.0.0.1:0".parse().unwrap())
        .await
        .unwrap();
    let mut cc = CaptureConfig::new(sim.url());
    cc.timeout_s = timeout_s;
    let src = VideoCaptureSource::open(cc).unwrap();
    (sim, src)
}

#[tokio::test]
async fn opencv_finds_the_rendered_corners_where_the_true_pose_projects_them() {
    let s = scenario();
    let w = WorldHandle::from_scenario(&s).unwrap();
    let (mut all_classic, mut all_sb) = (Vec::new(), Vec::new());
    for q in &POSES_DEG {
        move_to(&w, q).await;
        let img = w.render_camera_of(0);
        let t = truth(&w, &s);
        assert!(
            t.iter()
                .all(|p| p[0] > 5.0 && p[0] < 635.0 && p[1] > 5.0 && p[1] < 475.0),
            "pose {q:?} does not show the whole board"
        );
        let c = find_chessboard(&img, 8, 5, Detector::Classic)
            .unwrap()
            .unwrap_or_else(|| panic!("no board at {q:?}"));
        let sb = find_chessboard(&img, 8, 5, Detector::SectorBased)
            .unwrap()
            .unwrap_or_else(|| panic!("SB: no board at {q:?}"));
        all_classic.extend(errors(&c, &t));
        all_sb.extend(errors(&sb, &t));
    }
    let (cr, cm) = rms_max(&all_classic);
    let (sr, sm) = rms_max(&all_sb);
    println!(
        "world render (noise 2 grey, blur 0.7 px), {} poses × 40 corners: classic+cornerSubPix \
         rms {cr:.3} px max {cm:.3} px; findChessboardCornersSB rms {sr:.3} px max {sm:.3} px",
        POSES_DEG.len()
    );
    assert!(cm < 0.15, "classic corners off by up to {cm} px");
    assert!(sm < 0.25, "SB corners off by up to {sm} px");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn video_capture_reads_the_mjpeg_simulator_live_and_reconnects() {
    let s = scenario();
    let w = WorldHandle::from_scenario(&s).unwrap();
    let (_sim, src) = live(&w, 5.0).await;

    for q in &POSES_DEG[..3] {
        move_to(&w, q).await;
        let t0 = std::time::Instant::now();
        let img = src.grab().await.unwrap();
        let waited = t0.elapsed().as_secs_f64();
        assert_eq!((img.width, img.height), (640, 480));
        let c = find_chessboard(&img, 8, 5, Detector::Classic)
            .unwrap()
            .expect("board in the streamed frame");
        // A stale frame (taken before the move) would be many pixels off.
        let (r, m) = rms_max(&errors(&c, &truth(&w, &s)));
        println!("live frame after moving to {q:?}: waited {waited:.3} s, corners rms {r:.3} px max {m:.3} px");
        assert!(
            m < 0.3,
            "streamed corners off by up to {m} px (stale frame?)"
        );
    }

    // The link drops: the reader reopens the stream by itself.
    let before = src.frames_received();
    w.control().inject("cam", Fault::DropLink);
    let t0 = std::time::Instant::now();
    let mut ok = false;
    while t0.elapsed().as_secs_f64() < 20.0 {
        match src.grab().await {
            Ok(img) => {
                assert_eq!(img.width, 640);
                ok = true;
                break;
            }
            Err(e) => println!("after DropLink: {e} ({})", e.kind()),
        }
    }
    assert!(ok, "no frame within 20 s after the link dropped");
    println!(
        "recovered from DropLink in {:.2} s ({} → {} frames received)",
        t0.elapsed().as_secs_f64(),
        before,
        src.frames_received()
    );
    assert!(src.frames_received() > before);
}

/// Every wire fault of the camera simulator, seen through the OpenCV driver: what `grab`
/// reports, and that a good frame (board found where the truth projects it) follows.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_stream_fault_is_survived_by_the_opencv_driver() {
    let s = scenario();
    let w = WorldHandle::from_scenario(&s).unwrap();
    let (_sim, src) = live(&w, 1.0).await;
    src.grab().await.expect("first frame");
    let faults = [
        ("DropLink", Fault::DropLink),
        ("Truncated", Fault::Truncated),
        ("BadCrc", Fault::BadCrc),
        (
            "Garbage",
            Fault::Garbage {
                bytes: b"\x00\xffnot a part\r\n--x\r\n".to_vec(),
            },
        ),
        ("Silence 2 s", Fault::Silence { secs: 2.0 }),
        ("Delay 2 s", Fault::Delay { secs: 2.0 }),
        ("ErrorReply", Fault::ErrorReply { code: 503 }),
    ];
    for (name, fault) in faults {
        w.control().inject("cam", fault);
        let t0 = std::time::Instant::now();
        let mut seen = Vec::new();
        let mut good = None;
        while t0.elapsed().as_secs_f64() < 15.0 {
            match src.grab().await {
                Ok(img) => match find_chessboard(&img, 8, 5, Detector::Classic).unwrap() {
                    Some(c) => {
                        let (_, m) = rms_max(&errors(&c, &truth(&w, &s)));
                        if m < 0.3 {
                            good = Some(t0.elapsed().as_secs_f64());
                            break;
                        }
                        seen.push(format!("frame with corners off by {m:.2} px"));
                    }
                    None => seen.push("frame without a board (damaged)".into()),
                },
                Err(e) => seen.push(format!("{}", e.kind())),
            }
        }
        seen.dedup();
        println!(
            "{name:<12} → {} ; good frame after {:.2} s",
            if seen.is_empty() {
                "no visible effect".to_string()
            } else {
                seen.join(", ")
            },
            good.unwrap_or(f64::NAN)
        );
        assert!(
            good.is_some(),
            "{name}: no good frame within 15 s ({seen:?})"
        );
    }
}
