//! `robocal session --kind laser` on the seed 000 laser cell (in-process simulated devices,
//! virtual clock): three orthogonal planes → selection targets → beam calibration → held-out
//! targets aimed with the calibrated beam → laser diagnosis → held-out spread → verdict →
//! report. The scenario's true beam is read only here, to score.
use std::path::PathBuf;
use std::sync::OnceLock;

use nalgebra::Vector3;
use robocal::dataset::CalibrationFile;
use robocal::session::{SessionFile, SessionKind, Stage, VerdictKind};
use robocal::solve::laser;

use crate::common::{cli, root, s};

const SCENARIO: &str = "mocks/scenarios/lab-vs060-il600-planes.toml";

/// Runs a laser session on `scenario` into a fresh temp directory named `tag`.
fn run_session(scenario: &std::path::Path, tag: &str) -> (PathBuf, i32) {
    let dir = std::env::temp_dir().join(format!(
        "robocal-session-laser-{tag}-{}",
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&dir);
    let t0 = std::time::Instant::now();
    let code = cli(&[
        "session",
        "--sim",
        s(scenario),
        "--kind",
        "laser",
        "--out",
        s(&dir),
        "--in-process",
        "--no-history",
    ]);
    println!(
        "laser session ({tag}): exit {code} in {:.1} s",
        t0.elapsed().as_secs_f64()
    );
    assert!(code == 0 || code == 2, "exit {code}");
    (dir, code)
}

/// The laser cell as shipped (arm with kinematic errors and joint compliance, no arm
/// calibration given): shared by the tests of this module.
fn laser_session() -> &'static (PathBuf, i32) {
    static S: OnceLock<(PathBuf, i32)> = OnceLock::new();
    S.get_or_init(|| run_session(&root().join(SCENARIO), "nominal-arm"))
}

/// The same cell with an exact arm (no kinematic error, no compliance): the flange poses are
/// right, so what is left is the beam.
fn exact_arm_session() -> &'static (PathBuf, i32) {
    static S: OnceLock<(PathBuf, i32)> = OnceLock::new();
    S.get_or_init(|| {
        let mut sc = robocal_mocks::Scenario::load(&root().join(SCENARIO)).unwrap();
        sc.arms[0].errors = robocal_mocks::scenario::GeometricErrors::none();
        sc.arms[0].effects = Default::default();
        let p =
            std::env::temp_dir().join(format!("robocal-laser-exact-{}.toml", std::process::id()));
        std::fs::write(&p, toml::to_string(&sc).unwrap()).unwrap();
        run_session(&p, "exact-arm")
    })
}

/// Distance of point `p` from the beam line.
fn off_line(b: &laser::Beam, p: &Vector3<f64>) -> f64 {
    let d = p - b.r;
    (d - b.v.into_inner() * d.dot(&b.v)).norm()
}

