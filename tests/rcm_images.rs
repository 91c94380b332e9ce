//! Issue 29 §2: the RCM endoscope calibration from rendered images. The world renders the
//! endoscope view (`robocal_mocks::rcm_render`), the detector (`solve::rcm::lines`) finds the
//! shaft's silhouettes in the pixels, `calibrate rcm` reads images.
use std::process::Command;

use super::rcm_trials as rcm_images;
use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rcm_images::TrialOptions;
use robocal::model::KinematicModel;
use robocal::plan::rcm::{generate, RcmPlanSpec};
use robocal::solve::rcm::lines;
use robocal_mocks::rcm::{RcmCell, RcmScenario};
use robocal_mocks::rcm_render::write_image_dataset;

#[test]
fn detected_lines_match_the_world_and_the_hand_eye_stays_within_1_5x_of_exact_lines() {
    let o = TrialOptions {
        trials: 20,
        poses: 8,
        ..Default::default()
    };
    let r = rcm_images::run(&RcmScenario::builtin(), &o).unwrap();
    println!("{}", rcm_images::text(&o, &r));
    let px: Vec<f64> = r.line_errors.iter().map(|e| e.px).collect();
    let deg: Vec<f64> = r.line_errors.iter().map(|e| e.deg).collect();
    assert!(r.views >= 120, "{} views", r.views);
    assert!(
        r.refused.len() * 10 <= r.views,
        "{} of {} views refused",
        r.refused.len(),
        r.views
    );
    assert!(rcm_images::median(&px) < 0.2, "line px {:?}", px);
    assert!(rcm_images::quantile(&px, 0.95) < 1.0);
    assert!(rcm_images::median(&deg) < 0.05);
    assert!(r.failed.is_empty(), "{:?}", r.failed);
    assert_eq!(r.hand_eye.len(), 20);
    let med = |k: usize, f: fn(&(f64, f64)) -> f64| {
        rcm_images::median(&r.hand_eye.iter().map(|e| f(&e[k])).collect::<Vec<_>>())
    };
    let (dt, et) = (med(0, |e| e.0), med(1, |e| e.0));
    let (dr, er) = (med(0, |e| e.1), med(1, |e| e.1));
    assert!(
        dt <= 1.5 * et,
        "hand-eye {dt} mm with detected lines vs {et} with exact"
    );
    assert!(
        dr <= 1.5 * er,
        "hand-eye {dr} deg with detected lines vs {er} with exact"
    );
}

#[test]
fn calibrate_rcm_reads_images_refuses_blank_views_and_needs_no_robot_preset() {
    let cell = RcmCell::new(RcmScenario::builtin());
    let model = KinematicModel::preset("ur5e").unwrap();
    let spec = RcmPlanSpec {
        trocar_mm: cell.scenario.trocar_mm,
        insertion_dir: cell.scenario.insertion_dir,
        x_hint: [0.0, 1.0, 0.0],
        pivot_deg: 25.0,
        insertion_mm: [50.0, 150.0],
        roll_deg: 10.0,
        count: 12,
        seed: 5,
        shaft_length_mm: 350.0,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let poses: Vec<_> = generate(&spec, Some(&model))
        .unwrap()
        .into_iter()
        .map(|p| (p.instrument, cell.reported(&p.instrument, &mut rng)))
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let (path, views) =
        write_image_dataset(&cell, &poses, &cell.scenario.render, dir.path(), "rcm", 1).unwrap();
    assert!(views.len() >= 10);
    // An instrument holder that is no robocal preset.
    let text = std::fs::read_to_string(&path).unwrap();
    let text = text.replacen("\"model\":\"ur5e\"", "\"model\":\"acme-holder-3\"", 1);
    assert!(text.contains("acme-holder-3"));
    std::fs::write(&path, &text).unwrap();
    // One view blanked: the detector refuses it and names it.
    let (blank_id, _) = views[2];
    std::fs::write(
        dir.path().join(format!("rcm.images/pose-{blank_id}.pgm")),
        robocal_drivers::camera::pgm::encode(1280, 1024, &vec![90u8; 1280 * 1024]),
    )
    .unwrap();
    let out = dir.path().join("out");
    let calibrate = || {
        Command::new(env!("CARGO_BIN_EXE_robocal"))
            .args(["calibrate", "rcm", "--bootstrap", "0", "--data"])
            .arg(&path)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap()
    };
    let o = calibrate();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    println!("{}\n{stderr}", String::from_utf8_lossy(&o.stdout));
    assert!(
        stderr.contains(&format!("pose {blank_id} (")) && stderr.contains("refused"),
        "{stderr}"
    );
    let cal = robocal::dataset::CalibrationFile::load(out.join("calibration.json")).unwrap();
    let cam: robocal::dataset::endoscope::CameraCal =
        serde_json::from_value(cal.extra["camera"].clone()).unwrap();
    let err = (Vector3::from(cam.hand_eye.xyz_mm) - cell.camera.translation.vector).norm();
    assert!(err < 1.0, "hand-eye translation error {err} mm");
    let rep: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("rcm_report.json")).unwrap())
            .unwrap();
    assert_eq!(rep["detected"].as_array().unwrap().len(), views.len() - 1);
    assert_eq!(rep["refused"].as_array().unwrap().len(), 1);
    // A missing image is an error naming the file, the line and the field.
    std::fs::remove_file(
        dir.path()
            .join(format!("rcm.images/pose-{}.pgm", views[0].0)),
    )
    .unwrap();
    let o = calibrate();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        stderr.contains("rcm.jsonl:2") && stderr.contains("\"image\""),
        "{stderr}"
    );
}

