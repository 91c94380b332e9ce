//! `robocal predict` with the `calibration.json` a laser diagnosis wrote reproduces the
//! held-out figure the diagnosis reports (issue 26 §9), for every laser effect kind: the
//! independent world (`robocal_mocks`) hides a range scale error, an incidence bias and a
//! range nonlinearity; a laser session records the planes and the targets; `robocal
//! diagnose` on the plane file with the selection targets held out names each kind; the mean
//! 5-direction spread of `robocal predict`'s spots of the held-out targets equals the
//! diagnosis' `heldout_rms.final_mm`.
use std::collections::BTreeMap;
use std::path::Path;

use robocal::schema::DiagnosisFile;
use robocal::solve::laser::validate::spread;

use crate::common::{cli, diagnose_cli, predict_cli, root, s};

/// `robocal diagnose` then `robocal predict` on the session in `dir`; returns the kinds
/// named, the diagnosis' held-out spread and predict's (mm).
fn diagnose_and_predict(dir: &Path) -> (Vec<String>, f64, f64) {
    let train = dir.join("run-train/dataset.jsonl");
    let held = dir.join("run-selection/dataset.jsonl");
    let out = dir.join("trust-diag");
    let code = diagnose_cli(&train, &held, &out);
    assert_eq!(code, 0, "diagnose");
    let d: DiagnosisFile = robocal::schema::read(&out.join("diagnosis.json")).unwrap();
    let kinds = d.effects.iter().map(|e| e.kind.clone()).collect();
    let reported = d.heldout_rms.final_mm.expect("a held-out spread");
    let pred = dir.join("trust-pred.csv");
    let cal = out.join("calibration.json");
    let code = predict_cli(&cal, &held, &pred);
    assert_eq!(code, 0, "predict");
    let spots = robocal::schema::points_csv::read(&pred).unwrap();
    let ds = robocal::dataset::Dataset::load(&held).unwrap();
    let mut by_target: BTreeMap<String, Vec<nalgebra::Point3<f64>>> = BTreeMap::new();
    for r in ds.poses() {
        if let (Some(t), Some(p)) = (&r.target, spots.get(&r.id)) {
            by_target.entry(t.clone()).or_default().push(*p);
        }
    }
    assert!(by_target.len() >= 8, "{} targets", by_target.len());
    let got = by_target.values().map(|p| spread(p)).sum::<f64>() / by_target.len() as f64;
    (kinds, reported, got)
}

#[test]
fn predict_reproduces_the_laser_diagnosis_every_kind() {
    // The laser cell with an exact arm (the flange poses are right), and the three laser
    // effects hidden in the world.
    let mut sc =
        robocal_mocks::Scenario::load(&root().join("mocks/scenarios/lab-vs060-il600-planes.toml"))
            .unwrap();
    sc.arms[0].errors = robocal_mocks::scenario::GeometricErrors::none();
    sc.arms[0].effects = Default::default();
    let e = &mut sc.lasers[0].effects;
    e.scale_ppm = 3000.0;
    e.incidence_mm = 4.0;
    e.nonlinearity_mm = 0.6;
    let tmp = tempfile::tempdir().unwrap();
    let p = tmp.path().join("scenario.toml");
    std::fs::write(&p, toml::to_string(&sc).unwrap()).unwrap();
    let dir = tmp.path().join("session");
    let code = cli(&[
        "session",
        "--sim",
        s(&p),
        "--kind",
        "laser",
        "--out",
        s(&dir),
        "--in-process",
        "--no-history",
    ]);
    assert!(code == 0 || code == 2, "session exit {code}");
    let (kinds, reported, got) = diagnose_and_predict(&dir);
    eprintln!(
        "laser world (scale 3000 ppm, incidence 4 mm, nonlinearity 0.6 mm): found {kinds:?}; \
         held-out spread: diagnosis {reported:.5} mm, predict with its calibration.json \
         {got:.5} mm"
    );
    for k in ["laser_scale", "laser_incidence", "laser_nonlinearity"] {
        assert!(kinds.iter().any(|x| x == k), "{k} not named: {kinds:?}");
    }
    assert!(
        (got - reported).abs() < 1e-4,
        "predict {got} mm vs the diagnosis' {reported} mm"
    );
}
