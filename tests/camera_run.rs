//! Camera acquisition: `robocal run` on the UR5e + eye-in-hand camera scenario with a small
//! seed-004 (camera viewpoints on a shell) plan records one PGM image per pose next to the
//! journal, detects the chessboard (feature `opencv`), survives a kill between image and
//! record, and keeps the pose through camera faults.
use std::collections::HashSet;
use std::path::{Path, PathBuf};

use robocal::acquire::{acquire, AcquireOptions, PlannedPose, RunSummary};
use robocal::dataset::{Dataset, Header, Journal, PoseRecord};
use robocal::plan::PlanFile;
use robocal_drivers::camera::read_image_file;
use robocal_drivers::safety::{guard, SafetyLimits};
use robocal_mocks::scenario::ClockMode;
use robocal_mocks::world::Fault;
use robocal_mocks::{Scenario, WorldHandle};

const SCENARIO: &str = "mocks/scenarios/ur5e-camera.toml";

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn cli(args: &[&str]) -> i32 {
    let mut v = vec!["robocal".to_string()];
    v.extend(args.iter().map(|s| s.to_string()));
    robocal::main_with_args(v)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A small seed-004 plan (12 viewpoints) for the UR5e, aimed at the scenario's chessboard:
/// the shell is centred on the board (the seed's own centre is not where this scenario's
/// board lies) and far enough for the whole 9×6-square board to fit in the 640×480 view.
fn camera_plan(dir: &Path) -> PathBuf {
    let scenario = Scenario::load(&root().join(SCENARIO)).unwrap();
    let board = scenario.scene.chessboard.clone().unwrap();
    let c = board.placement.isometry()
        * nalgebra::Point3::new(
            board.cols as f64 * board.square_mm / 2.0,
            board.rows as f64 * board.square_mm / 2.0,
            0.0,
        );
    let text = std::fs::read_to_string(root().join("plans/seed004-shell.toml")).unwrap();
    let mut replaced = 0;
    let spec: String = text
        .lines()
        .map(|l| {
            let k = l.split('=').next().unwrap_or("").trim();
            let new = match k {
                "center_mm" => format!("center_mm = [{:.1}, {:.1}, {:.1}]", c.x, c.y, c.z),
                "radius_mm" => "radius_mm = [520.0, 600.0]".into(),
                "polar_deg" => "polar_deg = [0.0, 20.0]".into(),
                "strata" => "strata = [2, 2, 3]".into(),
                _ => return l.to_string(),
            };
            replaced += 1;
            new
        })
        .collect::<Vec<_>>()
        .join("\n");
    assert_eq!(replaced, 4, "seed-004 spec layout changed");
    let spec_path = dir.join("camera-shell.toml");
    std::fs::write(&spec_path, spec).unwrap();
    let plan = dir.join("plan.json");
    assert_eq!(
        cli(&[
            "plan",
            "--spec",
            s(&spec_path),
            "--robot",
            "ur5e",
            "--out",
            s(&plan),
        ]),
        0
    );
    plan
}

/// Dark and bright pixel fractions of an image.
fn spread(data: &[u8]) -> (f64, f64) {
    let n = data.len() as f64;
    let dark = data.iter().filter(|g| **g < 60).count() as f64 / n;
    let bright = data.iter().filter(|g| **g > 190).count() as f64 / n;
    (dark, bright)
}

fn decode(run: &Path, p: &PoseRecord) -> robocal_drivers::Image {
    let rel = p
        .image
        .as_deref()
        .unwrap_or_else(|| panic!("pose {} has no image", p.id));
    assert!(
        rel.starts_with("dataset.images/") && !Path::new(rel).is_absolute(),
        "{rel}"
    );
    let path = run.join(rel);
    assert!(path.is_file(), "{} missing", path.display());
    read_image_file(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn camera_run_records_an_image_per_pose_and_resumes_over_an_orphan() {
    let tmp = tempfile::tempdir().unwrap();
    let plan = camera_plan(tmp.path());
    let plan_ids: Vec<u64> = PlanFile::read(&plan)
        .unwrap()
        .poses
        .iter()
        .map(|p| p.id)
        .collect();
    let run = tmp.path().join("run");
    let scenario = root().join(SCENARIO);
    // No --camera: a shell plan on a cell with a camera records images by default, and
    // the board to detect defaults to the scenario's (9×6 squares: 8x5 inner corners).
    let first = [
        "run",
        "--plan",
        s(&plan),
        "--sim",
        s(&scenario),
        "--in-process",
        "--virtual-clock",
        "--max-poses",
        "4",
        "--out",
        s(&run),
    ];
    assert_eq!(cli(&first), 0);
    let cfg: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("run.json")).unwrap()).unwrap();
    assert_eq!(cfg["camera"], true, "{cfg}");
    assert_eq!(cfg["capture"]["board"], serde_json::json!([8, 5]), "{cfg}");
    // A kill -9 after the next pose's image was written but before its record: an orphan
    // image (and a stale temp file). The resumed run must overwrite it.
    let next = plan_ids[4];
    let orphan = run.join(format!("dataset.images/pose-{next}.pgm"));
    std::fs::write(&orphan, b"P5\n2 2\n255\nabcd").unwrap();
    std::fs::write(
        run.join(format!("dataset.images/.pose-{next}.pgm.tmp")),
        b"junk",
    )
    .unwrap();
    assert_eq!(
        cli(&["run", "--resume", s(&run), "--max-poses", "4"]),
        0,
        "resume"
    );
    let ds = Dataset::load(run.join("dataset.jsonl")).unwrap();
    let poses: Vec<&PoseRecord> = ds.poses().collect();
    assert_eq!(poses.len(), 8);
    let mut seen = HashSet::new();
    let mut with_board = 0;
    for p in &poses {
        let img = decode(&run, p);
        assert_eq!((img.width, img.height), (640, 480), "pose {}", p.id);
        assert!(
            seen.insert(img.data.clone()),
            "pose {}: same image as before",
            p.id
        );
        let (dark, bright) = spread(&img.data);
        if dark > 0.05 && bright > 0.05 {
            with_board += 1;
        }
    }
    assert!(
        with_board * 10 >= poses.len() * 8,
        "the board is visible in only {with_board} of {} images",
        poses.len()
    );
    let resumed = poses.iter().find(|p| p.id == next).unwrap();
    assert_eq!(decode(&run, resumed).width, 640, "orphan overwritten");
    #[cfg(feature = "opencv")]
    {
        let found = poses
            .iter()
            .filter(|p| p.corners.as_ref().is_some_and(|c| c.len() == 40))
            .count();
        assert!(
            found * 10 >= poses.len() * 8,
            "corners found in only {found} of {}",
            poses.len()
        );
        for c in poses.iter().filter_map(|p| p.corners.as_ref()).flatten() {
            assert!(
                (0.0..640.0).contains(&c[0]) && (0.0..480.0).contains(&c[1]),
                "{c:?}"
            );
        }
    }
    #[cfg(not(feature = "opencv"))]
    assert!(poses.iter().all(|p| p.corners.is_none()));
    // --no-camera: the same plan records no images.
    let bare = tmp.path().join("bare");
    assert_eq!(
        cli(&[
            "run",
            "--plan",
            s(&plan),
            "--sim",
            s(&scenario),
            "--in-process",
            "--virtual-clock",
            "--max-poses",
            "1",
            "--no-camera",
            "--out",
            s(&bare),
        ]),
        0
    );
    let ds = Dataset::load(bare.join("dataset.jsonl")).unwrap();
    assert!(ds.poses().all(|p| p.image.is_none()));
    assert!(!bare.join("dataset.images").exists());
}

#[test]
fn malformed_board_and_camera_without_camera_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let plan = tmp.path().join("missing-plan.json");
    for bad in ["8", "8x", "x5", "1x5", "8x5x2", "-8x5", "eightxfive"] {
        let e = robocal::cell::parse_board(bad).unwrap_err();
        assert!(e.contains("inner corners"), "{bad}: {e}");
    }
    assert_eq!(robocal::cell::parse_board(" 8X5 "), Ok((8, 5)));
    assert_eq!(robocal::cell::parse_board("7×4"), Ok((7, 4)));
    // Through the CLI: a bad --board is a usage error (exit code 2), before anything runs.
    let out = tmp.path().join("run");
    let code = cli(&[
        "run",
        "--plan",
        s(&plan),
        "--sim",
        s(&root().join(SCENARIO)),
        "--board",
        "8by5",
        "--out",
        s(&out),
    ]);
    assert_ne!(code, 0);
    assert!(!out.exists());
    // --camera on a cell without a camera.
    let lab = root().join("mocks/scenarios/lab-vs060-optotrak-il600.toml");
    let plan = camera_plan(tmp.path());
    let code = cli(&[
        "run",
        "--plan",
        s(&plan),
        "--sim",
        s(&lab),
        "--camera",
        "--out",
        s(&out),
    ]);
    assert_ne!(code, 0);
    assert!(!out.join("run.json").exists());
}

