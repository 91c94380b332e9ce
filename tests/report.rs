//! `robocal report` on directories written by the real commands on `tests/data/*`
//! (calibrate laser, calibrate kinematics, diagnose), plus its tolerance of broken files.
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use robocal::report::gather;
use serde_json::Value;

fn data(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(rel)
}

fn robocal(args: &[&str]) -> Output {
    let o = Command::new(env!("CARGO_BIN_EXE_robocal"))
        .args(args)
        .env("ROBOCAL_LOG", "warn")
        .output()
        .expect("run robocal");
    assert!(
        o.status.success(),
        "robocal {args:?} failed:\n{}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    o
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// Numbers of "held-out error X mm → Y mm".
fn headline_numbers(h: &str) -> (f64, f64) {
    let rest = h
        .split("held-out error ")
        .nth(1)
        .unwrap_or_else(|| panic!("no held-out numbers in {h:?}"));
    let mut it = rest.split(" mm");
    let before: f64 = it.next().unwrap().trim().parse().unwrap();
    let after: f64 = it
        .next()
        .unwrap()
        .trim_start_matches(" → ")
        .trim()
        .parse()
        .unwrap();
    (before, after)
}

#[test]
fn report_of_diagnose_and_laser_on_test_data() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let kin = data("kin-compliance-j2");
    robocal(&[
        "diagnose",
        "--data",
        p(&kin.join("train.jsonl")),
        "--heldout",
        p(&kin.join("heldout.jsonl")),
        "--out",
        p(&dir.join("diagnose")),
    ]);
    let laser = data("laser-planes");
    robocal(&[
        "calibrate",
        "laser",
        "--data",
        p(&laser.join("train.jsonl")),
        "--heldout",
        p(&laser.join("heldout.jsonl")),
        "--out",
        p(&dir.join("laser")),
    ]);
    // A copy of the dataset so the dataset section is exercised too.
    std::fs::copy(kin.join("heldout.jsonl"), dir.join("heldout.jsonl")).unwrap();

    let out = robocal(&[
        "report",
        "--dir",
        p(dir),
        "--out",
        p(&dir.join("report.html")),
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let headline = stdout.lines().last().unwrap().to_string();
    // The diagnosis' own held-out numbers, as diagnosis.json holds them.
    let diag: Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join("diagnose/diagnosis.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(diag["format"], "robocal-diagnosis/2");
    let nominal = diag["heldout_rms"]["nominal_mm"].as_f64().unwrap();
    let fin = diag["heldout_rms"]["final_mm"].as_f64().unwrap();
    let (b, a) = headline_numbers(&headline);
    assert!((b - nominal).abs() < 1e-3, "{headline} vs {nominal}");
    assert!((a - fin).abs() < 1e-3, "{headline} vs {fin}");
    assert!(a < b, "{headline}");
    assert!(
        headline.contains("effects found: joint_compliance(j2)"),
        "{headline}"
    );
    assert!(headline.contains("no acquisition summary"), "{headline}");

    let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
    assert!(md.contains(&headline), "headline missing from report.md");
    assert!(md.contains("## Diagnosis (`diagnose/diagnosis.json`)"));
    assert!(md.contains("## Laser hand-eye methods (`laser/laser_report.json`)"));
    assert!(md.contains("| orthogonal-planes LM |"));
    assert!(md.contains("| direct ML |"));
    assert!(md.contains("Sensor: kinematic"));
    assert_eq!(
        md.matches("## Calibration `").count(),
        2,
        "diagnose + laser calibration.json"
    );
    assert!(md.contains("laser_rx"), "laser parameters listed");
    assert!(md.contains("## Dataset (`heldout.jsonl`)"));
    assert!(md.contains("joint_compliance"));
    // HTML: self-contained, every SVG of the diagnosis inlined.
    let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
    let svgs = std::fs::read_dir(dir.join("diagnose"))
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .path()
                .extension()
                .is_some_and(|x| x == "svg")
        })
        .count();
    assert!(svgs >= 1, "diagnose wrote no plot");
    assert_eq!(html.matches("<svg").count(), svgs);
    assert!(!html.contains("<?xml"));

    // Deterministic: a second report is byte-identical; JSON mode carries the same headline.
    let md1 = md.clone();
    robocal(&[
        "report",
        "--dir",
        p(dir),
        "--out",
        p(&dir.join("report.html")),
    ]);
    let md2 = std::fs::read_to_string(dir.join("report.md")).unwrap();
    assert_eq!(md1, md2);
    let js = robocal(&[
        "report",
        "--dir",
        p(dir),
        "--json",
        "--out",
        p(&dir.join("x.md")),
    ]);
    let v: Value = serde_json::from_slice(&js.stdout).unwrap();
    assert_eq!(v["headline"].as_str().unwrap(), headline);
    assert_eq!(v["diagnoses"].as_array().unwrap().len(), 1);
    assert_eq!(v["laser_reports"].as_array().unwrap().len(), 1);
}

#[test]
fn report_tolerates_broken_and_unknown_files() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    std::fs::create_dir_all(dir.join("a/b")).unwrap();
    std::fs::write(dir.join("a/calibration.json"), "{ not json").unwrap();
    std::fs::write(dir.join("a/b/diagnosis.json"), "[1, 2]").unwrap();
    std::fs::write(dir.join("x.jsonl"), "{\"hello\": 1}\n").unwrap();
    std::fs::write(dir.join("plot.svg"), "no svg here").unwrap();
    // A run summary without its format tag (an older robocal): a warning naming the file.
    std::fs::write(dir.join("a/summary.json"), r#"{"planned": 5}"#).unwrap();
    // A run summary with extra, unknown fields (kept readable) and a typed summary.
    std::fs::write(
        dir.join("summary.json"),
        r#"{"format": "robocal-run-summary/1", "planned": 5, "recorded": 3, "recorded_now": 3,
            "already_done": 0, "skipped": [{"id": 1, "reason": "marker not visible"},
            {"id": 4, "reason": "marker not visible"}], "remaining": 0,
            "poses_per_hour": 120.0, "events": {"skip": 2},
            "time": {"move_s": 1.0, "settle_s": 2.0, "sample_s": 3.0, "overhead_s": 4.0},
            "aborted": null, "future_field": {"x": [1]}}"#,
    )
    .unwrap();
    let s = gather(dir).unwrap();
    assert_eq!(s.warnings.len(), 4, "{:?}", s.warnings);
    assert!(
        s.warnings
            .iter()
            .any(|w| w.contains("a/summary.json") && w.contains("robocal-run-summary/1")),
        "{:?}",
        s.warnings
    );
    assert!(s.calibrations.is_empty() && s.diagnoses.is_empty() && s.datasets.is_empty());
    let h = s.headline_text();
    assert_eq!(
        h,
        "held-out error: not available; effects found: not diagnosed; 2 poses skipped"
    );
    let md = s.markdown();
    assert!(md.contains("| marker not visible | 2 | 1 4 |"), "{md}");
    assert!(md.contains("poses/hour 120"));
    assert!(s.html().contains("plot.svg: not an SVG image"));
    // The CLI refuses a missing directory and a bad --out extension (exit 1, no panic).
    let o = Command::new(env!("CARGO_BIN_EXE_robocal"))
        .args(["report", "--dir", p(&dir.join("nope"))])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    let o = Command::new(env!("CARGO_BIN_EXE_robocal"))
        .args(["report", "--dir", p(dir), "--out", "r.pdf"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
}

/// A laser diagnosis (the same `diagnosis.json` shape as the kinematic one) shows its
/// effects in the report: the headline lists exactly the labels the file holds.
#[test]
fn report_shows_laser_diagnosis_effects() {
    use robocal::schema::{self, DiagnosisFile};
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let laser = data("laser-planes");
    robocal(&[
        "diagnose",
        "--data",
        p(&laser.join("train.jsonl")),
        "--heldout",
        p(&laser.join("heldout.jsonl")),
        "--out",
        p(&dir.join("laser-diag")),
    ]);
    let d: DiagnosisFile = schema::read(&dir.join("laser-diag/diagnosis.json")).unwrap();
    assert_eq!(d.sensor, schema::DiagnosisSensor::Laser);
    assert!(d.train_rms.base_model_mm.is_some());
    let s = gather(dir).unwrap();
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    let h = s.headline();
    let mut labels: Vec<String> = d.effects.iter().map(|e| e.label.clone()).collect();
    labels.sort();
    assert_eq!(h.effects, labels);
    // A laser diagnosis that found an effect: the headline names it (not "none").
    let mut with = d.clone();
    with.effects.push(schema::DiagnosedEffect {
        kind: "laser_scale".into(),
        joint: None,
        label: "laser_scale".into(),
        parameters: vec![schema::EffectParameter::new("scale", "ppm", 300.0, 10.0)],
        evidence: schema::Evidence::default(),
        train_rms_mm_before: Some(0.05),
        train_rms_mm_after: Some(0.02),
        heldout_rms_mm_before: None,
        heldout_rms_mm_after: None,
        train_rms_px_before: None,
        train_rms_px_after: None,
        heldout_rms_px_before: None,
        heldout_rms_px_after: None,
        hand_eye_change_mm: None,
        hand_eye_change_deg: None,
        calibration: robocal::dataset::CalEffect {
            kind: "laser_scale".into(),
            joint: None,
            params: Default::default(),
            extra: Default::default(),
        },
    });
    schema::write(&dir.join("laser-diag/diagnosis.json"), &with).unwrap();
    let s = gather(dir).unwrap();
    assert!(
        s.headline_text().contains("effects found: laser_scale"),
        "{}",
        s.headline_text()
    );
    assert!(s
        .markdown()
        .contains("scale = 300.0000 ppm (95 %: 280.4000 … 319.6000)"));
}

#[test]
fn report_collects_the_navigation_chain_and_rcm_files() {
    let dir = std::env::temp_dir().join(format!("robocal-report-nav-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("nav")).unwrap();
    std::fs::write(
        dir.join("nav/registration.json"),
        r#"{"format": "robocal-registration/1", "fre_mm": 0.24, "tre_mm": 0.26, "residuals": [1, 2]}"#,
    )
    .unwrap();
    std::fs::write(
        dir.join("chain.json"),
        r#"{"format": "robocal-chain/1", "tip_rms_mm": 0.5}"#,
    )
    .unwrap();
    std::fs::write(dir.join("rcm_report.json"), "[1, 2]").unwrap();
    let s = gather(&dir).unwrap();
    assert_eq!(s.navigation.len(), 2, "{:?}", s.navigation);
    assert!(
        s.warnings
            .iter()
            .any(|w| w.contains("rcm_report.json") && w.contains("not a JSON object")),
        "{:?}",
        s.warnings
    );
    let md = s.markdown();
    assert!(
        md.contains("CT ↔ tracker registration (`nav/registration.json`)"),
        "{md}"
    );
    assert!(
        md.contains("- fre_mm: 0.2400") && md.contains("- tre_mm: 0.2600"),
        "{md}"
    );
    assert!(
        md.contains("Navigation chain") && md.contains("- tip_rms_mm: 0.5000"),
        "{md}"
    );
    assert!(
        !md.contains("residuals"),
        "nested tables stay in the file: {md}"
    );
    assert_eq!(s.to_json()["navigation"].as_array().unwrap().len(), 2);
}
