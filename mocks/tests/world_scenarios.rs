//! Scenario files, determinism, time model, faults, Sim* devices, camera rendering.

use robocal_drivers::{
    ArmStatus, ErrorKind, ImageSource, JointReadout, MarkerTracker, MoveJoints, MoveSpeed,
    RangeReading, RangeSensor, SafetyState, ToolStatus,
};
use robocal_mocks::scenario::Scenario;
use robocal_mocks::sim::{SimArm, SimDevices};
use robocal_mocks::world::{sensors, Fault};
use robocal_mocks::WorldHandle;
use std::path::PathBuf;

fn scenario_files() -> Vec<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenarios");
    let mut v: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    v.sort();
    v
}

fn load(name: &str) -> Scenario {
    Scenario::load(
        &PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("scenarios")
            .join(name),
    )
    .unwrap()
}

#[test]
fn every_scenario_file_parses_and_builds() {
    let files = scenario_files();
    let names: Vec<String> = files
        .iter()
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    for want in [
        "lab-vs060-optotrak-il600.toml",
        "hospital-vs060-vega.toml",
        "ur5e-camera.toml",
        "fleet-vs060-x5.toml",
    ] {
        assert!(names.iter().any(|n| n == want), "missing {want}");
    }
    for f in &files {
        let s = Scenario::load(f).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
        let w = WorldHandle::from_scenario(&s).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
        assert!(!s.devices().is_empty());
        for (name, _) in s.devices() {
            assert!(w.device(&name).is_some());
        }
    }
    let fleet = load("fleet-vs060-x5.toml");
    let w = WorldHandle::from_scenario(&fleet).unwrap();
    let t = w.truth();
    assert_eq!(t.arms.len(), 5);
    for i in 1..5 {
        assert_ne!(t.arms[0].physics.chain, t.arms[i].physics.chain);
    }
}

#[test]
fn scenarios_are_strict() {
    let good = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenarios/hospital-vs060-vega.toml"),
    )
    .unwrap();
    let bad = good.replace("rate_hz = 60.0", "rate_hz = 60.0\nrate_hertz = 60.0");
    assert!(
        Scenario::from_toml(&bad).is_err(),
        "unknown field must be rejected"
    );
    let bad = good.replace("protocol = \"ndi-tcp\"", "protocol = \"telnet\"");
    assert!(Scenario::from_toml(&bad).is_err());
    let bad = good.replace("arm = \"vs060\"", "arm = \"nobody\"");
    let s = Scenario::from_toml(&bad).unwrap();
    assert!(WorldHandle::from_scenario(&s).is_err());
}

fn session(s: &Scenario, n: usize) -> (Vec<String>, f64) {
    let w = WorldHandle::from_scenario(s).unwrap();
    let mut out = Vec::new();
    let qs = [
        [0.0, 45.0, 60.0, 0.0, 30.0, 0.0],
        [-30.0, 20.0, 90.0, 40.0, -30.0, 10.0],
        [25.0, 35.0, 100.0, -60.0, 45.0, 90.0],
    ];
    for k in 0..n {
        let q: Vec<f64> = qs[k % 3].iter().map(|x: &f64| x.to_radians()).collect();
        w.arm_start_move(0, &q, MoveSpeed::default()).unwrap();
        w.advance(w.arm_motion_end(0) - w.now());
        let js = w.arm_joint_state(0);
        for _ in 0..5 {
            out.push(format!("{:?}", w.tracker_frame()));
        }
        if w.laser_count() > 0 {
            out.push(format!("{:?}", w.laser_reading()));
        }
        out.push(format!("{:?}", js.q));
    }
    (out, w.now())
}

#[test]
fn same_scenario_same_seed_gives_identical_measurements() {
    let s = load("lab-vs060-optotrak-il600.toml");
    let (a, _) = session(&s, 30);
    let (b, _) = session(&s, 30);
    assert_eq!(a, b);
    let mut s2 = s.clone();
    s2.seed += 1;
    let (c, _) = session(&s2, 30);
    assert_ne!(a, c);
}