#[test]
fn laser_session_runs_end_to_end_with_separate_targets() {
    let (dir, code) = laser_session();
    let f = SessionFile::load(&dir.join("session.json")).unwrap();
    assert_eq!(f.setup.kind, SessionKind::Laser);
    for st in Stage::ALL {
        assert!(f.stages_done.contains(&st), "stage {st:?} not done");
    }
    assert_ne!(f.verdict, VerdictKind::Incomplete, "{}", f.verdict_line);
    assert_eq!(*code, if f.verdict == VerdictKind::Pass { 0 } else { 2 });
    // Three datasets: the planes, the selection targets, the held-out targets.
    let roles: Vec<&str> = f.datasets.iter().map(|d| d.role.as_str()).collect();
    assert_eq!(roles, ["train", "selection", "validation"]);
    let l = f.laser.as_ref().expect("laser summary");
    assert!(
        l.selection_targets >= 8 && l.validation_targets >= 8,
        "{l:?}"
    );
    // Held-out targets are not the selection's: different labels, different poses.
    let labels = |set: &str| -> Vec<String> {
        let ds =
            robocal::dataset::Dataset::load(dir.join(format!("run-{set}/dataset.jsonl"))).unwrap();
        ds.poses().filter_map(|p| p.target.clone()).collect()
    };
    let (sel, val) = (labels("selection"), labels("validation"));
    assert!(sel.iter().all(|t| t.starts_with("V-sel-")), "{sel:?}");
    assert!(val.iter().all(|t| t.starts_with("V-val-")), "{val:?}");
    assert!(val.len() >= 20, "{} held-out poses", val.len());
    assert_eq!(f.measured.heldout_poses, val.len());
    // The held-out plan aims with the calibrated beam (its tool = the calibrate stage's beam).
    let cal = CalibrationFile::load(dir.join("calibrate/calibration.json")).unwrap();
    let beam = laser::beam_from_calibration(&cal).unwrap();
    let plan: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("plan/validation.json")).unwrap())
            .unwrap();
    let tp: Vec<f64> = serde_json::from_value(plan["tool"]["p"].clone()).unwrap();
    assert!(
        (Vector3::new(tp[0], tp[1], tp[2]) - beam.r).norm() < 1e-9,
        "{tp:?}"
    );
    // Every method is scored on the held-out targets; the closed forms carry the seed's figure.
    assert!(l
        .methods
        .iter()
        .any(|m| m.method.starts_with("closed-form") && m.seed_mm.is_some()));
    assert!(l.methods.iter().any(|m| m.method == "orthogonal-planes LM"));
    let deployed = l.methods.last().unwrap();
    assert!(deployed.method.starts_with("deployed"));
    assert_eq!(
        f.measured.laser_spread_mm_after,
        Some(deployed.spread_mean_mm)
    );
    // The report shows the laser section.
    let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
    assert!(
        html.contains("laser-methods"),
        "no laser section in the report"
    );
}

/// With exact flange poses the session recovers the beam: closer to the scenario's true beam
/// than the nominal mounting, and the held-out spread falls well below the nominal one.
#[test]
fn laser_session_recovers_the_beam_when_the_flange_is_right() {
    let (dir, _) = exact_arm_session();
    let f = SessionFile::load(&dir.join("session.json")).unwrap();
    let truth = Vector3::new(0.9, 40.7, 38.6);
    let nominal = laser::Beam {
        r: Vector3::new(0.0, 40.0, 40.0),
        v: Vector3::z_axis(),
    };
    let dep = CalibrationFile::load(dir.join("deploy/calibration.json")).unwrap();
    let b = laser::beam_from_calibration(&dep).unwrap();
    println!(
        "true beam origin off the line: nominal {:.3} mm, calibrated {:.3} mm; held-out spread {:?} -> {:?} mm",
        off_line(&nominal, &truth),
        off_line(&b, &truth),
        f.measured.laser_spread_mm_before,
        f.measured.laser_spread_mm_after
    );
    assert!(off_line(&b, &truth) < 0.5 * off_line(&nominal, &truth));
    let (before, after) = (
        f.measured.laser_spread_mm_before.unwrap(),
        f.measured.laser_spread_mm_after.unwrap(),
    );
    assert!(after < 0.5 * before, "spread {before} -> {after} mm");
}