// ----------------------------------------------------------------- faults (library level)

fn world() -> WorldHandle {
    let mut sc = Scenario::load(&root().join(SCENARIO)).unwrap();
    sc.clock = ClockMode::Virtual;
    WorldHandle::from_scenario(&sc).unwrap()
}

fn run_poses(
    world: &WorldHandle,
    plan: &[PlannedPose],
    path: &Path,
    header: &Header,
    max_poses: usize,
) -> RunSummary {
    let (mut devices, _) = robocal::cell::sim_cell(&robocal::cell::SimCell::of(world)).unwrap();
    assert!(devices.camera.is_some());
    let limits = SafetyLimits {
        joint_lower: vec![-360f64.to_radians(); 6],
        joint_upper: vec![360f64.to_radians(); 6],
        max_vel: 60f64.to_radians(),
        max_acc: 120f64.to_radians(),
        envelope: None,
        table: None,
        path_step: 1f64.to_radians(),
    };
    devices.arm = guard(devices.arm.clone(), limits, None);
    let (mut journal, existing, _) = Journal::open_or_create(path, header).unwrap();
    let opts = AcquireOptions {
        max_poses: Some(max_poses),
        ..AcquireOptions::default()
    };
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(acquire(
        &devices,
        plan,
        &mut journal,
        &existing,
        &opts,
        &mut |_| {},
    ))
    .unwrap()
}

