//! Issue 29 §2: the RCM endoscope calibration from rendered images. The world renders the
//! endoscope view (`robocal_mocks::rcm_render`), the detector (`solve::rcm::lines`) finds the
//! shaft's silhouettes in the pixels, `calibrate rcm` reads images.
use std::process::Command;

use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use robocal::cli::rcm_images::{self, TrialOptions};
use robocal::model::KinematicModel;
use robocal::plan::rcm::{generate, RcmPlanSpec};
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
    assert!(dt <= 1.5 * et, "hand-eye {dt} mm with detected lines vs {et} with exact");
    assert!(dr <= 1.5 * er, "hand-eye {dr} deg with detected lines vs {er} with exact");
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
    let (path, views) = write_image_dataset(
        &cell,
        &poses,
        &cell.scenario.render,
        dir.path(),
        "rcm",
        1,
    )
    .unwrap();
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
    let o = Command::new(env!("CARGO_BIN_EXE_robocal"))
        .args(["calibrate", "rcm", "--bootstrap", "0", "--data"])
        .arg(&path)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
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
    std::fs::remove_file(dir.path().join(format!("rcm.images/pose-{}.pgm", views[0].0))).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_robocal"))
        .args(["calibrate", "rcm", "--bootstrap", "0", "--data"])
        .arg(&path)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        stderr.contains("rcm.jsonl:2") && stderr.contains("\"image\""),
        "{stderr}"
    );
}
