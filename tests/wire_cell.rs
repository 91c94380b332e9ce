//! The wire-level dry-run cell (`robocal::cell::wire_cell`): the scenario's simulators on
//! loopback TCP / ptys, the REAL drivers connected to them. Readings through the wire equal
//! the world's truth within each protocol's resolution, and the acquisition engine records
//! every pose of a small seed-001 plan over the wire cell on the virtual clock.
use std::path::Path;

use nalgebra::Isometry3;
use robocal::acquire::{acquire, AcquireOptions, Devices, PlannedPose};
use robocal::cell::wire_cell;
use robocal::dataset::{Dataset, Header, Journal, Record, RobotBlock};
use robocal::model::KinematicModel;
use robocal::plan::{build_plan, PlanOptions, PlanSpec};
use robocal_drivers::safety::{guard, SafetyLimits};
use robocal_drivers::{MoveSpeed, RangeReading, ToolStatus};
use robocal_mocks::scenario::Protocol;
use robocal_mocks::{Scenario, WorldHandle};

const HOSPITAL: &str = "mocks/scenarios/hospital-vs060-vega.toml";
const LAB: &str = "mocks/scenarios/lab-vs060-optotrak-il600.toml";
const UR5E: &str = "mocks/scenarios/ur5e-camera.toml";

/// Joint targets (deg) in front of the VS060: the marker is visible to both trackers and
/// the lab laser beam meets P1, P1 and P2 (about 310, 402 and 569 mm; P2 beyond the
/// IL-600's incidence limit: out of range). The last one is the home pose, reached from the
/// second target.
const TARGETS_DEG: [[f64; 6]; 3] = [
    [10.0, 10.0, 80.0, 5.0, 40.0, -10.0],
    [5.0, -5.0, 100.0, 15.0, 35.0, 0.0],
    [0.0, 0.0, 90.0, 0.0, 45.0, 0.0],
];

/// The scenario file; with `noise_free` the tracker and laser noise is zeroed so that the
/// wire readings can be compared with the truth at the protocols' resolution.
fn scenario(file: &str, noise_free: bool) -> Scenario {
    let mut s = Scenario::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join(file)).unwrap();
    if noise_free {
        for t in &mut s.trackers {
            t.effects.noise_lateral_mm = 0.0;
            t.effects.noise_depth_mm = 0.0;
            t.effects.noise_rot_deg = 0.0;
        }
        for l in &mut s.lasers {
            l.effects.noise_mm = 0.0;
        }
    }
    s
}

/// The VS060's joint limits (as `robocal run` derives them from the plan's robot).
fn limits(max_vel: f64, max_acc: f64) -> SafetyLimits {
    let model = KinematicModel::preset("denso-vs060").unwrap();
    let (joint_lower, joint_upper) = model.joint_limits().into_iter().unzip();
    SafetyLimits {
        joint_lower,
        joint_upper,
        max_vel,
        max_acc,
        envelope: None,
        table: None,
        path_step: 1f64.to_radians(),
    }
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len(), "{a:?} vs {b:?}");
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

fn assert_pose_close(got: &Isometry3<f64>, want: &Isometry3<f64>, mm: f64, rad: f64, what: &str) {
    let dp = (got.translation.vector - want.translation.vector).norm();
    let dr = got.rotation.angle_to(&want.rotation);
    assert!(dp <= mm && dr <= rad, "{what}: {dp:.3e} mm, {dr:.3e} rad");
}

