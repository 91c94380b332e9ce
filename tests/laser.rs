//! Laser hand-eye calibration (seed 000) on the independent `laser-planes` case.

use robocal::dataset::Dataset;
use robocal::solve::laser;
use std::path::Path;
use std::process::Command;

fn data(p: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/laser-planes")
        .join(p)
}

fn run_compare() -> laser::Comparison {
    let train = Dataset::load(data("train.jsonl")).unwrap();
    let held = Dataset::load(data("heldout.jsonl")).unwrap();
    let obs = laser::observations(&train).unwrap();
    let val = laser::observations(&held).unwrap();
    let truth = robocal::schema::points_csv::read(&data("truth.csv")).unwrap();
    laser::compare(&obs, &val, Some(&truth), None).unwrap()
}

#[test]
fn direct_fit_meets_the_accuracy_targets_on_the_public_case() {
    let c = run_compare();
    let direct = c.rows.iter().find(|r| r.method == "direct ML").unwrap();
    // Targets of the issue: ≤ 0.08 mm spot RMS vs truth, ≤ 0.06 mm 5-direction spread
    // (independent point-to-plane fit: 0.059 / 0.038 mm).
    let rms = direct.spot_rms_vs_truth_mm.unwrap();
    assert!(rms <= 0.08, "spot RMS {rms}");
    assert!(
        direct.spread_mean_mm <= 0.06,
        "spread {}",
        direct.spread_mean_mm
    );
    // The true beam of case.json: r = (37.207, -14.560, 86.296) mm, v ≈ (0.00813, -0.00435, 0.99996).
    let b = c.final_beam.unwrap();
    assert!((b.r - nalgebra::Vector3::new(37.2067, -14.5596, 86.2963)).norm() < 0.2);
    let v_true = nalgebra::Vector3::new(
        0.008130369671647266,
        -0.00434949219528898,
        0.9999574885997131,
    );
    assert!(b.v.into_inner().dot(&v_true).acos() < 2e-4);
    // Three planes recovered with mutually orthogonal normals.
    assert_eq!(c.final_planes.len(), 3);
    for i in 0..3 {
        for j in (i + 1)..3 {
            let d = c.final_planes[i].1.n.dot(&c.final_planes[j].1.n);
            assert!(d.abs() < 2e-3, "planes {i},{j} not orthogonal: {d}");
        }
    }
}

#[test]
fn the_four_methods_are_compared_and_multi_plane_beats_single_plane() {
    let c = run_compare();
    let names: Vec<&str> = c.rows.iter().map(|r| r.method.as_str()).collect();
    for m in [
        "closed-form P1",
        "selected P1",
        "orthogonal-planes LM",
        "direct ML",
    ] {
        assert!(names.contains(&m), "{names:?}");
    }
    let best_single = c
        .rows
        .iter()
        .filter(|r| r.method.starts_with("closed-form"))
        .map(|r| r.spread_mean_mm)
        .fold(f64::INFINITY, f64::min);
    let ortho = c
        .rows
        .iter()
        .find(|r| r.method == "orthogonal-planes LM")
        .unwrap();
    assert!(
        ortho.spread_mean_mm < best_single,
        "{} vs {best_single}",
        ortho.spread_mean_mm
    );
    // Data selection never does worse than its own iteration 0 (the closed form on all data).
    for p in ["P1", "P2", "P3"] {
        let cf = c
            .rows
            .iter()
            .find(|r| r.method == format!("closed-form {p}"))
            .unwrap();
        let sel = c
            .rows
            .iter()
            .find(|r| r.method == format!("selected {p}"))
            .unwrap();
        assert!(sel.spread_mean_mm <= cf.spread_mean_mm + 1e-12);
    }
}

#[test]
fn cli_calibrates_and_predict_reproduces_the_truth() {
    let dir = tempfile::tempdir().unwrap();
    let bin = env!("CARGO_BIN_EXE_robocal");
    let out = Command::new(bin)
        .args(["calibrate", "laser", "--data"])
        .arg(data("train.jsonl"))
        .arg("--heldout")
        .arg(data("heldout.jsonl"))
        .arg("--out")
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let cal = dir.path().join("calibration.json");
    let pred = dir.path().join("pred.csv");
    let out = Command::new(bin)
        .args(["predict", "--calibration"])
        .arg(&cal)
        .arg("--data")
        .arg(data("heldout.jsonl"))
        .arg("--out")
        .arg(&pred)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let p = robocal::schema::points_csv::read(&pred).unwrap();
    let t = robocal::schema::points_csv::read(&data("truth.csv")).unwrap();
    assert_eq!(p.len(), t.len());
    let rms = (t
        .iter()
        .map(|(id, x)| (p[id] - x).norm_squared())
        .sum::<f64>()
        / t.len() as f64)
        .sqrt();
    assert!(rms <= 0.08, "predict RMS vs truth {rms}");
}

#[test]
fn a_truth_file_with_a_bad_field_names_file_line_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("t.csv");
    std::fs::write(&f, "id,x_mm,y_mm,z_mm\n1,2,3,4\n2,x,3,4\n").unwrap();
    let e = robocal::schema::points_csv::read(&f).unwrap_err();
    let msg = format!("{e:#}");
    assert!(msg.contains("t.csv:3") && msg.contains("x_mm"), "{msg}");
}