#[test]
fn a_600_pose_session_simulates_in_seconds_of_wall_time() {
    let s = load("lab-vs060-optotrak-il600.toml");
    let t0 = std::time::Instant::now();
    let (_, sim_t) = session(&s, 600);
    let wall = t0.elapsed().as_secs_f64();
    println!("600 poses: {sim_t:.1} s simulated in {wall:.2} s wall");
    assert!(sim_t > 600.0, "moves take simulated time");
    assert!(wall < 30.0);
}

#[test]
fn moves_follow_synchronised_trapezoids_and_real_time_mode_waits() {
    let s = load("lab-vs060-optotrak-il600.toml");
    let w = WorldHandle::from_scenario(&s).unwrap();
    let speed = MoveSpeed {
        max_vel: 30f64.to_radians(),
        max_acc: 60f64.to_radians(),
    };
    let start = w.arm_joint_state(0).q;
    let mut target = start.clone();
    target[0] += 60f64.to_radians();
    target[1] += 15f64.to_radians();
    let dur = w.arm_start_move(0, &target, speed).unwrap();
    // 60° at 30°/s, 60°/s²: 2 s cruise + 0.5 s accel + 0.5 s decel = 2.5 s, + 0.3 s settling.
    assert!((dur - 2.8).abs() < 1e-3, "{dur}");
    assert!(w.arm_is_moving(0));
    w.advance(1.25);
    let mid = w.arm_joint_state(0);
    let frac0 = (mid.q[0] - start[0]) / 60f64.to_radians();
    let frac1 = (mid.q[1] - start[1]) / 15f64.to_radians();
    assert!(
        (frac0 - 0.5).abs() < 1e-4 && (frac1 - 0.5).abs() < 1e-4,
        "joints arrive together"
    );
    assert!((mid.qd.unwrap()[0] - 30f64.to_radians()).abs() < 1e-4);
    w.advance(1.6);
    assert!(!w.arm_is_moving(0));
    // Real-time mode: the wait takes wall time.
    let mut rs = s.clone();
    rs.clock = robocal_mocks::scenario::ClockMode::Real;
    let rw = WorldHandle::from_scenario(&rs).unwrap();
    let mut t = rw.arm_joint_state(0).q;
    t[5] += 0.05;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let t0 = std::time::Instant::now();
    let d = rw.arm_start_move(0, &t, MoveSpeed::default()).unwrap();
    rt.block_on(rw.arm_wait_arrival(0));
    assert!(t0.elapsed().as_secs_f64() >= d * 0.9);
}