/// Move through the guarded wire arm to each target; joints, flange, marker and laser
/// readings read over the wire must equal the world's truth.
async fn wire_equals_truth(s: Scenario, marker_tol_mm: f64, marker_tol_rad: f64) {
    let world = WorldHandle::from_scenario(&s).unwrap();
    let (devices, info, served) = wire_cell(&robocal::cell::SimCell::of(&world))
        .await
        .expect("wire cell");
    assert_eq!(info.serial, world.arm_identity(0).map(|(_, s)| s));
    assert!(
        served.endpoints.iter().any(|e| e.protocol == "bcap"),
        "{:?}",
        served.json_lines()
    );
    let s = world.scenario();
    let tracker_on_wire = matches!(
        s.trackers[0].protocol,
        Protocol::NdiTcp | Protocol::NdiSerial
    );
    if tracker_on_wire {
        let proto = s.trackers[0].protocol.as_str();
        assert!(
            served
                .endpoints
                .iter()
                .any(|e| e.device == s.trackers[0].name && e.protocol == proto),
            "{:?}",
            served.json_lines()
        );
    }
    // The Optotrak has no wire protocol in this build: it must be listed as in-process.
    assert_eq!(
        served
            .unavailable
            .iter()
            .any(|(d, _, _)| *d == s.trackers[0].name),
        !tracker_on_wire,
        "{:?}",
        served.unavailable
    );
    let arm = guard(devices.arm.clone(), limits(1.0, 2.0), None);
    let tracker = devices.tracker.clone().expect("tracker");
    let speed = MoveSpeed {
        max_vel: 1.0,
        max_acc: 2.0,
    };
    let (mut lasers_hit, mut lasers_oor) = (0, 0);
    for target_deg in TARGETS_DEG {
        let target: Vec<f64> = target_deg.iter().map(|d| d.to_radians()).collect();
        arm.move_joints(&target, speed).await.expect("move");
        assert!(
            !world.arm_is_moving(0),
            "the move returned before the arm stopped"
        );

        // Joints: b-CAP CurJnt carries doubles (deg); the encoders are within the servo error
        // and backlash of the target.
        let q = arm.joints().await.expect("joints").q;
        let truth_q = world.arm_joint_state(0).q;
        assert!(max_abs_diff(&q, &truth_q) < 1e-9, "{q:?} vs {truth_q:?}");
        assert!(
            max_abs_diff(&q, &target) < 1e-3,
            "{q:?} vs target {target:?}"
        );
        // Flange: @CURRENT_POSITION (doubles, mm / deg) = the controller's nominal FK.
        let flange = arm.flange_pose().await.expect("flange").0;
        assert_pose_close(
            &flange,
            &world.arm_controller_flange(0),
            1e-6,
            1e-8,
            "flange",
        );

        // Marker: the first tool of a frame; truth from the hidden tracker and marker
        // placements composed with the true flange, and from `world.marker_truth`.
        let frame = tracker.frame().await.expect("tracker frame");
        let got = match &frame.tools.first().expect("one tool").status {
            ToolStatus::Visible { pose, .. } => pose.0,
            other => panic!("marker not visible at {target_deg:?}: {other:?}"),
        };
        let truth = world.control().truth();
        let tt = &truth.trackers[0];
        let composed =
            tt.tracker_in_base.inverse() * world.arm_true_flange(0) * tt.marker_on_flange;
        let want = world.marker_truth(0).expect("marker truth");
        assert_pose_close(&composed, &want, 1e-9, 1e-12, "truth composition");
        assert_pose_close(&got, &want, marker_tol_mm, marker_tol_rad, "marker");

        // Laser: DL-RS1A displays 0.01 mm steps (half a step of rounding).
        if let Some(range) = &devices.range {
            let reading = range.read_range().await.expect("laser");
            let (d, _, surface) = world.laser_truth(0).expect("the beam hits a surface");
            match reading {
                RangeReading::Distance(m) => {
                    assert!((m - d).abs() <= 0.005 + 1e-9, "{m} vs {d} on {surface}");
                    lasers_hit += 1;
                }
                RangeReading::OutOfRange => {
                    // The beam meets the surface beyond the head's incidence limit: the
                    // world's own (noise-free) sensor model says so too.
                    assert_eq!(
                        world.laser_reading_of(0),
                        RangeReading::OutOfRange,
                        "wire: out of range, truth {d} mm on {surface}"
                    );
                    lasers_oor += 1;
                }
            }
        }
    }
    if s.lasers.is_empty() {
        assert!(devices.range.is_none());
    } else {
        assert_eq!(lasers_hit + lasers_oor, TARGETS_DEG.len());
        assert!(lasers_hit >= 2, "{lasers_hit} distances read");
    }
    served.abort();
}

