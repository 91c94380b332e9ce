//! The acquisition engine against the drivers' in-process fakes (issue 7).
use std::future::Future;
use std::path::Path;
use std::pin::Pin;
use std::sync::{Arc, Mutex};

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use robocal::acquire::{acquire, AcquireOptions, Devices, PlannedPose, RunSummary};
use robocal::dataset::{Dataset, Header, Journal, Record};
use robocal_drivers::fake::{FakeArm, FakeRange, FakeTracker};
use robocal_drivers::safety::{guard, SafetyLimits};
use robocal_drivers::{
    Arm, Clock, ErrorKind, MarkerToTracker, RangeReading, ToolObservation, ToolStatus, TrackerFrame,
};

/// A manual clock: `sleep` advances time instantly (deterministic, no real waiting).
#[derive(Debug, Default)]
struct TestClock(Mutex<f64>);

impl Clock for TestClock {
    fn now(&self) -> f64 {
        *self.0.lock().unwrap()
    }
    fn sleep<'a, 'b>(&'a self, secs: f64) -> Pin<Box<dyn Future<Output = ()> + Send + 'b>>
    where
        'a: 'b,
        Self: 'b,
    {
        Box::pin(async move {
            *self.0.lock().unwrap() += secs.max(0.0);
        })
    }
}

fn header() -> Header {
    let text = concat!(
        r#"{"format": "robocal-dataset/1", "created": "2026-11-21T09:30:00Z", "robot": {"model": "ur5e"}, "tracker": {"kind": "fake"}}"#,
        "\n"
    );
    robocal::dataset::parse_dataset(text.as_bytes(), Path::new("h"))
        .unwrap()
        .dataset
        .header
}

fn plan(n: usize) -> Vec<PlannedPose> {
    (0..n)
        .map(|i| {
            let x = i as f64;
            let mut p =
                PlannedPose::new(i as u64, vec![10.0 + x, -80.0 + x, 90.0, -x, 90.0, 2.0 * x]);
            p.point = Some(i as u64);
            p.branch = Some(0);
            p.group = Some(if i % 4 == 3 { "validation" } else { "train" }.into());
            p
        })
        .collect()
}

/// Marker position (mm, tracker frame) as a function of the joints (rad).
fn marker_of(q: &[f64]) -> Vector3<f64> {
    Vector3::new(-400.0 + 100.0 * q[0], 200.0 * q[1], -1500.0 + 50.0 * q[5])
}

struct Cell {
    arm: FakeArm,
    range: FakeRange,
    clock: Arc<TestClock>,
    /// Frames to report as missing while the arm is at pose `id` (`usize::MAX`: always).
    hidden: Arc<Mutex<Vec<(u64, usize)>>>,
    devices: Devices,
}

fn target_rad(p: &PlannedPose) -> Vec<f64> {
    p.q_deg.iter().map(|d| d.to_radians()).collect()
}

fn cell(plan: &[PlannedPose], journal_path: Option<&Path>) -> Cell {
    let arm = FakeArm::new(vec![0.0; 6]).with_flange(|q| {
        Isometry3::from_parts(
            Translation3::new(400.0 + q[0], 10.0 * q[1], 500.0),
            UnitQuaternion::from_euler_angles(q[3], 0.0, q[5]),
        )
    });
    let range = FakeRange::new(RangeReading::Distance(512.0));
    let clock = Arc::new(TestClock::default());
    let hidden: Arc<Mutex<Vec<(u64, usize)>>> = Arc::new(Mutex::new(Vec::new()));
    let targets: Vec<(u64, Vec<f64>)> = plan.iter().map(|p| (p.id, target_rad(p))).collect();
    let (a2, h2, c2) = (arm.clone(), hidden.clone(), clock.clone());
    let jp = journal_path.map(Path::to_path_buf);
    let tracker = FakeTracker::new(move |n| {
        let q = a2.q();
        c2.0.lock().map(|mut t| *t += 1.0 / 60.0).unwrap(); // 60 Hz tracker
        let id = targets.iter().find(|(_, t)| *t == q).map(|(id, _)| *id);
        // Records are on disk before the arm measures the next pose: every pose before
        // the current one is already in the journal (or skipped).
        if let (Some(id), Some(jp)) = (id, &jp) {
            let ds = Dataset::load(jp).unwrap();
            let handled = robocal::acquire::done_pose_ids(&ds.records);
            assert!(
                (0..id).all(|k| handled.contains(&k)),
                "pose {id} measured before earlier poses were journaled: {handled:?}"
            );
        }
        let mut hid = h2.lock().unwrap();
        let status =
            if let Some(slot) = hid.iter_mut().find(|(h, left)| Some(*h) == id && *left > 0) {
                if slot.1 != usize::MAX {
                    slot.1 -= 1;
                }
                ToolStatus::Missing
            } else {
                let mut p = marker_of(&q);
                // Every 10th frame is a 3 mm outlier the averaging must reject.
                if n % 10 == 0 {
                    p.x += 3.0;
                }
                // Tiny deterministic jitter.
                p.y += 0.01 * ((n % 3) as f64 - 1.0);
                ToolStatus::Visible {
                    pose: MarkerToTracker(Isometry3::from_parts(
                        Translation3::from(p),
                        UnitQuaternion::identity(),
                    )),
                    rms_mm: 0.05,
                }
            };
        Ok(TrackerFrame {
            frame_number: n,
            t: 0.0,
            tools: vec![ToolObservation {
                tool: "marker".into(),
                status,
            }],
        })
    });
    let limits = SafetyLimits {
        joint_lower: vec![-170f64.to_radians(); 6],
        joint_upper: vec![170f64.to_radians(); 6],
        max_vel: 20f64.to_radians(),
        max_acc: 40f64.to_radians(),
        envelope: None,
        table: None,
        path_step: 1f64.to_radians(),
    };
    let raw: Arc<dyn Arm> = Arc::new(arm.clone());
    let devices = Devices {
        arm: guard(raw, limits, None),
        tracker: Some(Arc::new(tracker)),
        range: Some(Arc::new(range.clone())),
        clock: clock.clone(),
        thermometer: None,
    };
    Cell {
        arm,
        range,
        clock,
        hidden,
        devices,
    }
}

fn opts() -> AcquireOptions {
    let mut o = AcquireOptions::default();
    o.sample.frames = 20;
    o.sample.min_frames = 10;
    o.settle.poll_s = 0.02;
    o
}

fn run(
    cell: &Cell,
    plan: &[PlannedPose],
    journal: &mut Journal,
    existing: &[Record],
    opts: &AcquireOptions,
) -> RunSummary {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let mut progress = Vec::new();
    let s = rt
        .block_on(acquire(
            &cell.devices,
            plan,
            journal,
            existing,
            opts,
            &mut |p| progress.push(p.clone()),
        ))
        .unwrap();
    // One progress report per handled pose, ending at the handled count.
    if let Some(last) = progress.last() {
        assert_eq!(
            last.done,
            s.already_done + s.recorded_now + s.skipped.len() - skipped_before(existing)
        );
    }
    s
}

fn skipped_before(existing: &[Record]) -> usize {
    existing
        .iter()
        .filter(|r| matches!(r, Record::Event(e) if e.what == "skip"))
        .count()
}

fn events<'a>(ds: &'a Dataset, what: &str) -> Vec<&'a robocal::dataset::EventRecord> {
    ds.records
        .iter()
        .filter_map(|r| match r {
            Record::Event(e) if e.what == what => Some(e),
            _ => None,
        })
        .collect()
}