#[test]
fn seed002_plan_file_pivots_about_the_trocar_and_is_reachable() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("PLAN.json");
    let spec = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("plans/seed002-rcm.toml");
    let code = robocal::main_with_args([
        "robocal".into(),
        "plan".into(),
        "--spec".into(),
        spec.into_os_string(),
        "--robot".into(),
        "ur5e".into(),
        "--out".into(),
        out.clone().into_os_string(),
    ]);
    assert_eq!(code, 0);
    let f = robocal::plan::file::PlanFile::read(&out).unwrap();
    assert!(f.poses.len() >= 15, "{} poses", f.poses.len());
    let tool = f.tool.to_iso().unwrap();
    let trocar = Vector3::new(450.0, 0.0, 250.0);
    for p in &f.poses {
        // The instrument axis (tool z through the tip) passes through the trocar.
        let inst = p.flange.to_iso().unwrap() * tool;
        let z = inst.rotation * Vector3::z();
        let d = (trocar - inst.translation.vector).cross(&z).norm();
        assert!(d < 0.05, "pose {}: axis {d} mm from the trocar", p.id);
    }
}

// ------------------------------------------------------------ the detector on synthetic bands

fn dist(l: &[f64; 3], u: f64, v: f64) -> f64 {
    l[0] * u + l[1] * v + l[2]
}

fn line_through(p: [f64; 2], q: [f64; 2]) -> [f64; 3] {
    let (a, b) = (q[1] - p[1], p[0] - q[0]);
    let n = (a * a + b * b).sqrt();
    [a / n, b / n, -(a * p[0] + b * p[1]) / n]
}

/// The detector with default options on a `w × h` image, camera without distortion.
fn detect_on(img: &[u8], w: usize, h: usize) -> Result<lines::ShaftLines, String> {
    let cam = robocal::dataset::endoscope::EndoscopeCamera {
        kind: "endoscope".into(),
        width: w as u32,
        height: h as u32,
        fx: 500.0,
        fy: 500.0,
        cx: w as f64 / 2.0,
        cy: h as f64 / 2.0,
        dist: [0.0; 5],
    };
    lines::detect(img, w as u32, h as u32, &cam, &Default::default())
}

#[test]
fn detector_finds_both_edges_of_a_band_to_a_tenth_of_a_pixel() {
    let (w, h) = (240, 200);
    let l1 = line_through([100.3, 0.0], [120.7, 200.0]);
    let l2 = line_through([130.6, 0.0], [147.2, 200.0]);
    // A dark band between the two lines on a bright background, area-sampled (8 × 8).
    let img: Vec<u8> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            let mut acc = 0.0f64;
            for k in 0..64 {
                let u = x + ((k % 8) as f64 + 0.5) / 8.0 - 0.5;
                let v = y + ((k / 8) as f64 + 0.5) / 8.0 - 0.5;
                let inside = dist(&l1, u, v) > 0.0 && dist(&l2, u, v) < 0.0;
                acc += if inside { 30.0 } else { 180.0 };
            }
            (acc / 64.0).round() as u8
        })
        .collect();
    let r = detect_on(&img, w, h).unwrap();
    for fl in &r.lines {
        let truth = if dist(&l1, fl.seg[0], fl.seg[1]).abs() < 2.0 {
            l1
        } else {
            l2
        };
        for e in [[fl.seg[0], fl.seg[1]], [fl.seg[2], fl.seg[3]]] {
            assert!(dist(&truth, e[0], e[1]).abs() < 0.1, "{fl:?}");
        }
        assert!(fl.rms_px < 0.2 && fl.length_px > 150.0, "{fl:?}");
    }
    assert!(
        (dist(&l1, r.lines[0].seg[0], r.lines[0].seg[1]).abs() < 2.0)
            != (dist(&l1, r.lines[1].seg[0], r.lines[1].seg[1]).abs() < 2.0),
        "both edges, not one twice"
    );
    assert!(r.sigma_px() < 0.05);
}

#[test]
fn detector_refuses_views_without_a_shaft_and_names_why() {
    let (w, h) = (120, 100);
    let e = detect_on(&vec![128u8; w * h], w, h).unwrap_err();
    assert!(e.contains("edge points"), "{e}");
    // One edge only (a half plane).
    let l = line_through([60.0, 0.0], [70.0, 100.0]);
    let img: Vec<u8> = (0..w * h)
        .map(|i| {
            if dist(&l, (i % w) as f64, (i / w) as f64) > 0.0 {
                40
            } else {
                200
            }
        })
        .collect();
    let e = detect_on(&img, w, h).unwrap_err();
    assert!(e.contains("no two long straight edges"), "{e}");
    // An image of another size than the header's camera.
    let mut cam = robocal::dataset::endoscope::EndoscopeCamera {
        kind: "endoscope".into(),
        width: 64,
        height: 64,
        fx: 500.0,
        fy: 500.0,
        cx: 32.0,
        cy: 32.0,
        dist: [0.0; 5],
    };
    let e = lines::detect(&img, w as u32, h as u32, &cam, &Default::default()).unwrap_err();
    assert!(e.contains("header"), "{e}");
    cam.width = w as u32;
    let e = lines::detect(&img[..10], w as u32, h as u32, &cam, &Default::default()).unwrap_err();
    assert!(e.contains("samples"), "{e}");
}
