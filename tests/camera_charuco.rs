//! ChArUco end to end: the world renders a ChArUco board (real DICT_4X4_50 codes) at its true
//! pose; the pure-Rust detector + sub-pixel refinement finds its corners with their board ids
//! — on whole views, on views with half the board outside the image and with part of the
//! board occluded — against the world's true corners; the header's `target` block is checked
//! strictly; `robocal run` + `calibrate camera` calibrate a charuco dataset whose views are
//! mostly partial.
use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand::SeedableRng;

use crate::common::heldout_argv;
use robocal::dataset::{CalibrationFile, TargetHeader};
use robocal::solve::camera::charuco::{detect_charuco, CharucoSpec};
use robocal::solve::camera::data::{target_of, Target};
use robocal_mocks::scenario::{CameraConfig, ChessboardConfig};
use robocal_mocks::world::{camera_board, sensors};
use robocal_mocks::Scenario;

const SCENARIO: &str = "mocks/scenarios/ur5e-camera-charuco.toml";

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn cli(args: &[&str]) -> i32 {
    let mut v = vec!["robocal".to_string()];
    v.extend(args.iter().map(|s| s.to_string()));
    robocal::main_with_args(v)
}

fn cell() -> (CameraConfig, ChessboardConfig, CharucoSpec) {
    let sc = Scenario::load(&root().join(SCENARIO)).unwrap();
    let b = sc.scene.chessboard.clone().unwrap();
    let m = b.charuco.clone().expect("a charuco board");
    let spec = CharucoSpec {
        cols: (b.cols - 1) as usize,
        rows: (b.rows - 1) as usize,
        square_mm: b.square_mm,
        marker_mm: m.marker_mm,
        dictionary: m.dictionary,
    };
    (sc.cameras[0].clone(), b, spec)
}

/// A camera `dist` mm above the board point `(x, y)` (board frame), looking down at it with
/// a tilt (rad, about the camera x and y axes) and a roll about its axis.
fn camera_at(
    b: &ChessboardConfig,
    x: f64,
    y: f64,
    dist: f64,
    tilt: [f64; 2],
    roll: f64,
) -> Isometry3<f64> {
    let target = b.placement.isometry() * Point3::new(x, y, 0.0);
    let down = UnitQuaternion::from_scaled_axis(Vector3::new(std::f64::consts::PI, 0.0, 0.0));
    let rot = down
        * UnitQuaternion::from_scaled_axis(Vector3::new(tilt[0], tilt[1], 0.0))
        * UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, roll));
    let eye = target.coords - rot * Vector3::z() * dist;
    Isometry3::from_parts(Translation3::from(eye), rot)
}

/// Detected minus true corners: (corners found, inside-image true corners, mean px, max px,
/// wrong ids = corners more than 2 px from their id's true position).
fn score(
    det: &[Option<[f64; 2]>],
    truth: &[Option<[f64; 2]>],
    w: u32,
    h: u32,
) -> (usize, usize, f64, f64, usize) {
    let inside = truth
        .iter()
        .flatten()
        .filter(|t| t[0] >= 0.0 && t[1] >= 0.0 && t[0] <= w as f64 - 1.0 && t[1] <= h as f64 - 1.0)
        .count();
    let (mut n, mut sum, mut max, mut wrong) = (0, 0.0, 0.0f64, 0);
    for (d, t) in det.iter().zip(truth) {
        if let (Some(d), Some(t)) = (d, t) {
            let e = ((d[0] - t[0]).powi(2) + (d[1] - t[1]).powi(2)).sqrt();
            if e > 2.0 {
                wrong += 1;
                continue;
            }
            n += 1;
            sum += e;
            max = max.max(e);
        }
    }
    (n + wrong, inside, sum / n.max(1) as f64, max, wrong)
}