#[test]
fn records_every_pose_with_averaged_marker_and_laser() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dataset.jsonl");
    let plan = plan(8);
    let c = cell(&plan, Some(&path));
    let mut j = Journal::create(&path, &header()).unwrap();
    let s = run(&c, &plan, &mut j, &[], &opts());
    assert_eq!(s.recorded, 8);
    assert!(s.skipped.is_empty() && s.aborted.is_none() && s.remaining == 0);
    let ds = Dataset::load(&path).unwrap();
    let poses: Vec<_> = ds.poses().collect();
    assert_eq!(poses.len(), 8);
    for (rec, p) in poses.iter().zip(&plan) {
        assert_eq!(rec.id, p.id);
        assert_eq!(rec.q_cmd.as_ref().unwrap(), &p.q_deg);
        let q = rec.q.as_ref().unwrap();
        for (a, b) in q.iter().zip(&p.q_deg) {
            assert!((a - b).abs() < 1e-9);
        }
        assert_eq!(rec.group, p.group);
        let m = rec.marker.as_ref().unwrap();
        let want = marker_of(&target_rad(p));
        let got = Vector3::from(m.p.unwrap());
        // The 3 mm outliers are rejected: the mean is within the jitter.
        assert!((got - want).norm() < 0.02, "{got} vs {want}");
        assert!(m.frames.unwrap() >= 17 && m.frames.unwrap() <= 20);
        assert!((m.rms.unwrap() - 0.05).abs() < 1e-12);
        assert_eq!(rec.range, Some(Some(512.0)));
        let f = rec.flange.as_ref().unwrap();
        assert!((f.p[0] - (400.0 + p.q_deg[0].to_radians())).abs() < 1e-9);
    }
    // Every move went through the speed cap of the safety wrapper (20 °/s).
    let cmds = c.arm.commands();
    assert_eq!(cmds.len(), 8);
    assert!(cmds
        .iter()
        .all(|m| m.speed.max_vel <= 20f64.to_radians() + 1e-12));
    // Time is increasing and the breakdown adds up.
    let ts: Vec<f64> = poses.iter().map(|p| p.t).collect();
    assert!(ts.windows(2).all(|w| w[1] > w[0]), "{ts:?}");
    assert!(s.time.sample_s > 0.0 && s.time.settle_s > 0.0);
    assert!((s.time.total_s() - c.clock.now()).abs() < 1e-9);
    assert!(s.poses_per_hour > 0.0);
}