#[test]
fn laser_accept_spec_and_arm_calibration_are_checked() {
    use robocal::session::AcceptSpec;
    let a = AcceptSpec::from_file(&root().join("accept/laser.toml")).unwrap();
    assert_eq!(a.session, Some(SessionKind::Laser));
    a.check_kind(SessionKind::Laser, "laser.toml").unwrap();
    assert!(a.check_kind(SessionKind::Kinematic, "laser.toml").is_err());
    // A laser spec with a kinematic criterion would never check it.
    let e = AcceptSpec::from_toml_str(
        "name = \"x\"\nsession = \"laser\"\nlaser_spread_mm_max = 0.5\nheldout_rms_mm_max = 1.0\n",
        "x.toml",
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("heldout_rms_mm_max") && e.contains("kinematic"),
        "{e}"
    );
    // No laser criterion: refused.
    let e = AcceptSpec::from_toml_str("name = \"x\"\nsession = \"laser\"\n", "x.toml")
        .unwrap_err()
        .to_string();
    assert!(e.contains("laser_spread_mm_max"), "{e}");
    // An arm calibration of another robot is refused before anything is created.
    let dir = std::env::temp_dir().join(format!("robocal-laser-armcal-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let cal = CalibrationFile::new(
        robocal::dataset::RobotBlock::named("ur5e"),
        vec![param("phi2", 180.0, "deg")],
    );
    cal.save(dir.join("ur5e.json")).unwrap();
    let out = dir.join("sess");
    let code = cli(&[
        "session",
        "--sim",
        s(&root().join(SCENARIO)),
        "--kind",
        "laser",
        "--arm-calibration",
        s(&dir.join("ur5e.json")),
        "--out",
        s(&out),
        "--in-process",
        "--no-history",
    ]);
    assert_eq!(code, 1);
    assert!(!out.join("session.json").exists());
}

#[test]
fn spots_go_through_the_identified_arm() {
    // The session's planes dataset, read with the controller's flange and through an
    // "identified" arm whose joint-2 zero differs by 0.05°: the spots move accordingly, and a
    // calibration without arm parameters is refused.
    let (dir, _) = laser_session();
    let p = dir.join("run-train/dataset.jsonl");
    let ds = robocal::dataset::Dataset::load(&p).unwrap();
    let plain = laser::observations(&ds).unwrap();
    let model = robocal::model::KinematicModel::preset("denso-vs060").unwrap();
    let name = "phi2".to_string();
    let mut cal = CalibrationFile::new(ds.header.robot.clone(), vec![param("laser_rx", 1.0, "mm")]);
    let cal_path = dir.join("test-arm.json");
    cal.save(&cal_path).unwrap();
    let e = laser::identified_arm(&cal_path, &ds, &p)
        .unwrap_err()
        .to_string();
    assert!(e.contains("no kinematic parameter"), "{e}");
    let i = model.param_index(&name).unwrap();
    cal.params = vec![param(
        &name,
        model.params()[i].value + 0.05f64.to_radians(),
        "rad",
    )];
    cal.save(&cal_path).unwrap();
    let arm = laser::identified_arm(&cal_path, &ds, &p).unwrap();
    let through = laser::observations_through(&ds, Some(&arm)).unwrap();
    assert_eq!(plain.len(), through.len());
    let moved: f64 = plain
        .iter()
        .zip(&through)
        .map(|(a, b)| (a.flange.translation.vector - b.flange.translation.vector).norm())
        .fold(0.0, f64::max);
    // 0.05° at ~0.5 m reach: ~0.4 mm.
    assert!(moved > 0.1 && moved < 2.0, "flange moved {moved} mm");
}

fn param(name: &str, value: f64, unit: &str) -> robocal::dataset::CalParam {
    robocal::dataset::CalParam {
        name: name.into(),
        value,
        std: None,
        unit: unit.into(),
        free: true,
        extra: Default::default(),
    }
}

#[test]
fn a_laser_scan_ply_is_read_as_surface_points() {
    // `calibrate laser --scan … --ply` writes a vertex-only PLY; `register --ct-mesh --tracker
    // SCAN.ply` reads its vertices as the surface points.
    let pts = vec![
        nalgebra::Point3::new(1.0, 2.0, 3.0),
        nalgebra::Point3::new(-4.5, 0.25, 100.0),
    ];
    let dir = std::env::temp_dir().join(format!("robocal-laser-ply-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("scan.ply");
    std::fs::write(&p, laser::ply(&pts, "test scan")).unwrap();
    let got = robocal::register::points::read_surface_points(&p).unwrap();
    assert_eq!(got.len(), 2);
    assert_eq!(got[1].name, "v2");
    assert!((got[1].p - pts[1]).norm() < 1e-9);
    std::fs::write(&p, laser::ply(&[], "empty")).unwrap();
    let e = robocal::register::points::read_surface_points(&p)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("without vertices") && e.contains("scan.ply"),
        "{e}"
    );
}