#[tokio::test]
async fn hospital_bcap_and_vega_tcp_over_the_wire_equal_the_truth() {
    // NDI BX: float32 transforms (~1e-4 mm at 2 m).
    wire_equals_truth(scenario(HOSPITAL, true), 2e-3, 1e-5).await;
}

#[tokio::test]
async fn lab_bcap_optotrak_fallback_and_keyence_pty_equal_the_truth() {
    // The Optotrak falls back to the in-process device: exact.
    wire_equals_truth(scenario(LAB, true), 1e-9, 1e-12).await;
}

#[tokio::test]
async fn hospital_with_a_serial_polaris_over_a_pty_equals_the_truth() {
    // The same cell with a serial Polaris: the NDI client on the pty the simulator opened.
    let mut s = scenario(HOSPITAL, true);
    s.trackers[0].protocol = Protocol::NdiSerial;
    wire_equals_truth(s, 2e-3, 1e-5).await;
}

#[tokio::test]
async fn ur5e_over_rtde_dashboard_and_script_equals_the_truth() {
    let world = WorldHandle::from_scenario(&scenario(UR5E, true)).unwrap();
    let (devices, info, served) = wire_cell(&robocal::cell::SimCell::of(&world))
        .await
        .expect("wire cell");
    for proto in ["rtde", "dashboard", "script"] {
        assert!(
            served
                .endpoints
                .iter()
                .any(|e| e.device == "ur5e" && e.protocol == proto),
            "{:?}",
            served.json_lines()
        );
    }
    // The camera is served as MJPEG over HTTP; the cell has no tracker and no laser.
    assert!(
        served
            .endpoints
            .iter()
            .any(|e| e.device == "cam" && e.protocol == "mjpeg"),
        "{:?}",
        served.json_lines()
    );
    assert!(served.unavailable.is_empty(), "{:?}", served.unavailable);
    assert!(devices.tracker.is_none() && devices.range.is_none());
    assert_eq!(info.serial, world.arm_identity(0).map(|(_, s)| s));
    let model = KinematicModel::preset("ur5e").unwrap();
    let (joint_lower, joint_upper) = model.joint_limits().into_iter().unzip();
    let arm = guard(
        devices.arm.clone(),
        SafetyLimits {
            joint_lower,
            joint_upper,
            max_vel: 1.0,
            max_acc: 2.0,
            envelope: None,
            table: None,
            path_step: 1f64.to_radians(),
        },
        None,
    );
    let q0 = world.arm_joint_state(0).q;
    let speed = MoveSpeed {
        max_vel: 1.0,
        max_acc: 2.0,
    };
    for delta_deg in [
        [10.0, 5.0, -10.0, 5.0, 10.0, 20.0],
        [-15.0, -10.0, 5.0, -5.0, 0.0, -20.0],
        [0.0; 6],
    ] {
        let target: Vec<f64> = q0
            .iter()
            .zip(delta_deg)
            .map(|(q, d)| q + f64::to_radians(d))
            .collect();
        arm.move_joints(&target, speed).await.expect("move");
        assert!(!world.arm_is_moving(0));
        // RTDE actual_q: doubles.
        let q = arm.joints().await.expect("joints").q;
        let truth_q = world.arm_joint_state(0).q;
        assert!(max_abs_diff(&q, &truth_q) < 1e-9, "{q:?} vs {truth_q:?}");
        assert!(
            max_abs_diff(&q, &target) < 1e-3,
            "{q:?} vs target {target:?}"
        );
        // RTDE actual_TCP_pose: m + rotation vector, doubles.
        let flange = arm.flange_pose().await.expect("flange").0;
        assert_pose_close(
            &flange,
            &world.arm_controller_flange(0),
            1e-6,
            1e-9,
            "flange",
        );
    }
    served.abort();
}