#[test]
fn marker_not_visible_is_retried_then_skipped() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dataset.jsonl");
    let plan = plan(6);
    let c = cell(&plan, Some(&path));
    // Pose 2: never visible. Pose 4: invisible for the first 25 frames (1 retry).
    c.hidden.lock().unwrap().push((2, usize::MAX));
    c.hidden.lock().unwrap().push((4, 25));
    let mut j = Journal::create(&path, &header()).unwrap();
    let s = run(&c, &plan, &mut j, &[], &opts());
    assert_eq!(s.recorded, 5);
    assert_eq!(s.skipped.len(), 1);
    assert_eq!(s.skipped[0].id, 2);
    assert_eq!(s.skipped[0].reason, "marker not visible after 4 tries");
    let ds = Dataset::load(&path).unwrap();
    let ids: Vec<u64> = ds.poses().map(|p| p.id).collect();
    assert_eq!(ids, vec![0, 1, 3, 4, 5]);
    let retries = events(&ds, "retry");
    assert_eq!(retries.iter().filter(|e| e.id == Some(2)).count(), 3);
    assert!(retries.iter().any(|e| e.id == Some(4)));
    let skips = events(&ds, "skip");
    assert_eq!(skips.len(), 1);
    assert_eq!(skips[0].id, Some(2));
}

#[test]
fn laser_out_of_range_is_null_with_an_event() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dataset.jsonl");
    let plan = plan(3);
    let c = cell(&plan, Some(&path));
    // Pose 0 reads 5 valid readings (default); pose 1: all out of range.
    for _ in 0..5 {
        c.range.push(Ok(RangeReading::Distance(500.0)));
    }
    for _ in 0..5 {
        c.range.push(Ok(RangeReading::OutOfRange));
    }
    let mut j = Journal::create(&path, &header()).unwrap();
    let s = run(&c, &plan, &mut j, &[], &opts());
    assert_eq!(s.recorded, 3);
    let ds = Dataset::load(&path).unwrap();
    let r: Vec<Option<Option<f64>>> = ds.poses().map(|p| p.range).collect();
    assert_eq!(r, vec![Some(Some(500.0)), Some(None), Some(Some(512.0))]);
    let f = events(&ds, "fault");
    assert_eq!(f.len(), 1);
    assert_eq!(f[0].id, Some(1));
    assert!(f[0].reason.as_ref().unwrap().contains("laser out of range"));
}

#[test]
fn unreachable_pose_is_skipped_by_the_safety_wrapper() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dataset.jsonl");
    let mut plan = plan(4);
    plan[1].q_deg[2] = 175.0; // beyond the 170° limit
    let c = cell(&plan, Some(&path));
    let mut j = Journal::create(&path, &header()).unwrap();
    let s = run(&c, &plan, &mut j, &[], &opts());
    assert_eq!(s.recorded, 3);
    assert_eq!(s.skipped.len(), 1);
    assert_eq!(s.skipped[0].id, 1);
    assert!(
        s.skipped[0].reason.starts_with("unreachable"),
        "{}",
        s.skipped[0].reason
    );
    // The refused target never reached the arm.
    assert_eq!(c.arm.commands().len(), 3);
}