#[tokio::test]
async fn faults_reach_the_devices_in_order() {
    let s = load("lab-vs060-optotrak-il600.toml");
    let w = WorldHandle::from_scenario(&s).unwrap();
    let c = w.control();
    c.inject("certus", Fault::BadCrc);
    c.inject("certus", Fault::DropLink);
    assert_eq!(c.pending_faults("certus"), 2);
    assert_eq!(c.take_fault("certus"), Some(Fault::BadCrc));
    assert_eq!(c.take_fault("vs060"), None);
    let devs = SimDevices::of(&w);
    let tracker = &devs.trackers[0].1;
    assert_eq!(
        tracker.frame().await.unwrap_err().kind(),
        ErrorKind::Disconnected
    );
    assert!(tracker.frame().await.is_ok());
    let arm: &SimArm = &devs.arms[0].1;
    c.inject("vs060", Fault::ErrorReply { code: -2147483648 });
    assert_eq!(
        arm.joints().await.unwrap_err().kind(),
        ErrorKind::DeviceRejected
    );
    c.inject("vs060", Fault::Silence { secs: 2.0 });
    let t0 = w.now();
    assert_eq!(arm.joints().await.unwrap_err().kind(), ErrorKind::Timeout);
    assert!(w.now() - t0 >= 2.0 - 1e-9);
    c.inject(
        "il600",
        Fault::Garbage {
            bytes: vec![0xff, 0x00],
        },
    );
    let laser = &devs.lasers[0].1;
    assert_eq!(
        laser.read_range().await.unwrap_err().kind(),
        ErrorKind::Protocol
    );
    // Protective stop: moves refused, recover clears it.
    let mut q = arm.joints().await.unwrap().q;
    q[0] += 0.1;
    c.protective_stop(0);
    assert_eq!(
        arm.state().await.unwrap().safety,
        SafetyState::ProtectiveStop
    );
    assert_eq!(
        arm.move_joints(&q, MoveSpeed::default())
            .await
            .unwrap_err()
            .kind(),
        ErrorKind::SafetyStop
    );
    arm.recover().await.unwrap();
    arm.move_joints(&q, MoveSpeed::default()).await.unwrap();
    assert!((arm.joints().await.unwrap().q[0] - q[0]).abs() < 1e-4);
    // Out of limits.
    let mut bad = q.clone();
    bad[0] = 4.0;
    assert_eq!(
        arm.move_joints(&bad, MoveSpeed::default())
            .await
            .unwrap_err()
            .kind(),
        ErrorKind::InvalidArgument
    );
    // Laser and tracker through the traits.
    let _ = laser.read_range().await.unwrap();
    assert!(matches!(
        tracker.frame().await.unwrap().tools[0].status,
        ToolStatus::Visible { .. } | ToolStatus::Missing | ToolStatus::OutOfVolume
    ));
    let _ = RangeReading::OutOfRange;
}

#[tokio::test]
async fn camera_renders_the_chessboard_where_the_projection_says() {
    let mut s = load("ur5e-camera.toml");
    // Noise-free, blur-free render for a pixel-exact check.
    s.cameras[0].noise_grey = 0.0;
    s.cameras[0].blur_px = 0.0;
    let w = WorldHandle::from_scenario(&s).unwrap();
    let devs = SimDevices::of(&w);
    let img = devs.cameras[0].1.grab().await.unwrap();
    assert_eq!((img.width, img.height), (640, 480));
    assert_eq!(img.data.len(), 640 * 480);
    let cam = &s.cameras[0];
    let board = s.scene.chessboard.as_ref().unwrap();
    let cam_in_base = w.camera_in_base(0).unwrap();
    let board_in_cam = cam_in_base.inverse() * board.placement.isometry();
    let (mut checked, mut dark, mut bright) = (0, 0, 0);
    for i in 0..board.cols {
        for j in 0..board.rows {
            let c = nalgebra::Point3::new(
                (i as f64 + 0.5) * board.square_mm,
                (j as f64 + 0.5) * board.square_mm,
                0.0,
            );
            let Some((u, v)) = sensors::project(cam, &(board_in_cam * c)) else {
                continue;
            };
            if u < 2.0 || v < 2.0 || u > 637.0 || v > 477.0 {
                continue;
            }
            let g = img.data[(v.round() as usize) * 640 + u.round() as usize];
            if (i + j) % 2 == 0 {
                assert!(g < 60, "square ({i},{j}) should be dark: {g}");
                dark += 1;
            } else {
                assert!(g > 200, "square ({i},{j}) should be bright: {g}");
                bright += 1;
            }
            checked += 1;
        }
    }
    println!("camera: {checked} square centres checked ({dark} dark, {bright} bright)");
    assert!(checked >= 40);
    // Noise and blur change pixels but keep the pattern.
    let w2 = WorldHandle::from_scenario(&load("ur5e-camera.toml")).unwrap();
    let img2 = w2.render_camera();
    let diff = img
        .data
        .iter()
        .zip(&img2.data)
        .filter(|(a, b)| (**a as i32 - **b as i32).abs() > 40)
        .count();
    assert!(diff < img.data.len() / 20, "{diff}");
    assert_ne!(img.data, img2.data);
}