#[test]
fn charuco_corners_with_ids_on_whole_partial_and_occluded_views() {
    let (cam, b, spec) = cell();
    let (w, h) = (cam.width, cam.height);
    let (bw, bh) = (b.cols as f64 * b.square_mm, b.rows as f64 * b.square_mm);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
    // (name, camera pose, occluder rectangle in pixels)
    type Case = (&'static str, Isometry3<f64>, Option<[usize; 4]>);
    let views: Vec<Case> = vec![
        (
            "whole",
            camera_at(&b, bw / 2.0, bh / 2.0, 560.0, [0.15, -0.1], 0.3),
            None,
        ),
        (
            "whole, tilted 25 deg",
            camera_at(&b, bw / 2.0, bh / 2.0, 600.0, [0.3, 0.3], -2.0),
            None,
        ),
        // The image centre on the board's right-hand edge: half the board outside the image.
        (
            "half outside",
            camera_at(&b, bw, bh / 2.0, 400.0, [0.1, 0.05], 0.2),
            None,
        ),
        // Close up on a corner of the board: a quarter of the board in view.
        (
            "corner close-up",
            camera_at(&b, 45.0, 40.0, 300.0, [-0.1, 0.15], 1.0),
            None,
        ),
        (
            "occluded",
            camera_at(&b, bw / 2.0, bh / 2.0, 560.0, [0.0, 0.1], 0.0),
            Some([250, 0, 400, 480]),
        ),
    ];
    for (name, pose, occ) in views {
        let mut img = sensors::render(&cam, &pose, Some(&b), &mut rng);
        let mut truth = camera_board::true_corners(&cam, &pose, &b);
        if let Some([u0, v0, u1, v1]) = occ {
            // An occluder (a grey card) over columns u0..u1: its corners are gone from the truth.
            for v in v0..v1 {
                for u in u0..u1 {
                    img[v * w as usize + u] = 140;
                }
            }
            for t in truth.iter_mut() {
                if t.is_some_and(|p| p[0] > u0 as f64 - 3.0 && p[0] < u1 as f64 + 2.0) {
                    *t = None;
                }
            }
        }
        let det = detect_charuco(&img, w, h, &spec).unwrap_or_else(|e| panic!("{name}: {e}"));
        let (found, inside, mean, max, wrong) = score(&det, &truth, w, h);
        eprintln!(
            "{name:<22} {found:>2} of {inside:>2} corners in the image found, error mean {mean:.4} px max {max:.4} px, wrong ids {wrong}"
        );
        assert_eq!(
            wrong, 0,
            "{name}: corners labelled with another corner's id"
        );
        assert!(mean < 0.05 && max < 0.2, "{name}: mean {mean} max {max} px");
        assert!(
            found as f64 >= 0.8 * inside as f64,
            "{name}: {found} of {inside}"
        );
        assert!(found >= 8, "{name}: {found}");
        if name != "whole" && name != "whole, tilted 25 deg" {
            assert!(
                inside < spec.cols * spec.rows,
                "{name} must be a partial view"
            );
        }
    }
}

fn header(kind: &str, extra: &str) -> Result<Target, String> {
    let t: TargetHeader = serde_json::from_str(&format!(
        r#"{{"kind": "{kind}", "cols": 8, "rows": 5, "square_mm": 30.0{extra}}}"#
    ))
    .map_err(|e| e.to_string())?;
    target_of(&t)
}

#[test]
fn charuco_header_is_parsed_strictly() {
    let ok = header(
        "charuco",
        r#", "marker_mm": 22.0, "dictionary": "DICT_5X5_100""#,
    )
    .unwrap();
    assert!(
        matches!(ok, Target::Charuco(ref c) if c.marker_mm == 22.0 && c.dictionary == "DICT_5X5_100")
    );
    for (kind, extra, want) in [
        (
            "charuco",
            r#", "marker_mm": 22.0, "dictionary": "DICT_4X4_5""#,
            "field \"target.dictionary\": unknown ArUco dictionary \"DICT_4X4_5\"",
        ),
        (
            "charuco",
            r#", "marker_mm": 30.0, "dictionary": "DICT_4X4_50""#,
            "marker_mm = 30 must be positive and smaller than square_mm = 30",
        ),
        (
            "charuco",
            r#", "marker_mm": -1.0, "dictionary": "DICT_4X4_50""#,
            "marker_mm = -1 must be positive",
        ),
        (
            "charuco",
            r#", "dictionary": "DICT_4X4_50""#,
            "field \"target.marker_mm\": missing",
        ),
        (
            "charuco",
            r#", "marker_mm": 22.0"#,
            "field \"target.dictionary\": missing",
        ),
        (
            "chessboard",
            r#", "marker_mm": 22.0"#,
            "field \"target.marker_mm\": only a \"charuco\" target has markers",
        ),
        (
            "aruco",
            "",
            "field \"target.kind\": \"aruco\" (expected \"chessboard\" or \"charuco\")",
        ),
        (
            "charuco",
            r#", "marker_mm": 22.0, "dictionary": "DICT_4X4_50", "legacy": true"#,
            "unknown field `legacy`",
        ),
    ] {
        let e = header(kind, extra).unwrap_err();
        assert!(e.contains(want), "{kind} {extra}: {e}");
    }
    // Too many squares for the dictionary: 12 × 11 squares need 66 markers.
    let t: TargetHeader = serde_json::from_str(
        r#"{"kind": "charuco", "cols": 11, "rows": 10, "square_mm": 20.0, "marker_mm": 15.0, "dictionary": "DICT_4X4_50"}"#,
    )
    .unwrap();
    let e = target_of(&t).unwrap_err();
    assert!(e.contains("66 markers") && e.contains("only 50"), "{e}");
}

/// The ChArUco cell with a perfect arm (the hand-eye then has an exact truth).
fn scenario(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(root().join(SCENARIO)).unwrap();
    let text = text.replace(
        "[[camera]]",
        "[arm.errors]\norigin_mm = [0.0, 0.0]\norigin_deg = [0.0, 0.0]\noffset_deg = [0.0, 0.0]\n\n[[camera]]",
    );
    let p = dir.join("scenario.toml");
    std::fs::write(&p, text).unwrap();
    p
}

fn plan(dir: &Path, name: &str, strata: &str, seed: u64, jitter: bool) -> PathBuf {
    crate::camera_calib::plan_from(
        "plans/seed004-ur5e-camera-charuco.toml",
        dir,
        name,
        strata,
        seed,
        jitter,
    )
}

use crate::camera_calib::run;

/// `robocal run` on the ChArUco cell with close viewpoints (most views see only part of the
/// board), then `robocal calibrate camera`: the partial views are used and the hand-eye and
/// intrinsics come back close to the truth.
#[test]
fn calibrate_camera_on_a_charuco_dataset_of_mostly_partial_views() {
    let tmp = tempfile::tempdir().unwrap();
    let sc = scenario(tmp.path());
    let train = run(
        tmp.path(),
        &plan(tmp.path(), "train", "[2, 2, 5]", 4, false),
        &sc,
        "train",
    );
    let held = run(
        tmp.path(),
        &plan(tmp.path(), "held", "[1, 1, 6]", 5, true),
        &sc,
        "held",
    );
    let first = std::fs::read_to_string(&train).unwrap();
    let first = first.lines().next().unwrap();
    assert!(
        first.contains(r#""kind":"charuco""#) && first.contains(r#""dictionary":"DICT_4X4_50""#),
        "{first}"
    );
    let out = tmp.path().join("cal");
    assert_eq!(
        cli(&heldout_argv(
            &["calibrate", "camera"],
            &train,
            &held,
            &out,
            &["--quiet"]
        )),
        0
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("camera_report.json")).unwrap())
            .unwrap();
    let (views, partial) = (
        report["views"].as_u64().unwrap(),
        report["partial_views"].as_u64().unwrap(),
    );
    let cal = CalibrationFile::load(out.join("calibration.json")).unwrap();
    let b = cal.camera().unwrap().expect("camera block");
    assert_eq!(b.target.kind, "charuco");
    let truth = Scenario::load(&sc).unwrap().cameras[0].placement.isometry();
    let t = truth.translation.vector;
    let d = ((b.hand_eye.xyz_mm[0] - t.x).powi(2)
        + (b.hand_eye.xyz_mm[1] - t.y).powi(2)
        + (b.hand_eye.xyz_mm[2] - t.z).powi(2))
    .sqrt();
    let q = b.hand_eye.quat;
    let rot = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]));
    let ang = rot.angle_to(&truth.rotation).to_degrees();
    let heldout = cal.metrics["heldout_rms_px"].as_f64().unwrap();
    eprintln!(
        "charuco, {views} views ({partial} partial), rejected {}: hand-eye error {d:.4} mm {ang:.5} deg, fx {:.3} fy {:.3} cx {:.3} cy {:.3} (true 900 900 320 240), held-out {heldout:.4} px",
        report["rejected_views"],
        b.intrinsics.fx, b.intrinsics.fy, b.intrinsics.cx, b.intrinsics.cy
    );
    assert!(views >= 18, "{views} views with a board");
    assert!(partial * 2 >= views, "{partial} of {views} partial");
    // Measured: 0.0019 mm, 0.0020 deg, fx 900.009, held-out 0.0154 px (20 of 20 views partial).
    assert!(d <= 0.02 && ang <= 0.01, "hand-eye {d} mm {ang} deg");
    assert!(
        (b.intrinsics.fx - 900.0).abs() < 0.1,
        "fx {}",
        b.intrinsics.fx
    );
    assert!(heldout <= 0.03, "held-out {heldout} px");
    // The same dataset with a dictionary that does not exist: refused naming file and field.
    let text = std::fs::read_to_string(&train).unwrap();
    let bad = tmp.path().join("train/bad.jsonl");
    std::fs::write(&bad, text.replacen("DICT_4X4_50", "DICT_4X4_42", 1)).unwrap();
    let e = robocal::solve::camera::data::load(&bad, &Default::default(), false)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("bad.jsonl")
            && e.contains("field \"target.dictionary\": unknown ArUco dictionary \"DICT_4X4_42\""),
        "{e}"
    );
}