/// The first `n` poses of the seed 001 plan, built in-process for the cell of `s`: the
/// spec's tracker and marker placements are replaced by the scenario's (as a user plans for
/// the cell at hand), so the planner's visibility check is about this tracker.
fn seed001_poses(s: &Scenario, n: usize) -> (RobotBlock, Vec<PlannedPose>) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("plans/seed001-annulus.toml");
    let mut spec = PlanSpec::from_file(&path).unwrap();
    let t = &s.trackers[0];
    if let Some(ts) = spec.tracker.as_mut() {
        ts.pose.xyz = t.tracker_in_base.xyz_mm;
        ts.pose.rpy = t.tracker_in_base.rpy_deg;
    }
    spec.tool.xyz = t.marker_on_flange.xyz_mm;
    spec.tool.rpy = t.marker_on_flange.rpy_deg;
    if let Some(a) = spec.annulus.as_mut() {
        a.points = a.points.min(3 * n);
    }
    let model = KinematicModel::preset("denso-vs060").unwrap();
    let robot = RobotBlock::named("denso-vs060");
    let out = build_plan(&spec, robot, &model, &PlanOptions::default()).unwrap();
    let poses: Vec<PlannedPose> = out
        .file
        .poses
        .iter()
        .take(n)
        .map(PlannedPose::from)
        .collect();
    assert_eq!(poses.len(), n, "the plan has too few poses");
    (out.file.robot, poses)
}

async fn acquire_over_wire(file: &str, n: usize) {
    let s = scenario(file, false);
    let world = WorldHandle::from_scenario(&s).unwrap();
    assert!(world.is_virtual());
    let (robot, poses) = seed001_poses(&s, n);
    let (mut devices, _info, served) = wire_cell(&robocal::cell::SimCell::of(&world))
        .await
        .expect("wire cell");
    let opts = AcquireOptions::default();
    devices.arm = guard(
        devices.arm.clone(),
        limits(opts.speed.max_vel, opts.speed.max_acc),
        None,
    );
    let devices: Devices = devices;
    let dir = tempfile::tempdir().unwrap();
    let mut header: Header = serde_json::from_value(serde_json::json!({
        "format": "robocal-dataset/1", "robot": {"model": "denso-vs060"}}))
    .unwrap();
    header.robot = robot;
    let path = dir.path().join("dataset.jsonl");
    let mut journal = Journal::create(&path, &header).unwrap();
    let t0 = world.now();
    let summary = acquire(&devices, &poses, &mut journal, &[], &opts, &mut |_| {})
        .await
        .expect("acquire");
    drop(journal);
    assert!(summary.aborted.is_none(), "{summary:?}");
    assert!(summary.skipped.is_empty(), "{summary:?}");
    assert_eq!((summary.planned, summary.recorded), (n, n), "{summary:?}");
    // Virtual time passed (moves, settling, frames) although the test ran in wall seconds.
    assert!(world.now() - t0 > summary.time.move_s, "{summary:?}");
    let ds = Dataset::load(&path).unwrap();
    let recorded: Vec<_> = ds
        .records
        .iter()
        .filter_map(|r| match r {
            Record::Pose(p) => Some(p),
            _ => None,
        })
        .collect();
    assert_eq!(recorded.len(), n);
    // A clean run over healthy links: the only faults are the laser's (beam off the planes).
    for r in &ds.records {
        if let Record::Event(e) = r {
            let why = e.reason.as_deref().unwrap_or("");
            assert!(
                e.what != "fault" || why.starts_with("laser out of range"),
                "{e:?}"
            );
            assert!(e.what != "retry" && e.what != "skip", "{e:?}");
        }
    }
    for (p, plan) in recorded.iter().zip(&poses) {
        assert_eq!(p.id, plan.id);
        assert!(p.marker.is_some(), "pose {} has no marker", p.id);
        let q = p.q.as_ref().expect("measured joints");
        assert!(
            max_abs_diff(q, &plan.q_deg) < 0.05,
            "{q:?} vs {:?}",
            plan.q_deg
        );
    }
    served.abort();
}

#[tokio::test]
async fn engine_records_every_seed001_pose_over_the_hospital_wire_cell() {
    acquire_over_wire(HOSPITAL, 12).await;
}

#[tokio::test]
async fn engine_records_every_seed001_pose_over_the_lab_wire_cell() {
    acquire_over_wire(LAB, 12).await;
}