fn events<'a>(ds: &'a Dataset, what: &str, id: u64) -> Vec<&'a str> {
    ds.records
        .iter()
        .filter_map(|r| match r {
            robocal::dataset::Record::Event(e) if e.what == what && e.id == Some(id) => {
                e.reason.as_deref()
            }
            _ => None,
        })
        .collect()
}

#[test]
fn camera_faults_never_lose_the_pose() {
    let tmp = tempfile::tempdir().unwrap();
    let plan_file = PlanFile::read(&camera_plan(tmp.path())).unwrap();
    let plan: Vec<PlannedPose> = plan_file
        .poses
        .iter()
        .take(3)
        .map(PlannedPose::from)
        .collect();
    let header: Header = serde_json::from_value(serde_json::json!({
        "format": "robocal-dataset/1", "robot": plan_file.robot}))
    .unwrap();
    let path = tmp.path().join("dataset.jsonl");
    let w = world();
    let ctl = w.control();
    // Pose 1: the camera link drops once: retried, the pose has its image.
    ctl.inject("cam", Fault::DropLink);
    let s = run_poses(&w, &plan, &path, &header, 1);
    assert!(s.aborted.is_none(), "{s:?}");
    assert_eq!(ctl.pending_faults("cam"), 0);
    // Pose 2: the camera answers with an error: the pose is recorded without an image.
    ctl.inject("cam", Fault::ErrorReply { code: 7 });
    let s = run_poses(&w, &plan, &path, &header, 1);
    assert!(s.aborted.is_none(), "{s:?}");
    // Pose 3: the link stays down through every attempt: the run stops (resumable) without
    // recording the pose; the resumed run records it with its image.
    for _ in 0..AcquireOptions::default().faults.link_attempts {
        ctl.inject("cam", Fault::DropLink);
    }
    let s = run_poses(&w, &plan, &path, &header, 1);
    let why = s.aborted.clone().expect("aborted");
    assert!(why.contains("camera grab"), "{why}");
    assert_eq!(s.recorded, 2);
    let s = run_poses(&w, &plan, &path, &header, 1);
    assert!(s.aborted.is_none(), "{s:?}");
    assert_eq!(s.recorded, 3);

    let ds = Dataset::load(&path).unwrap();
    let poses: Vec<&PoseRecord> = ds.poses().collect();
    assert_eq!(
        poses.iter().map(|p| p.id).collect::<Vec<_>>(),
        plan.iter().map(|p| p.id).collect::<Vec<_>>()
    );
    let dir = tmp.path();
    let (a, b, c) = (plan[0].id, plan[1].id, plan[2].id);
    assert_eq!(decode(dir, poses[0]).width, 640);
    assert!(events(&ds, "fault", a)
        .iter()
        .any(|r| r.contains("link lost during camera grab")));
    assert!(events(&ds, "resume", a)
        .iter()
        .any(|r| r.contains("link restored")));
    assert!(poses[1].image.is_none() && poses[1].corners.is_none());
    assert!(!dir.join(format!("dataset.images/pose-{b}.pgm")).exists());
    let f = events(&ds, "fault", b);
    assert!(
        f.iter()
            .any(|r| r.contains("camera grab failed") && r.contains("without an image")),
        "{f:?}"
    );
    assert_eq!(decode(dir, poses[2]).width, 640);
    assert!(events(&ds, "fault", c)
        .iter()
        .any(|r| r.contains("run aborted")));
}