#[test]
fn link_drop_backs_off_reconnects_and_reverifies() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dataset.jsonl");
    let plan = plan(3);
    let c = cell(&plan, Some(&path));
    c.arm.fail_next_move(ErrorKind::Disconnected);
    c.arm.fail_next_move(ErrorKind::Timeout);
    let mut j = Journal::create(&path, &header()).unwrap();
    let s = run(&c, &plan, &mut j, &[], &opts());
    assert_eq!(s.recorded, 3);
    assert!(s.aborted.is_none());
    let ds = Dataset::load(&path).unwrap();
    let f = events(&ds, "fault");
    assert_eq!(f.len(), 1, "one fault event per outage");
    assert!(f[0]
        .reason
        .as_ref()
        .unwrap()
        .contains("link lost during move"));
    let r = events(&ds, "resume");
    assert!(r[0]
        .reason
        .as_ref()
        .unwrap()
        .contains("after 2 failed attempt"));
    let notes = events(&ds, "note");
    assert!(notes
        .iter()
        .any(|e| e.reason.as_ref().unwrap().contains("position re-verified")));
    // Backoff 0.5 s then 1.0 s is part of the move time.
    assert!(s.time.move_s >= 1.5, "{:?}", s.time);
    assert_eq!(c.arm.commands().len(), 5);
}

#[test]
fn protective_stop_pauses_recovers_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dataset.jsonl");
    let plan = plan(3);
    let c = cell(&plan, Some(&path));
    c.arm.fail_next_move(ErrorKind::SafetyStop);
    c.arm
        .set_safety(robocal_drivers::SafetyState::ProtectiveStop);
    let mut j = Journal::create(&path, &header()).unwrap();
    let s = run(&c, &plan, &mut j, &[], &opts());
    assert_eq!(s.recorded, 3);
    let ds = Dataset::load(&path).unwrap();
    let pauses = events(&ds, "pause");
    assert!(!pauses.is_empty());
    assert!(pauses[0]
        .reason
        .as_ref()
        .unwrap()
        .contains("protective stop"));
    assert_eq!(events(&ds, "resume").len(), pauses.len());
}

#[test]
fn persistent_link_loss_aborts_and_resume_completes() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dataset.jsonl");
    let plan = plan(5);
    let c = cell(&plan, Some(&path));
    let mut j = Journal::create(&path, &header()).unwrap();
    let mut o = opts();
    o.max_poses = Some(2);
    let s = run(&c, &plan, &mut j, &[], &o);
    assert_eq!((s.recorded, s.remaining), (2, 3));
    // The link goes down for good during pose 2.
    for _ in 0..6 {
        c.arm.fail_next_move(ErrorKind::Disconnected);
    }
    drop(j);
    let (mut j, loaded) = Journal::open(&path).unwrap();
    let s = run(&c, &plan, &mut j, &loaded.dataset.records, &opts());
    assert!(s.aborted.as_ref().unwrap().contains("link lost"), "{s:?}");
    assert_eq!(s.recorded, 2);
    assert_eq!(s.remaining, 3);
    // Power cut in the middle of writing: a torn line at the end.
    drop(j);
    let mut f = std::fs::OpenOptions::new()
        .append(true)
        .open(&path)
        .unwrap();
    std::io::Write::write_all(&mut f, br#"{"kind": "pose", "id": 2, "t": 99"#).unwrap();
    drop(f);
    let (mut j, loaded) = Journal::open(&path).unwrap();
    assert_eq!(loaded.warnings.len(), 1);
    let s = run(&c, &plan, &mut j, &loaded.dataset.records, &opts());
    assert_eq!(s.recorded, 5);
    assert_eq!(s.already_done, 2);
    assert_eq!(s.recorded_now, 3);
    let ds = Dataset::load(&path).unwrap();
    let ids: Vec<u64> = ds.poses().map(|p| p.id).collect();
    assert_eq!(ids, vec![0, 1, 2, 3, 4]);
    assert_eq!(s.events["resume"], 2);
}

#[test]
fn plan_must_fit_the_robot() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dataset.jsonl");
    let mut plan = plan(2);
    plan[1].q_deg.pop();
    let c = cell(&plan, None);
    let mut j = Journal::create(&path, &header()).unwrap();
    let rt = tokio::runtime::Builder::new_current_thread()
        .build()
        .unwrap();
    let e = rt
        .block_on(acquire(
            &c.devices,
            &plan,
            &mut j,
            &[],
            &opts(),
            &mut |_| {},
        ))
        .unwrap_err();
    assert!(e.to_string().contains("plan pose 1"), "{e}");
    assert!(c.arm.commands().is_empty());
}
